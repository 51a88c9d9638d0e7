"""Camera sensor effects applied to a rendered image.

Order: exposure/gain and vignetting -> motion blur -> pixel noise -> 8-bit
quantisation -> JPEG. Every effect is off when its setting is zero/None.
Randomness comes from the generator passed in (seeded per frame by the caller,
so a resumed render reproduces the same frames).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np


@dataclass(frozen=True)
class SensorModel:
    noise_std: float = 0.0  # [DN] Gaussian noise on 0..255
    motion_blur: bool = False
    exposure_s: float = 0.01  # [s]
    gain_drift: float = 0.0  # [-] std of the slowly varying gain
    vignetting: float = 0.0  # [-] brightness loss at the image corner
    jpeg_quality: int | None = None


def gain_sequence(n: int, drift_std: float, rng: np.random.Generator) -> np.ndarray:
    """(n,) slowly varying exposure gain around 1 (AR(1) with 2 s memory at 15 fps)."""
    g = np.ones(n)
    if drift_std <= 0:
        return g
    rho = 0.97
    x = rng.normal(0, drift_std)
    for k in range(n):
        x = rho * x + np.sqrt(1 - rho**2) * rng.normal(0, drift_std)
        g[k] = 1.0 + x
    return g


def exposure_times(exposure_s: float, samples: int = 5) -> np.ndarray:
    """(samples,) times [s] of the motion-blur samples relative to the frame's time: the
    middles of equal parts of an exposure centred on it (their mean is the time average)."""
    return (np.arange(samples) + 0.5) / samples * exposure_s - exposure_s / 2


_BORDER = cv2.BORDER_REPLICATE  # of the motion blur's samples


def motion_blur(
    image: np.ndarray, displacements_px: Sequence[np.ndarray], mask: np.ndarray | None = None
) -> np.ndarray:
    """The image a pixel integrates over the exposure, from the sharp image at the frame's
    time: the average over the sample times (`exposure_times`).

    displacements_px: per sample time, (H, W, 2) image motion [px] (u, v) of each pixel's
    scene point from the frame's time to it. At that time a pixel x sees the point y with
    ``y + d(y) = x``, solved by one fixed-point step from ``x - d(x)``. (A straight streak
    along each pixel's own motion to the next frame, the blur before, moved a feature ~2.7x
    farther than its path's time average where the motion changes along the streak:
    0.068 against 0.026 px in `test_motion_blur_is_the_time_average_of_the_paths`.)
    mask: (H, W) bool, the pixels whose blur is wanted (default all); only blocks that hold
    those that move are resampled (`moving_blocks`), the others keep the sharp image.
    """
    if not len(displacements_px):
        return image
    d_all = [np.asarray(d, np.float32) for d in displacements_px]
    moving = np.zeros(image.shape[:2], bool)
    for d in d_all:  # (u, v) both 0.0 where the 8 bytes are 0 (-0.0 counts as moving)
        moving |= np.ascontiguousarray(d).view(np.uint64)[..., 0] != 0
    if mask is not None:
        moving &= mask
    blocks = moving_blocks(moving)
    grid = _pixel_grid(*image.shape[:2])
    sample = image.copy()  # a sample's image: the sharp one where nothing moves
    out = np.zeros(image.shape, np.float32)
    for d in d_all:
        if not d.any():  # the sample at the frame's time
            out += image
            continue
        for rows, cols in blocks:
            d_b, g_b = d[rows, cols], grid[rows, cols]
            d_b = cv2.remap(d, g_b - d_b, None, cv2.INTER_LINEAR, borderMode=_BORDER)
            sample[rows, cols] = cv2.remap(
                image, g_b - d_b, None, cv2.INTER_LINEAR, borderMode=_BORDER
            )
        out += sample
    out *= np.float32(1.0 / len(displacements_px))
    return out


# [px] `moving_blocks`: height of its row bands and the narrowest gap it leaves out, 8..H
BLUR_BLOCK_PX = 32


def moving_blocks(moving: np.ndarray) -> list[tuple[slice, slice]]:
    """(rows, cols) slices of rectangles that hold every True pixel of moving (H, W) bool:
    per band of BLUR_BLOCK_PX rows, its runs of columns with a True pixel (runs closer
    than BLUR_BLOCK_PX merged)."""
    H = moving.shape[0]
    blocks = []
    for r0 in range(0, H, BLUR_BLOCK_PX):
        rows = slice(r0, min(r0 + BLUR_BLOCK_PX, H))
        cols = np.flatnonzero(moving[rows].any(axis=0))
        if not len(cols):
            continue
        breaks = np.flatnonzero(np.diff(cols) > BLUR_BLOCK_PX)
        starts = np.concatenate([[cols[0]], cols[breaks + 1]])
        stops = np.concatenate([cols[breaks], [cols[-1]]]) + 1
        blocks += [(rows, slice(int(a), int(b))) for a, b in zip(starts, stops, strict=True)]
    return blocks


@lru_cache(maxsize=4)
def _pixel_grid(H: int, W: int) -> np.ndarray:
    """(H, W, 2) float32 column and row of every pixel (read only)."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    grid = np.stack([u, v], axis=2)
    grid.flags.writeable = False
    return grid


def gaussian_noise(shape: tuple, std: float, seed: int) -> np.ndarray:
    """float32 array of the shape, N(0, std^2), the same for the same seed (OpenCV's
    generator, seeded in this thread)."""
    out = np.empty(int(np.prod(shape)), np.float32)
    cv2.setRNGSeed(int(seed))
    cv2.randn(out, 0.0, float(std))
    return out.reshape(shape)


def apply_sensor(
    image: np.ndarray,
    model: SensorModel,
    rng: np.random.Generator,
    gain: float = 1.0,
    vignette: np.ndarray | None = None,
    blur_px: Sequence[np.ndarray] | None = None,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Sensor effects on an (H, W, 3) uint8 RGB image; returns uint8.

    mask: (H, W) bool, pixels that have an image (others stay black).
    blur_px: the image motion at the exposure's sample times (`motion_blur`); None: none.
    """
    img = image.astype(np.float32)
    if vignette is not None and model.vignetting > 0:
        scale = np.float32(gain) * np.asarray(vignette, np.float32)
        img = cv2.multiply(img, cv2.merge([scale, scale, scale]))
    elif gain != 1.0:
        img *= np.float32(gain)
    if model.motion_blur and blur_px is not None:
        img = motion_blur(img, blur_px, mask)
    noise = 0.0
    if model.noise_std > 0:
        noise = gaussian_noise(img.shape, model.noise_std, int(rng.integers(0, 2**31 - 1)))
    # the sum rounded to the nearest integer and saturated to 0..255, in one pass
    out = cv2.add(img, noise, dtype=cv2.CV_8U)
    if mask is not None:
        out = cv2.bitwise_and(out, out, mask=np.asarray(mask, np.uint8))
    if model.jpeg_quality is not None:
        bgr = cv2.cvtColor(out, cv2.COLOR_RGB2BGR)
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, model.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        out = cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    return out
