"""Procedural, seamlessly tileable ground textures (asphalt, grass), seeded.

Every texture is periodic: its right edge continues into its left edge and its
bottom into its top, so a mesh whose UVs are world metres divided by the tile
size shows no seams. Periodicity comes from building everything on the torus:
noise is filtered in the Fourier domain, blobs are spread by circular
convolution, and lines are drawn at the 9 wrapped offsets.

The ego-motion estimator tracks road texture, so the asphalt has contrast at all
the scales a camera sees on a road (2-20 cm): multi-scale noise, aggregate
speckles, cracks, sealed-crack tar lines and a repaired patch. Texel size is
``tile_m / size_px`` (4.5 m / 512 px ~ 9 mm by default in sim/scene.py).

All functions take a ``np.random.Generator`` and return ``(H, W, 3) uint8`` RGB.
"""

from __future__ import annotations

import cv2
import numpy as np


def periodic_noise(
    rng: np.random.Generator,
    size_px: int,
    beta: float = 2.0,
    min_period_px: float = 2.0,
    max_period_px: float | None = None,
) -> np.ndarray:
    """Tileable noise with power spectrum ~ 1/f**beta between two periods, std 1.

    Returns (size_px, size_px) float64 with zero mean and unit variance.
    """
    _check_size(size_px)
    max_period_px = max_period_px or float(size_px)
    f = np.fft.fftfreq(size_px)
    fr = np.hypot(f[:, None], f[None, :])
    band = (fr >= 1.0 / max_period_px) & (fr <= 1.0 / min_period_px)
    amp = np.zeros_like(fr)
    amp[band] = fr[band] ** (-beta / 2.0)
    white = rng.standard_normal((size_px, size_px))
    out = np.real(np.fft.ifft2(np.fft.fft2(white) * amp))
    out -= out.mean()
    std = out.std()
    return out / std if std > 0 else out


def periodic_blobs(
    rng: np.random.Generator,
    size_px: int,
    count: int,
    radius_px: float,
    values: np.ndarray,
) -> np.ndarray:
    """Sum of ``count`` Gaussian blobs (sigma = radius_px/2) at random wrapped places.

    values: (count,) peak value of each blob.
    """
    img = np.zeros((size_px, size_px))
    ij = rng.integers(0, size_px, size=(count, 2))
    np.add.at(img, (ij[:, 0], ij[:, 1]), values)
    return _circular_gauss(img, radius_px / 2.0)


