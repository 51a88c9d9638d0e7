"""Road-plane consistency: photometric residual after motion compensation.

Frame k-1 is warped onto frame k through the camera model with a homography
(the ground truth's exact one, or the estimate's); the residual is measured on
*road* pixels of frame k: valid rays, no vehicle (id image), range equal to the
road plane's range within 3 % (so guard-rails, posts and trees are excluded),
within ``max_range_m``, and a warped source inside the previous frame's view.
Vehicles are measured separately: they should stand out.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.fileio import read_png


def _warp_prev(
    camera: CameraModel, rays: np.ndarray, valid_u8: np.ndarray, prev: np.ndarray, H: np.ndarray
) -> np.ndarray:
    P_prev = rays @ np.linalg.inv(H).T
    w = np.nan_to_num(camera.project(P_prev), nan=-10.0).astype(np.float32)
    w = w.reshape(camera.height, camera.width, 2)
    out = cv2.remap(prev, w, None, cv2.INTER_LINEAR, borderValue=0)
    ok = cv2.remap(valid_u8, w, None, cv2.INTER_NEAREST, borderValue=0) > 0
    return np.where(ok, out, np.nan)


def road_residuals(
    drive_dir: Path,
    camera: CameraModel,
    mount: CameraMount,
    gt: list[dict],
    homographies: dict[int, np.ndarray],
    frames: list[int] | None = None,
    max_range_m: float = 30.0,
) -> dict:
    """RMS residual [grey levels] on road pixels with ground-truth and given homographies.

    homographies: frame k -> H (3, 3) mapping rays of frame k-1 to frame k.
    Returns {"road_rms_gt", "road_rms", "ratio", "vehicle_rms_gt", "uncompensated_rms",
    the same as median absolute residuals ("road_median_abs_gt", ...), "frames"}:
    each the median over the frames. RMS figures are dominated by the few pixels at
    occlusion boundaries of objects above the road; the median ones by the road.
    """
    drive_dir = Path(drive_dir)
    rays = camera.pixel_rays().reshape(-1, 3).astype(np.float64)
    valid = camera.valid_mask()
    valid_u8 = cv2.erode(valid.astype(np.uint8), np.ones((3, 3), np.uint8))
    with np.errstate(divide="ignore"):
        plane_range = (1.0 / (rays @ mount.K0)).reshape(valid.shape)
    frames = frames if frames is not None else [k for k in homographies if k >= 1]
    rows = []
    for k in frames:
        m = gt[k]["motion_from_prev"]
        if m is None or k not in homographies:
            continue
        gray = [
            cv2.cvtColor(
                read_png(drive_dir / "frames" / f"{j:06d}.png"), cv2.COLOR_RGB2GRAY
            ).astype(np.float32)
            for j in (k - 1, k)
        ]
        ids = read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int32) - 1
        rng = read_png(drive_dir / "range" / f"{k:06d}.png") / 100.0
        road = (
            valid
            & (ids < 0)
            & (plane_range > 0)
            & (plane_range < max_range_m)
            & (np.abs(rng - plane_range) < 0.03 * plane_range)
        )
        w_gt = _warp_prev(camera, rays, valid_u8, gray[0], np.asarray(m["H"]))
        w_est = _warp_prev(camera, rays, valid_u8, gray[0], homographies[k])
        both = road & np.isfinite(w_gt) & np.isfinite(w_est)
        veh = valid & (ids > 0) & np.isfinite(w_gt)
        if both.sum() < 100:
            continue
        e_gt, e_est = w_gt[both] - gray[1][both], w_est[both] - gray[1][both]
        e_veh = w_gt[veh] - gray[1][veh] if veh.sum() >= 50 else np.array([np.nan])
        e_raw = gray[0][both] - gray[1][both]
        rows.append(
            [
                _rms(e_gt),
                _rms(e_est),
                _rms(e_veh),
                _rms(e_raw),
                _mad(e_gt),
                _mad(e_est),
                _mad(e_veh),
                _mad(e_raw),
            ]
        )
    if not rows:
        return {"frames": 0}
    a = np.array(rows)
    med = [
        float(np.nanmedian(a[:, i])) if np.any(np.isfinite(a[:, i])) else float("nan")
        for i in range(a.shape[1])
    ]
    return {
        "road_rms_gt": med[0],
        "road_rms": med[1],
        "ratio": med[1] / med[0],
        "vehicle_rms_gt": med[2],
        "uncompensated_rms": med[3],
        "road_median_abs_gt": med[4],
        "road_median_abs": med[5],
        "vehicle_median_abs_gt": med[6],
        "uncompensated_median_abs": med[7],
        "frames": len(rows),
    }


def _mad(e: np.ndarray) -> float:
    """Median absolute residual: robust to the few occlusion boundaries (posts, rails)."""
    return float(np.median(np.abs(e)))


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e.astype(np.float64) ** 2)))
