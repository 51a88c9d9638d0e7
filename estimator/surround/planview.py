"""Plan (top) view of the road around the car: the flat-plane transform.

Each plan-view cell is a point on the road in the ego road frame (x forward,
y left, origin on the road under the camera viewpoint, metres); its pixel in
the camera image comes from the mount and the camera model, so the lookup is
computed once per camera and each frame costs one ``cv2.remap``.

Plan-view image axes: row 0 is the farthest point ahead (x = +range), column 0
the farthest point to the left (y = +range); the car sits in the centre,
driving up.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount


@dataclass
class PlanView:
    """Lookup from the road plane around the car to camera pixels.

    range_m: half-size of the square view [m]; m_per_px: resolution [m/px].
    map_x, map_y: (S, S) float32 camera pixel of each cell (-1 where unseen).
    seen: (S, S) bool, cells whose road point the camera sees (valid ray).
    """

    range_m: float
    m_per_px: float
    map_x: np.ndarray
    map_y: np.ndarray
    seen: np.ndarray

    @classmethod
    def build(
        cls, camera: CameraModel, mount: CameraMount, range_m: float = 30.0, m_per_px: float = 0.1
    ) -> PlanView:
        if range_m <= 0 or m_per_px <= 0:
            raise ValueError(
                f"plan view needs range_m > 0 and m_per_px > 0, got {range_m}, {m_per_px}"
            )
        size = int(round(2 * range_m / m_per_px))
        x, y = cls._grid(range_m, m_per_px, size)
        cam_xy = np.asarray(mount.position_m[:2])
        p_car = np.stack([x + cam_xy[0], y + cam_xy[1], np.zeros_like(x)], axis=-1).reshape(-1, 3)
        P_cam = (p_car - np.asarray(mount.position_m)) @ mount.R_car_cam  # R_cam_car @ (p - t)
        w = camera.project(P_cam)
        ok = camera.valid_rays(P_cam) & np.all(np.isfinite(w), axis=1)
        w[~ok] = -1.0
        map_x = w[:, 0].reshape(size, size).astype(np.float32)
        map_y = w[:, 1].reshape(size, size).astype(np.float32)
        return cls(range_m, m_per_px, map_x, map_y, ok.reshape(size, size))

    @staticmethod
    def _grid(range_m: float, m_per_px: float, size: int) -> tuple[np.ndarray, np.ndarray]:
        c = (np.arange(size) + 0.5) * m_per_px
        x = (range_m - c)[:, None] * np.ones((1, size))  # forward decreases down the rows
        y = np.ones((size, 1)) * (range_m - c)[None, :]  # left decreases along the columns
        return x, y

    @property
    def size(self) -> int:
        return self.map_x.shape[0]

    def warp(self, image: np.ndarray, nearest: bool = False) -> np.ndarray:
        """Plan view (S, S[, C]) of a camera image; unseen cells are 0."""
        interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
        return cv2.remap(
            image, self.map_x, self.map_y, interp, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )

    def to_road(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 2) road points (x fwd, y left) [m] of plan-view pixel centres."""
        x = self.range_m - (np.asarray(rows, float) + 0.5) * self.m_per_px
        y = self.range_m - (np.asarray(cols, float) + 0.5) * self.m_per_px
        return np.stack([x, y], axis=-1)

    def to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) plan-view (col, row) of road points (x fwd, y left) [m]."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        col = (self.range_m - xy[:, 1]) / self.m_per_px - 0.5
        row = (self.range_m - xy[:, 0]) / self.m_per_px - 0.5
        return np.stack([col, row], axis=-1)


def pixel_road_xy(camera: CameraModel, mount: CameraMount) -> np.ndarray:
    """(H, W, 2) float32 road point (x fwd, y left) [m] in the ego road frame of each
    pixel's ray (inverse perspective); NaN where the ray does not meet the road."""
    rays = camera.unproject(camera.pixel_grid().reshape(-1, 2))  # float64: far points
    with np.errstate(divide="ignore", invalid="ignore"):
        s = rays @ np.asarray(mount.K0, float)  # K0^T P: 1 on the road
        P = rays / s[:, None]
    p_car = P @ mount.R_car_cam.T + np.asarray(mount.position_m)
    xy = p_car[:, :2] - np.asarray(mount.position_m[:2])
    xy[~(s > 0) | ~camera.valid_rays(rays)] = np.nan
    return xy.reshape(camera.height, camera.width, 2).astype(np.float32)
