"""Surround analysis of one frame: compensation, detection, tracking (section 5).

`SurroundAnalyzer.step` takes the current frame and the ego-motion estimate
since the previous one, keeps the few earlier frames the detector compares
with, and returns the detections and the vehicle tracks in the ego road frame
(x forward, y left, origin on the road under the camera viewpoint).

Which candidates are vehicles. The detector's candidates are blobs that move
unlike any static point (`estimator.surround.detection`), but rendered roadside
structure (periodic guard-rail posts, aliased lane marks, trees against the
sky) sometimes fits the "moving" hypothesis better by chance, in a frame or
two, at a place that recurs because the scene repeats. An independently
moving vehicle does so in (nearly) every frame, at positions that follow one
motion. So every candidate is tracked (`estimator.surround.tracking`), and a track is a
*vehicle* once it is confirmed and its hit rate, an exponential average of
"detected this frame" (1) or not (0) with weight `SurroundConfig.hit_rate_alpha`,
reaches `vehicle_on` over at least `vehicle_min_hits` hits; it stays one while
the rate is above `vehicle_off` (hysteresis). The frame's reported detections
are the candidates assigned to vehicle tracks, placed at their track's Kalman
posterior of the frame (`SurroundConfig.report_filtered`: a single frame's
nearest point jitters by 2-3 px, ~1-2 m at 15-20 m); the reported tracks are
the vehicle tracks that were detected within the last `max_coast_frames` frames.
Each candidate keeps what this decision made of its track (`Detection.track_state`,
`TRACK_STATES`), so that an evaluation can tell which rule lost a vehicle it found.

A candidate whose ground point is hidden (car-body mask) is a bearing-only
measurement for the tracker; once assigned to a track, its reported position is
the track's, moved onto the measured bearing.

A vehicle's box. The detector fits a car-sized box to the lower outline it sees
(`estimator.surround.boxfit`), and one frame's outline often leaves the heading
ambiguous (one face seen: the rear or a side?). A vehicle track that knows the
direction of its velocity over the ground (at least `heading_min_speed_mps`, std at
most `heading_max_sigma_rad`) decides it: the box takes that heading (to the fit's
1-deg step), and the outline places it along it. The box is reported beside the point.

The road a vehicle uncovered. The detector's blob holds, besides the vehicle, the road
it uncovered over the detector's baseline, and a vehicle driving away from the camera is
seen up to its own displacement over that baseline nearer than it is. With
`SurroundConfig.uncovered_road` the tracker measures each candidate that was not refined
onto the vehicle's own moving edge as the nearest point of the vehicle swept back along its
ground velocity (`estimator.surround.tracking`): the tracked point is the vehicle's own
nearest point, and the box fitted to what the camera saw is kept where it was fitted.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, replace

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.compensation import FrameCompensator
from estimator.surround.boxfit import Box, BoxFitConfig, fit_box
from estimator.surround.detection import (
    Detection,
    DetectionFrame,
    DetectorConfig,
    VehicleDetector,
)
from estimator.surround.tracking import Track, Tracker, TrackerConfig, swept_measurement

# What the tracker made of a candidate (`Detection.track_state`): its track is a vehicle
# (reported); or not yet confirmed (M of N); or confirmed with fewer than
# `SurroundConfig.vehicle_min_hits` hits; or with enough hits but a hit rate below
# `vehicle_on` (or fallen below `vehicle_off`)
TRACK_STATES = ("vehicle", "tentative", "young", "intermittent")


@dataclass(frozen=True)
class SurroundConfig:
    """Which tracks are vehicles (units beside each value)."""

    hit_rate_alpha: float = 0.25  # [-] weight of the current frame in the hit-rate average
    vehicle_on: float = 0.85  # [-] hit rate from which a confirmed track is a vehicle
    vehicle_off: float = 0.45  # [-] hit rate below which it is no longer one
    vehicle_min_hits: int = 5  # [frames] hits before a track can be a vehicle
    max_coast_frames: int = 2  # [frames] a vehicle track missed longer is not reported
    # a vehicle's reported position: the track's Kalman posterior of this frame (its
    # detection filtered with the earlier ones), not the single-frame detection; a hidden
    # one (bearing only) is reported on its measured bearing at the track's range
    report_filtered: bool = True  # [-]
    # a detection is the nearest point of the vehicle and the road it uncovered over the
    # detector's baseline (`estimator.surround.tracking`); False: of the vehicle alone
    uncovered_road: bool = True  # [-]
    # a vehicle's box heading from its track: the direction of its velocity over the ground,
    # where the track knows it (speed and its std below); else from the box fit alone
    heading_min_speed_mps: float = 3.0  # [m/s] slower tracks: heading from the fit alone
    heading_max_sigma_rad: float = 0.35  # [rad] a less certain heading is not used

    def __post_init__(self) -> None:
        if not (0 < self.hit_rate_alpha <= 1 and 0 <= self.vehicle_off <= self.vehicle_on <= 1):
            raise ValueError(
                f"SurroundConfig: need 0 < alpha <= 1 and 0 <= off <= on <= 1, "
                f"got {self.hit_rate_alpha}, {self.vehicle_off}, {self.vehicle_on}"
            )
        if not (self.heading_min_speed_mps > 0 and self.heading_max_sigma_rad > 0):
            raise ValueError(
                f"SurroundConfig: heading_min_speed_mps and heading_max_sigma_rad must be > 0, "
                f"got {self.heading_min_speed_mps}, {self.heading_max_sigma_rad}"
            )


@dataclass
class SurroundFrame:
    """Result of one frame: detection internals and the vehicle tracks."""

    frame: int
    t_s: float
    detection: DetectionFrame
    tracks: list[Track]
    compensated: np.ndarray | None = None  # kept for compatibility (not computed)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) float32 grey of an RGB (H, W, 3) or grey (H, W) image."""
    img = np.asarray(image)
    if img.ndim == 3:
        if img.dtype == np.uint8:
            if img.strides[-1] < 0:  # a reversed view of a BGR image (cv2.imread()[..., ::-1])
                return cv2.cvtColor(img[..., ::-1], cv2.COLOR_BGR2GRAY).astype(np.float32)
            return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY).astype(np.float32)
        img = img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114
    return img.astype(np.float32)


