"""Road segmentation by appearance: the road is what looks like the road just behind the car.

The direct estimator assumes its points lie on the road plane (eq. 3). Structure above
the road that moves almost like it (a guard-rail 15-25 m away, a kerb island) passes the
data snooping and the plane-parallax test: its parallax over a frame pair is within the
noise. Its look is not the road's: the road near the car, which the camera's calibration
locates (the ``seed``: the nearest ROI pixels on the road plane), sets a colour model
(median and spread in CIE Lab), and the road is the connected region of pixels that fit
it and reach the seed, with the holes in it (lane markings, tar lines it encloses)
filled. What is not road is excluded from the next pair's points like the off-road
map's pixels.

A classic colour-model road detector (region growing from a road seed); it needs no
training and runs on a real recording, where the near road is asphalt as here. Its
failure is to keep too much (a grey car on the road, a grey wall beyond it), never the
estimator's: the off-road map and the data snooping still run on what it keeps.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator.geometry import road_distance_m


@dataclass(frozen=True)
class AppearanceConfig:
    """Tolerances of the road's colour model (CIE Lab, OpenCV's 8-bit scale)."""

    lightness_tol: float = 40.0  # [L units, 0-255] |L - median of the seed| kept as road:
    # asphalt far away looks lighter (texture filtering, haze) than under the car; rails,
    # kerbs and markings are far lighter still
    chroma_tol: float = 6.0  # [a, b units] least tolerance on a and b (3 MADs if wider)
    close_px: int = 5  # [px at the map's level] closing of the road-like pixels (noise, cracks)
    min_seed_share: float = 0.02  # [-] a region holding less of the seed is not the road


def seed_indices(rays: np.ndarray, K0: np.ndarray, share: float = 0.3) -> np.ndarray:
    """(M,) indices into rays (M, 3) of the nearest ``share`` of road-plane points.

    rays: unit candidate rays in the camera frame (pointing at the road, ``K0ᵀ ray > 0``);
    K0: (3,) road plane (``K0ᵀ P = 1``) [1/m]. Distance is horizontal (along the plane).
    """
    horizontal = road_distance_m(rays, K0)
    return np.flatnonzero(horizontal <= np.quantile(horizontal, share))


def offroad_by_appearance(
    image: np.ndarray, seed: np.ndarray, cfg: AppearanceConfig = AppearanceConfig()
) -> np.ndarray | None:
    """(H, W) uint8, 1 where image (H, W, 3) RGB or (H, W) gray does not look like the road.

    seed: (S,) flat pixel indices of image that are expected to show the road. None when
    the seed is empty. A gray image is judged by its lightness alone.
    """
    if len(seed) == 0:
        return None
    if image.ndim == 2:
        lab = image.astype(np.float32)[..., None]
        tol_min = np.array([cfg.lightness_tol], np.float32)
    else:
        lab = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2LAB).astype(np.float32)
        tol_min = np.array([cfg.lightness_tol, cfg.chroma_tol, cfg.chroma_tol], np.float32)
    h, w = lab.shape[:2]
    flat = lab.reshape(h * w, -1)
    s = flat[seed]
    med = np.median(s, axis=0)
    mad = 1.4826 * np.median(np.abs(s - med), axis=0)
    tol = np.maximum(3.0 * mad, tol_min)
    tol[0] = tol_min[0]  # lightness: a fixed band (the seed's own texture is no guide)
    like = np.all(np.abs(flat - med) <= tol, axis=1).reshape(h, w).astype(np.uint8)
    if cfg.close_px > 1:
        like = cv2.morphologyEx(like, cv2.MORPH_CLOSE, np.ones((cfg.close_px,) * 2, np.uint8))
    n, labels = cv2.connectedComponents(like, connectivity=4)
    counts = np.bincount(labels.ravel()[seed], minlength=n)
    counts[0] = 0  # label 0: not road-like
    road = (counts >= cfg.min_seed_share * len(seed))[labels]
    # holes: what the border cannot reach through non-road pixels (markings on the road)
    off = np.pad((~road).astype(np.uint8), 1, constant_values=1)
    cv2.floodFill(off, None, (0, 0), 2)
    return (off[1:-1, 1:-1] == 2).astype(np.uint8)
