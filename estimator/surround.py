"""Surround analysis of one frame: compensation, detection, tracking (section 5).

`SurroundAnalyzer.step` takes the current frame, the previous one and the
ego-motion estimate between them, and returns the detections and the
confirmed tracks in the ego road frame (x forward, y left, origin on the road
under the camera viewpoint).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.camera import CameraModel
from estimator.compensation import FrameCompensator
from estimator.detection import DetectionFrame, DetectorConfig, VehicleDetector
from estimator.mount import CameraMount
from estimator.tracking import Track, Tracker, TrackerConfig


@dataclass
class SurroundFrame:
    """Result of one frame: detection internals and the confirmed tracks."""

    frame: int
    t_s: float
    detection: DetectionFrame
    tracks: list[Track]
    compensated: np.ndarray  # (H, W) float32 previous frame warped onto this one


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 grey of an RGB (H, W, 3) or grey (H, W) image."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114
    return img.astype(np.float32)


class SurroundAnalyzer:
    """Detector + tracker for one camera; keeps the previous frame."""

    def __init__(
        self,
        camera: CameraModel,
        mount: CameraMount,
        detector: DetectorConfig | None = None,
        tracker: TrackerConfig | None = None,
    ) -> None:
        self.camera, self.mount = camera, mount
        self.compensator = FrameCompensator(camera, mount)
        self.detector = VehicleDetector(camera, mount, detector)
        self.tracker = Tracker(tracker)
        self._prev: np.ndarray | None = None

    def step(
        self,
        frame: int,
        t_s: float,
        image: np.ndarray,
        x: np.ndarray,
        dt_s: float,
        speed_mps: float,
        yaw_rate_rps: float,
    ) -> SurroundFrame | None:
        """Analyse ``image`` given the estimate x (9,) of the motion since the last call.

        Returns None for the first frame (nothing to compare with).
        """
        gray = to_gray(image)
        prev, self._prev = self._prev, gray
        if prev is None or not dt_s > 0 or not np.all(np.isfinite(x)):
            return None
        warped, ok = self.compensator.warp(prev, x, dt_s)
        det = self.detector.detect(gray, warped, ok)
        xy = np.array([[d.x_m, d.y_m] for d in det.detections]).reshape(-1, 2)
        tracks = self.tracker.step(t_s, xy, speed_mps, yaw_rate_rps, extras=det.detections)
        return SurroundFrame(frame, t_s, det, list(tracks), warped)