class SurroundAnalyzer:
    """Detector + tracker for one camera; keeps the earlier frames it needs."""

    def __init__(
        self,
        camera: CameraModel,
        mount: CameraMount,
        detector: DetectorConfig | None = None,
        tracker: TrackerConfig | None = None,
        surround: SurroundConfig | None = None,
    ) -> None:
        self.camera, self.mount = camera, mount
        self.compensator = FrameCompensator(camera, mount)
        self.detector = VehicleDetector(camera, mount, detector, self.compensator)
        self.tracker = Tracker(tracker)
        self._box_cfg = BoxFitConfig(size_m=self.detector.cfg.hidden_box_m)
        self.cfg = surround or SurroundConfig()
        n = self.detector.cfg.baseline_frames
        self._frames: deque[np.ndarray] = deque(maxlen=n + 1)
        self._full: deque[np.ndarray] = deque(maxlen=n + 1)
        self._steps: deque[tuple[np.ndarray, float]] = deque(maxlen=n)
        self._rate: dict[int, float] = {}  # track id -> hit rate
        self._track_s = 0.0  # [s] the last step's tracker and vehicle flags
        self._vehicle: set[int] = set()  # ids of tracks that are vehicles
        self._baseline_s = 0.0  # [s] the detector's baseline of the current frame
        # track id -> its latest box, relative to the tracked point: (dx, dy) [m], yaw [rad],
        # length, width [m]
        self._box: dict[int, tuple[float, float, float, float, float]] = {}

    def step(
        self,
        frame: int,
        t_s: float,
        image: np.ndarray,
        x: np.ndarray,
        dt_s: float,
        speed_mps: float,
        yaw_rate_rps: float,
        vehicle_mask: np.ndarray | None = None,
    ) -> SurroundFrame | None:
        """Analyse ``image`` given the estimate x (9,) of the motion since the last call.

        vehicle_mask: (H, W) bool, the pixels that see a vehicle, given instead of the
        detector's motion test (a diagnostic ceiling, `VehicleDetector.detect`).
        Returns None for the first frame (nothing to compare with).
        """
        gray = to_gray(image)
        small = self.detector.prepare(gray)
        if not (dt_s > 0 and np.all(np.isfinite(x))):
            # no usable motion: restart the history from this frame
            self._frames.clear()
            self._full.clear()
            self._steps.clear()
            self._frames.append(small)
            self._full.append(gray)
            return None
        self._frames.append(small)
        self._full.append(gray)
        if len(self._frames) < 2:
            return None
        self._steps.append((np.asarray(x, float).copy(), float(dt_s)))
        steps = list(self._steps)[-(len(self._frames) - 1) :]
        det = self.detector.detect(
            small,
            self._frames[0],
            steps,
            gray,
            self._full[0],
            vehicle_mask=vehicle_mask,
            middle_full=self._full[-2] if len(self._full) > 2 else None,
        )
        cands = det.candidates
        t_track = time.perf_counter()
        xy = np.array([[d.x_m, d.y_m] for d in cands]).reshape(-1, 2)
        self._baseline_s = sum(dt for _, dt in steps)
        self.tracker.step(
            t_s,
            xy,
            speed_mps,
            yaw_rate_rps,
            extras=cands,
            bearing_only=[d.hidden for d in cands],
            swept_s=[self._swept_s(d) for d in cands],
        )
        det.detections = self._classify(cands)
        self._track_s = time.perf_counter() - t_track
        tracks = [
            t
            for t in self.tracker.tracks
            if t.id in self._vehicle and t.misses <= self.cfg.max_coast_frames
        ]
        return SurroundFrame(frame, t_s, det, tracks)

    @property
    def stage_seconds(self) -> dict[str, float]:
        """[s] the last step's time by stage: the detector's (`VehicleDetector.clock`:
        warps, score, blobs, refine), then the tracker's ("track")."""
        return {**self.detector.clock.seconds, "track": self._track_s}

    def _classify(self, cands: list) -> list:
        """Update the hit rates and vehicle flags; the candidates of vehicle tracks."""
        cfg = self.cfg
        live = self.tracker.tracks
        ids = {t.id for t in live}
        self._rate = {i: r for i, r in self._rate.items() if i in ids}
        self._box = {i: b for i, b in self._box.items() if i in ids}
        self._vehicle &= ids
        out = []
        this_frame = {id(c) for c in cands}  # the frame's candidates (alive: ids unique)
        for t in live:
            hit = t.misses == 0
            r = self._rate.get(t.id)
            r = 1.0 if r is None else (1 - cfg.hit_rate_alpha) * r + cfg.hit_rate_alpha * hit
            self._rate[t.id] = r
            if t.id in self._vehicle:
                if r < cfg.vehicle_off:
                    self._vehicle.discard(t.id)
            elif t.confirmed and t.hits >= cfg.vehicle_min_hits and r >= cfg.vehicle_on:
                self._vehicle.add(t.id)
            held = hit and id(t.extra) in this_frame  # it holds a candidate of this frame
            if held:
                t.extra.track_state = self._track_state(t)
            if held and t.id in self._vehicle:
                d = t.extra
                heading = self._track_heading(t)
                if not d.hidden and d.outline_xy is not None:
                    # the box of its lower outline, along the track's heading once it is
                    # known (only a vehicle's detections are fitted: the other candidates'
                    # boxes would not be read)
                    if heading is not None:
                        d.box = fit_box(d.outline_xy, self._box_cfg, heading[0], 0.0) or d.box
                    elif d.box is None:
                        d.box = fit_box(d.outline_xy, self._box_cfg)
                if d.box is not None:
                    b = d.box
                    # the box where it was fitted: the detection lies the uncovered road
                    # behind the tracked point
                    sweep = self._sweep(t, self._swept_s(d))
                    self._box[t.id] = (
                        b.x_m - d.x_m - sweep[0],
                        b.y_m - d.y_m - sweep[1],
                        b.yaw_rad,
                        b.length_m,
                        b.width_m,
                    )
                if cfg.report_filtered and not d.hidden:
                    d.x_m, d.y_m = float(t.x[0]), float(t.x[1])
                elif d.hidden:  # bearing only: the track's range on the measured bearing
                    u = np.array([math.cos(d.bearing_rad), math.sin(d.bearing_rad)])
                    r_along = max(float(t.x[:2] @ u), 0.0)
                    d.x_m, d.y_m = float(r_along * u[0]), float(r_along * u[1])
                if d.box is not None:  # moved with the reported point
                    dx, dy = self._box[t.id][:2]
                    d.box = replace(d.box, x_m=d.x_m + dx, y_m=d.y_m + dy)
                out.append(d)
        return out

    def _track_state(self, track: Track) -> str:
        """One of `TRACK_STATES`: what the vehicle decision made of a live track."""
        if track.id in self._vehicle:
            return "vehicle"
        if not track.confirmed:
            return "tentative"
        return "young" if track.hits < self.cfg.vehicle_min_hits else "intermittent"

    def _track_heading(self, track: Track) -> tuple[float, float] | None:
        """(heading, its std) [rad] of a track's velocity over the ground, or None where
        the track is too slow or its direction too uncertain."""
        v = np.asarray(track.x[2:4], float)
        speed = float(np.hypot(*v))
        if speed < self.cfg.heading_min_speed_mps:
            return None
        across = np.array([-v[1], v[0]]) / speed  # unit vector across the velocity
        sigma = math.sqrt(max(float(across @ track.P[2:4, 2:4] @ across), 0.0)) / speed
        if sigma > self.cfg.heading_max_sigma_rad:
            return None
        return math.atan2(v[1], v[0]), sigma

    def _swept_s(self, det: Detection) -> float:
        """[s] the time over which ``det``'s point may lie on the road its vehicle uncovered
        (`Tracker.step`): the baseline (uncovered_road), but 0 for a refined point, which
        lies on the vehicle's own moving edge (`VehicleDetector._refine`)."""
        if not self.cfg.uncovered_road or det.outline_xy is not None:
            return 0.0
        return self._baseline_s

    @staticmethod
    def _sweep(track: Track, swept_s: float) -> np.ndarray:
        """(2,) [m] the tracked point less where it expects a detection (`swept_measurement`)."""
        H = swept_measurement(track.x[None], np.array([swept_s]))[0, 0]
        return track.x[:2] - H @ track.x

    def track_position_cov(self, track: Track) -> np.ndarray:
        """(2, 2) [m²] covariance of a track's reported point: the filter's, plus one
        measurement's (`Tracker.measurement_cov` at the point, bearing-only where its last
        detection's ground was hidden). The detector's error persists from frame to frame
        (the same part of the vehicle is its nearest visible point for many frames), which
        the filter, treating it as white, averages away; one frame's error is its bound."""
        hidden = bool(getattr(track.extra, "hidden", False))
        return track.P[:2, :2] + self.tracker.measurement_cov(track.x[:2], hidden)

    def track_box(self, track: Track) -> Box | None:
        """The vehicle box of a track (its latest fitted box, kept at the same offset from
        the tracked point); None before the track had one."""
        b = self._box.get(track.id)
        if b is None:
            return None
        dx, dy, yaw, length, width = b
        x, y = float(track.x[0]), float(track.x[1])
        return Box(x + dx, y + dy, yaw, length, width, float("nan"))