def _circular_gauss(img: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur on the torus (FFT), scaled so that an impulse keeps its peak."""
    n = img.shape[0]
    f = np.fft.fftfreq(n)
    g = np.exp(-2.0 * (np.pi * sigma_px) ** 2 * (f[:, None] ** 2 + f[None, :] ** 2))
    peak = float(np.real(np.fft.ifft2(g))[0, 0])
    return np.real(np.fft.ifft2(np.fft.fft2(img) * g)) / peak


def _random_walk(
    rng: np.random.Generator, start: np.ndarray, steps: int, step_px: float, wiggle: float
) -> np.ndarray:
    """(steps+1, 2) polyline: a walk with a slowly turning heading."""
    heading = rng.uniform(0, 2 * np.pi)
    turns = np.cumsum(rng.normal(0.0, wiggle, size=steps))
    ang = heading + turns
    d = step_px * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    return np.vstack([start, start + np.cumsum(d, axis=0)])


def _draw_wrapped_polyline(mask: np.ndarray, pts: np.ndarray, thickness: int) -> None:
    """Draw a polyline on the torus: at the 9 offsets by +-size (cv2 clips)."""
    n = mask.shape[0]
    shift = 4  # sub-pixel bits
    for dx in (-n, 0, n):
        for dy in (-n, 0, n):
            p = np.round((pts + (dx, dy)) * (1 << shift)).astype(np.int32)
            cv2.polylines(mask, [p], False, 255, thickness, cv2.LINE_AA, shift)


def _draw_wrapped_polygon(mask: np.ndarray, pts: np.ndarray) -> None:
    n = mask.shape[0]
    for dx in (-n, 0, n):
        for dy in (-n, 0, n):
            p = np.round(pts + (dx, dy)).astype(np.int32)
            cv2.fillPoly(mask, [p], 255, cv2.LINE_AA)


def asphalt_texture(rng: np.random.Generator, size_px: int = 512) -> np.ndarray:
    """A tileable asphalt texture, (size_px, size_px, 3) uint8 RGB.

    Layers (DN on 0..255, for a 512-px tile of ~4.5 m, ~9 mm per texel):
    base grey ~95 with a large-scale mottle (+-6), fine multi-scale noise (+-9,
    periods 2-64 px = 2-60 cm), light and dark aggregate stones (1-3 px radius),
    2-4 thin cracks, 1-2 dark tar lines (sealed cracks, 4-7 px wide) and, in
    half the tiles, a smoother repaired patch.
    """
    _check_size(size_px)
    n = size_px
    s = n / 512.0  # scale of the pixel sizes below
    grey = 95.0 + 6.0 * periodic_noise(rng, n, beta=3.0, min_period_px=64 * s)
    grey += 9.0 * periodic_noise(rng, n, beta=1.2, min_period_px=2.0, max_period_px=64 * s)
    # aggregate: many small stones, mostly light, some dark
    n_stones = int(0.02 * n * n)
    light = rng.uniform(25.0, 70.0, size=n_stones)
    light[rng.uniform(size=n_stones) < 0.3] *= -0.6
    grey += periodic_blobs(rng, n, n_stones, max(1.0, 1.5 * s), light)
    grey += periodic_blobs(rng, n, n_stones // 8, max(1.5, 3.0 * s), light[: n_stones // 8] * 0.5)
    # a repaired patch: smoother, darker, with an edge
    if rng.uniform() < 0.5:
        mask = np.zeros((n, n), np.uint8)
        c = rng.uniform(0, n, size=2)
        w, h = rng.uniform(0.2, 0.45, size=2) * n
        ang = rng.uniform(-0.15, 0.15)
        rect = cv2.boxPoints(((float(c[0]), float(c[1])), (float(w), float(h)), np.degrees(ang)))
        _draw_wrapped_polygon(mask, rect)
        m = mask / 255.0
        grey = grey * (1 - m) + (grey - 95.0) * 0.45 * m + 80.0 * m
    # cracks: thin, dark, wiggly
    cracks = np.zeros((n, n), np.uint8)
    for _ in range(int(rng.integers(2, 5))):
        pts = _random_walk(rng, rng.uniform(0, n, 2), int(rng.integers(20, 60)), 6.0 * s, 0.35)
        _draw_wrapped_polyline(cracks, pts, 1)
    grey -= 40.0 * (cracks / 255.0)
    # tar lines: sealed cracks, wide and very dark
    tar = np.zeros((n, n), np.uint8)
    for _ in range(int(rng.integers(1, 3))):
        pts = _random_walk(rng, rng.uniform(0, n, 2), int(rng.integers(15, 40)), 10.0 * s, 0.15)
        _draw_wrapped_polyline(tar, pts, int(rng.integers(4, 8) * s) or 2)
    t = tar / 255.0
    grey = grey * (1 - t) + (45.0 + 0.2 * (grey - 95.0)) * t
    tint = np.array([1.0, 0.99, 0.96])  # slightly warm
    rgb = grey[..., None] * tint[None, None, :]
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def grass_texture(rng: np.random.Generator, size_px: int = 256) -> np.ndarray:
    """A tileable grass/verge texture, (size_px, size_px, 3) uint8 RGB."""
    _check_size(size_px)
    n = size_px
    big = periodic_noise(rng, n, beta=3.0, min_period_px=n / 8)
    fine = periodic_noise(rng, n, beta=1.0, min_period_px=2.0, max_period_px=n / 8)
    dirt = np.clip(periodic_noise(rng, n, beta=3.5, min_period_px=n / 6) - 1.0, 0, None)
    green = np.array([72.0, 104.0, 46.0])
    brown = np.array([110.0, 92.0, 62.0])
    w = np.clip(dirt, 0, 1)[..., None]
    rgb = green * (1 - w) + brown * w
    rgb = rgb * (1.0 + 0.12 * big[..., None] + 0.10 * fine[..., None])
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def _check_size(size_px: int) -> None:
    if not (isinstance(size_px, int | np.integer) and 16 <= size_px <= 4096):
        raise ValueError(f"texture size_px must be an int in [16, 4096], got {size_px!r}")
