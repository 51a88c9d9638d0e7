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

`PullMap` goes one step further: where the images pull the estimate off the truth. At
each pair's true state, `DirectEstimator.point_pull` splits one IEKF step into the
inliers' parts; summed per pixel and per band of road range (in the car's forward speed
and yaw rate) they show which part of the image carries a bias that the truth does not
explain (a far guard-rail's posts, a kerb, a vehicle the map missed).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.ego_estimator import INLIER, PointPull
from estimator.egomotion.homography import V_SLICE, W_SLICE
from estimator.fileio import read_png, write_png
from estimator.geometry import road_distance_m

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


def gt_vehicle_ids(drive_dir: Path, frame: int) -> np.ndarray:
    """(H, W) int64: the id of the vehicle each pixel of ``frame`` sees (its
    ground-truth ``id``), -1 for none and 0 for the ego car (from the id image)."""
    return read_png(Path(drive_dir) / "ids" / f"{frame:06d}.png").astype(np.int64) - 1


def gt_vehicle_mask(drive_dir: Path, frame: int) -> np.ndarray:
    """(H, W) bool: pixels of ``frame`` that see another vehicle (id image; not the ego car)."""
    return gt_vehicle_ids(drive_dir, frame) > 0


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


RANGE_BANDS_M = (0.0, 10.0, 20.0, 40.0, math.inf)  # [m] bands of the points' road range


class PullMap:
    """The images' pull at the true state, summed over a drive's frame pairs (`add`).

    Per pixel of the pairs' first frames and per band of road range (``RANGE_BANDS_M``,
    the horizontal distance to where the pixel's nominal ray meets the road), in the car's
    forward speed [m/s] and yaw rate [deg/s]: ``summary`` gives the mean pull per pair
    (what the images alone would make of the truth, the bias of the data term) and its
    split by range; ``write_png`` shows where it comes from.
    """

    def __init__(self, camera: CameraModel, mount: CameraMount) -> None:
        self.shape = (camera.height, camera.width)
        rays = camera_unit_rays(camera).reshape(-1, 3)
        rng = road_distance_m(rays, mount.K0)
        self._range_m = np.where(np.isfinite(rng) & (rng >= 0), rng, np.inf).reshape(self.shape)
        R = mount.R_car_cam
        self._speed_dir = np.zeros(9)
        self._speed_dir[V_SLICE] = R[0]  # forward speed = R_car_cam[0] . V
        self._yaw_dir = np.zeros(9)
        self._yaw_dir[W_SLICE] = np.degrees(R[2])  # yaw rate [deg/s] = R_car_cam[2] . W
        self.speed_map = np.zeros(self.shape)  # (H, W) summed pulls [m/s]
        self.yaw_map = np.zeros(self.shape)  # (H, W) [deg/s]
        n = len(RANGE_BANDS_M) - 1
        self._band = np.zeros((n, 3))  # points, speed pull, yaw pull per band
        self.pairs = 0

    def add(self, pull: PointPull | None) -> None:
        """One pair's `DirectEstimator.point_pull` at its true state (None: no fit, skipped)."""
        if pull is None or len(pull.points_px) == 0:
            return
        h, w = self.shape
        u = np.clip(np.rint(pull.points_px[:, 0]).astype(int), 0, w - 1)
        v = np.clip(np.rint(pull.points_px[:, 1]).astype(int), 0, h - 1)
        speed, yaw = pull.dx @ self._speed_dir, pull.dx @ self._yaw_dir
        np.add.at(self.speed_map, (v, u), speed)
        np.add.at(self.yaw_map, (v, u), yaw)
        n = len(self._band)
        band = np.clip(
            np.searchsorted(RANGE_BANDS_M, self._range_m[v, u], side="right") - 1, 0, n - 1
        )
        for j, weights in enumerate((None, speed, yaw)):  # points, speed and yaw pulls
            self._band[:, j] += np.bincount(band, weights, minlength=n)
        self.pairs += 1

    def summary(self, mean_speed_mps: float) -> dict:
        """{"pairs", "speed_pull_mps", "speed_pull_pct" (of mean_speed_mps),
        "yaw_rate_pull_dps", "by_range": {"0-10 m": {"points_share", "speed_pull_mps",
        "yaw_rate_pull_dps"}, ...}}: means per pair (NaN without pairs)."""
        n = self.pairs
        nan = float("nan")
        speed = float(self.speed_map.sum()) / n if n else nan
        pct = 100.0 * speed / mean_speed_mps if n and mean_speed_mps > 0 else nan
        total = self._band[:, 0].sum()
        bands = {}
        for (lo, hi), (pts, sp, yw) in zip(
            zip(RANGE_BANDS_M[:-1], RANGE_BANDS_M[1:], strict=True), self._band, strict=True
        ):
            name = f"{lo:g}-{hi:g} m" if math.isfinite(hi) else f"{lo:g}+ m"
            bands[name] = {
                "points_share": float(pts / total) if total else nan,
                "speed_pull_mps": float(sp) / n if n else nan,
                "yaw_rate_pull_dps": float(yw) / n if n else nan,
            }
        return {
            "pairs": n,
            "speed_pull_mps": speed,
            "speed_pull_pct": pct,
            "yaw_rate_pull_dps": float(self.yaw_map.sum()) / n if n else nan,
            "by_range": bands,
        }

    def write_png(self, path: Path, background: np.ndarray) -> None:
        """Two panels over ``background`` (H, W) or (H, W, 3) uint8, a frame of the drive:
        the forward-speed pull and the yaw-rate pull per pair, smoothed (Gaussian, 1 % of
        the width), red where the images pull the value down, green up, each scaled to its
        own largest magnitude (stated on the panel)."""
        bg = np.asarray(background)
        gray = bg if bg.ndim == 2 else cv2.cvtColor(bg, cv2.COLOR_RGB2GRAY)
        sigma = max(1.5, 0.01 * self.shape[1])
        n = max(self.pairs, 1)
        panels = []
        for name, unit, total_map in (
            ("forward speed", "m/s", self.speed_map),
            ("yaw rate", "deg/s", self.yaw_map),
        ):
            dens = cv2.GaussianBlur(total_map / n, (0, 0), sigma)  # per pair, smoothed
            peak = float(np.abs(dens).max())
            rgb = np.repeat(0.5 * gray[..., None].astype(np.float32), 3, axis=2)
            if peak > 0:
                rgb[..., 0] += 255.0 * np.clip(-dens / peak, 0.0, 1.0)  # down: red
                rgb[..., 1] += 255.0 * np.clip(dens / peak, 0.0, 1.0)  # up: green
            img = np.clip(rgb, 0, 255).astype(np.uint8)
            total = float(total_map.sum()) / n
            for row, text in enumerate(
                (f"pull on the {name}: {total:+.3g} {unit} per pair", "red: down, green: up")
            ):
                cv2.putText(
                    img,
                    text,
                    (8, 20 + 18 * row),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.5,
                    (255, 255, 255),
                    1,
                    cv2.LINE_AA,
                )
            panels.append(img)
        write_png(path, np.concatenate(panels, axis=1))
