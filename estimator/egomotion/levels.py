"""What the direct estimator precomputes once per camera, per pyramid level: the road
region of interest (below the horizon, in range, outside the ego body), the rays of its
candidate pixels and their nominal motion Jacobians (`build_levels`).

Pyramid levels are addressed in full-resolution pixels: ``cv2.pyrDown`` puts level-l
pixel (i, j) at full-resolution pixel (2^l i, 2^l j), so a candidate's ray is
``camera.unproject`` of its full-resolution position.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.homography import make_state
from estimator.egomotion.motion_model import warp_jacobian
from estimator.geometry import road_distance_m


# ---------------------------------------------------------- region of interest
def ego_body_hit(
    rays_car: np.ndarray, origin_car: np.ndarray, box_m: tuple[float, float, float], margin_m: float
) -> np.ndarray:
    """(N,) bool: rays (N, 3) from origin (3,) (car frame) that enter the ego body box.

    The box is ``|x| <= L/2 + margin``, ``|y| <= W/2 + margin``, ``0 <= z <= H + margin``.
    A ray from a viewpoint inside the box is never counted as blocked (slab test).
    """
    L, Wd, Ht = box_m
    lo = np.array([-L / 2 - margin_m, -Wd / 2 - margin_m, 0.0])
    hi = np.array([L / 2 + margin_m, Wd / 2 + margin_m, Ht + margin_m])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / rays_car
        t1 = (lo - origin_car) * inv
        t2 = (hi - origin_car) * inv
    t1 = np.nan_to_num(t1, nan=-np.inf)
    t2 = np.nan_to_num(t2, nan=np.inf)
    t_near = np.max(np.minimum(t1, t2), axis=1)
    t_far = np.min(np.maximum(t1, t2), axis=1)
    return (t_near <= t_far) & (t_near > 0.0)


def road_roi(
    mount: CameraMount,
    rays: np.ndarray,
    max_range_m: float,
    ego_box_m: tuple[float, float, float] | None,
    ego_margin_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Road masks of rays (N, 3) of the nominal camera: (seen (N,) bool, in_range (N,) bool).

    seen: below the horizon (``K0^T r > 0``) and not through the ego body;
    in_range: the road hit is within ``max_range_m`` (horizontal distance from
    the viewpoint). Only ``seen`` has image edges at its border (body, horizon).
    """
    kr = rays @ mount.K0
    seen = np.isfinite(kr) & (kr > 1e-6)
    with np.errstate(invalid="ignore"):
        in_range = seen & (road_distance_m(rays, mount.K0) <= max_range_m)
    if ego_box_m is not None:
        rays_car = rays @ mount.R_car_cam.T
        seen &= ~ego_body_hit(
            rays_car, np.asarray(mount.position_m, float), ego_box_m, ego_margin_m
        )
    return seen, in_range


@dataclass
class Level:
    """What depends only on the camera at one pyramid level.

    scale: 2^l; shape: (H_l, W_l); roi_idx: (M,) flat indices of candidate pixels;
    roi_w: (M, 2) their full-resolution pixels; roi_rays: (M, 3) their rays;
    valid_b: (H_l, W_l) uint8 mask of pixels where B may be sampled;
    sel_J: (M, 2, 9) float32 dw/dx of each candidate at the nominal state (V = 1 m/s
    forward, W = A = 0) per unit dt (V, W columns) and per metre of travel (A columns),
    for ranking candidates (`select_points`); to_mask: (M,) flat index of each candidate
    in the off-road mask grid (set by `DirectEstimator`); road_dist_m: (M,) horizontal
    distance of each candidate's road hit [m] (``far_depth_m``); roi_rays32: roi_rays in
    float32 (the dense off-road map).
    """

    scale: int
    shape: tuple[int, int]
    roi_idx: np.ndarray
    roi_w: np.ndarray
    roi_rays: np.ndarray
    valid_b: np.ndarray
    sel_J: np.ndarray
    to_mask: np.ndarray | None = None
    road_dist_m: np.ndarray | None = None
    roi_rays32: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.roi_rays32 = self.roi_rays.astype(np.float32)


def _level_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    shapes = [(height, width)]
    for _ in range(1, levels):
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def build_levels(camera: CameraModel, mount: CameraMount, cfg: DirectConfig) -> list[Level]:
    """Per-level ROI, rays of candidate pixels and sampling masks (once per camera).

    The image-edge masks (valid rays, road side of the horizon, outside the ego
    body) are eroded by ``roi_erode_px`` (plus 2 sigma of the pre-smoothing at
    level 0): no point or sample then reads pixels across those edges.
    """
    valid_full = camera.valid_mask()
    out = []
    kernel = np.ones((3, 3), np.uint8)
    for lvl, (h, w) in enumerate(_level_shapes(camera.height, camera.width, cfg.levels)):
        s = 2**lvl
        v, u = np.mgrid[0:h, 0:w]
        uf, vf = (u * s).ravel(), (v * s).ravel()
        inside = (uf < camera.width) & (vf < camera.height)
        valid = np.zeros(h * w, bool)
        valid[inside] = valid_full[vf[inside], uf[inside]]
        w_full = np.stack([uf, vf], 1).astype(np.float64)
        cand = np.flatnonzero(valid)
        rays = camera.unproject(w_full[cand])
        seen, in_range = road_roi(mount, rays, cfg.max_range_m, cfg.ego_box_m, cfg.ego_margin_m)
        erode = cfg.roi_erode_px + (math.ceil(2 * cfg.presmooth_sigma_px) if lvl == 0 else 0)
        clean = np.zeros(h * w, np.uint8)
        clean[cand[seen]] = 1
        clean = cv2.erode(clean.reshape(h, w), kernel, iterations=erode)
        keep = in_range & (clean.ravel()[cand] > 0)
        out.append(
            Level(
                s,
                (h, w),
                cand[keep],
                w_full[cand[keep]],
                rays[keep],
                clean,
                selection_jacobian(camera, mount, rays[keep]),
                road_dist_m=road_distance_m(rays[keep], mount.K0),
            )
        )
    return out


def selection_jacobian(camera: CameraModel, mount: CameraMount, rays: np.ndarray) -> np.ndarray:
    """(N, 2, 9) float32 dw/dx of rays (N, 3) at the nominal state, per unit dt and travel.

    The state is V = 1 m/s along the car's x axis, W = A = 0, over a short dt: the V
    and W columns are then per second of dt, the A columns per metre of travel (the
    plane-tilt effect of A scales with the translation). Scale them by dt and by
    speed * dt (`column_scale`) for the current frame pair.
    """
    dt = 1e-3
    x = make_state(mount.R_car_cam.T @ np.array([1.0, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    _, J = warp_jacobian(camera, rays, x, mount.K0, dt)
    return np.nan_to_num(J / dt).astype(np.float32)
