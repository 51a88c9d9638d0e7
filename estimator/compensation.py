"""Whole-image ego-motion compensation of the road plane.

The previous frame is warped onto the current one with the estimated state:
each current pixel's ray (precomputed once per camera) is mapped back through
the inverse road homography (eq. 3-4) and projected (eq. 6-8); one
``cv2.remap`` samples the previous frame there. Only pixels with a valid ray
are computed.
"""

from __future__ import annotations

import cv2
import numpy as np

from estimator.camera import CameraModel
from estimator.homography import homography
from estimator.mount import CameraMount


class FrameCompensator:
    """Warps previous frames onto current ones for one camera (rays cached)."""

    def __init__(self, camera: CameraModel, mount: CameraMount) -> None:
        self.camera, self.K0 = camera, mount.K0
        self.valid = camera.valid_mask()
        self._idx = np.flatnonzero(self.valid)
        self._rays = camera.pixel_rays().reshape(-1, 3)[self._idx].astype(np.float64)
        # source validity: a warped pixel must come from inside the other frame's view
        self._valid_u8 = cv2.erode(self.valid.astype(np.uint8), np.ones((3, 3), np.uint8))

    def maps(self, x: np.ndarray, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """(H, W) float32 map_x, map_y into the previous frame (-1 where undefined)."""
        H = homography(np.asarray(x, float), self.K0, dt_s)
        P_prev = self._rays @ np.linalg.inv(H).T  # rays of the current frame, seen before
        w = self.camera.project(P_prev)
        bad = ~(np.all(np.isfinite(w), axis=1) & (P_prev @ self.K0 > 0))
        w[bad] = -1.0
        mx = np.full(self.valid.size, -1.0, np.float32)
        my = np.full(self.valid.size, -1.0, np.float32)
        mx[self._idx], my[self._idx] = w[:, 0], w[:, 1]
        shape = self.valid.shape
        return mx.reshape(shape), my.reshape(shape)

    def warp(
        self, image_prev: np.ndarray, x: np.ndarray, dt_s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Previous frame (H, W) warped onto the current one, and its (H, W) bool validity."""
        mx, my = self.maps(x, dt_s)
        src = np.asarray(image_prev, np.float32)
        out = cv2.remap(
            src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
        )
        ok = (
            cv2.remap(
                self._valid_u8,
                mx,
                my,
                cv2.INTER_NEAREST,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0,
            )
            > 0
        )
        return out, ok & self.valid
