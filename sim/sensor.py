"""Camera sensor effects applied to a rendered image.

Order: exposure/gain and vignetting -> motion blur -> pixel noise -> 8-bit
quantisation -> JPEG. Every effect is off when its setting is zero/None.
Randomness comes from the generator passed in (seeded per frame by the caller,
so a resumed render reproduces the same frames).
"""

from __future__ import annotations

from dataclasses import dataclass

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


def motion_blur(image: np.ndarray, flow_px: np.ndarray, samples: int = 5) -> np.ndarray:
    """Average of the image displaced along a per-pixel flow over the exposure.

    flow_px: (H, W, 2) image motion during the exposure [px] (u, v).
    """
    H, W = image.shape[:2]
    v, u = np.mgrid[0:H, 0:W].astype(np.float32)
    acc = np.zeros(image.shape, np.float32)
    for s in np.linspace(-0.5, 0.5, samples, dtype=np.float32):
        mx = (u + s * flow_px[..., 0]).astype(np.float32)
        my = (v + s * flow_px[..., 1]).astype(np.float32)
        acc += cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return acc / samples


def apply_sensor(
    image: np.ndarray,
    model: SensorModel,
    rng: np.random.Generator,
    gain: float = 1.0,
    vignette: np.ndarray | None = None,
    flow_px: np.ndarray | None = None,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """Sensor effects on an (H, W, 3) uint8 RGB image; returns uint8.

    mask: (H, W) bool, pixels that have an image (others stay black).
    """
    img = image.astype(np.float32)
    if gain != 1.0:
        img *= gain
    if vignette is not None and model.vignetting > 0:
        img *= vignette[..., None]
    if model.motion_blur and flow_px is not None:
        img = motion_blur(img, flow_px)
    if model.noise_std > 0:
        img += np.float32(model.noise_std) * rng.standard_normal(img.shape, dtype=np.float32)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if mask is not None:
        out[~mask] = 0
    if model.jpeg_quality is not None:
        ok, buf = cv2.imencode(
            ".jpg", out[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, model.jpeg_quality]
        )
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        out = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return out
