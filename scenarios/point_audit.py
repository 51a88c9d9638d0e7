"""Audit of the estimator's point set against ground truth: how much of it is not road.

The direct estimator assumes every point lies on the road plane (eq. 3). A point on
something above the road (a guard-rail post, a kerb, a vehicle) moves in the image
like a road point nearer the car, so it pulls the speed up. The data snooping cannot
catch such points when they agree with each other: roadside posts have vertical
edges along the image motion and can carry much of the forward-speed information
while being few. This module measures, from the range images of a rendered drive,
which finest-level inliers of each frame pair lie more than ``min_height_m`` above the
road (the highest surface within the point's 3x3 pixel support, so that points on an
object's outline count) and what share of the points and of their forward-speed
information (`EgoMotionRecord.point_speed_info`) they hold.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from estimator.camera import CameraModel
from estimator.direct import INLIER
from estimator.fileio import read_png

MIN_HEIGHT_M = 0.1  # [m] above this, a point is not on the road


def height_map(
    drive_dir: Path, frame: int, unit_rays: np.ndarray, T_world_cam: np.ndarray
) -> np.ndarray:
    """(H, W) height above the road [m] of what each pixel of ``frame`` sees (+inf: sky).

    unit_rays: (H, W, 3) unit rays of the camera; T_world_cam: (4, 4) actual camera pose.
    """
    rng_m = read_png(Path(drive_dir) / "range" / f"{frame:06d}.png").astype(np.float64) / 100.0
    z = (unit_rays * rng_m[..., None]) @ T_world_cam[2, :3] + T_world_cam[2, 3]
    z[rng_m <= 0] = np.inf
    return z


def camera_unit_rays(camera: CameraModel) -> np.ndarray:
    """(H, W, 3) unit rays of every pixel (0 where the camera has none)."""
    rays = camera.pixel_rays().astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    return np.nan_to_num(rays)


def gt_road_mask(
    drive_dir: Path,
    frame: int,
    unit_rays: np.ndarray,
    gt_frame: dict,
    max_height_m: float = MIN_HEIGHT_M,
) -> np.ndarray:
    """(H, W) bool: pixels of ``frame`` that see a surface within max_height_m of the road."""
    z = height_map(drive_dir, frame, unit_rays, np.asarray(gt_frame["T_world_cam_actual"], float))
    return z < max_height_m


def points_above_road(
    drive_dir: Path,
    camera: CameraModel,
    gt: list[dict],
    records: list,
    min_height_m: float = MIN_HEIGHT_M,
) -> dict:
    """Shares of the finest-level inliers above the road, over all frame pairs.

    gt: per-frame ground truth (``T_world_cam_actual``); records: the estimator's
    `EgoMotionRecord`s (points in the previous frame). Returns {"min_height_m",
    "frames" (pairs audited), "inliers", "inlier_share", "speed_info_share"}; the shares
    are NaN when no pair had inliers (or, for the information, when the estimator does
    not report it: the baselines).
    """
    rays = camera_unit_rays(camera)
    h, w = camera.height, camera.width
    n_in = n_above = 0
    info_all = info_above = 0.0
    frames = 0
    kernel = np.ones((3, 3), np.uint8)
    for rec in records:
        k = int(rec.frame) - 1
        labels = np.asarray(rec.point_labels)
        inl = labels == INLIER
        if k < 0 or not inl.any():
            continue
        z = height_map(drive_dir, k, rays, np.asarray(gt[k]["T_world_cam_actual"], float))
        z_support = cv2.dilate(np.minimum(z, 1e3).astype(np.float32), kernel)
        px = np.rint(np.asarray(rec.points_px)[inl]).astype(int)
        px[:, 0] = px[:, 0].clip(0, w - 1)
        px[:, 1] = px[:, 1].clip(0, h - 1)
        above = z_support[px[:, 1], px[:, 0]] > min_height_m
        frames += 1
        n_in += int(inl.sum())
        n_above += int(above.sum())
        info = np.asarray(rec.point_speed_info, float)
        if len(info) == len(labels):
            info_all += float(info[inl].sum())
            info_above += float(info[inl][above].sum())
    return {
        "min_height_m": min_height_m,
        "frames": frames,
        "inliers": n_in,
        "inlier_share": n_above / n_in if n_in else float("nan"),
        "speed_info_share": info_above / info_all if info_all > 0 else float("nan"),
    }
