"""A surround detector/tracker from outside the project, behind the analyzer's interface.

`make_surround` builds the shipped `SurroundAnalyzer` for the built-in detector methods
and a `PluginSurround` for a plug-in (`estimator.plugins`: ``package.module:ClassName`` or
an ``omnibench.detectors`` entry point), so that a run scores either the same way. The
plug-in's tracks are its reported vehicles; they are also scored as its detections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.plugins import DETECTOR_GROUP, check_detector_class, is_plugin_name, load_class
from estimator.surround.analyzer import SurroundAnalyzer, SurroundFrame
from estimator.surround.boxfit import Box
from estimator.surround.detection import DETECTOR_METHODS, Detection, DetectionFrame, DetectorConfig
from estimator.surround.planview import PlanView

BOX_FIELDS = ("box_x_m", "box_y_m", "box_yaw_rad", "box_length_m", "box_width_m")


def check_detector(name: str) -> str:
    """``name`` if it is a built-in detector method or a plug-in that follows the protocol;
    ValueError naming it and what is wrong otherwise."""
    if name in DETECTOR_METHODS:
        return name
    if is_plugin_name(name, DETECTOR_GROUP):
        check_detector_class(load_class(name, DETECTOR_GROUP), name)
        return name
    raise ValueError(
        f"unknown detector {name!r}; choose one of {', '.join(DETECTOR_METHODS)} or a plug-in "
        "package.module:ClassName"
    )


def check_pixel_model(path: str | Path | None, detector: str) -> None:
    """A classifier file for the "learned" detector (None: the built-in one): ValueError,
    before any work, for a file given with another detector or one that cannot be loaded
    (missing, or not a model `PixelClassifier` reads)."""
    if path is None:
        return
    if detector != "learned":
        raise ValueError(f"--pixel-model is for --detector learned, not {detector!r}")
    from estimator.surround.pixel_classifier import PixelClassifier

    try:
        PixelClassifier.load(path)
    except FileNotFoundError as e:
        raise ValueError(str(e)) from e


def make_surround(
    name: str, camera: CameraModel, mount: CameraMount, config: DetectorConfig, **settings: Any
):
    """The surround analysis ``name`` (a built-in method: `SurroundAnalyzer` with
    ``config``; a plug-in: `PluginSurround` with its keyword ``settings``)."""
    check_detector(name)
    if name in DETECTOR_METHODS:
        return SurroundAnalyzer(camera, mount, replace(config, method=name))
    return PluginSurround(
        load_class(name, DETECTOR_GROUP)(camera, mount, **settings), camera, mount
    )


@dataclass
class PluginTrack:
    """A plug-in's track, as the runner reads a `Track`: id, x (4,) = (x, y, vx, vy) [m,
    m/s] in the ego road frame (velocity NaN when not given), P (4, 4) NaN (not given)."""

    id: int
    x: np.ndarray
    P: np.ndarray = field(default_factory=lambda: np.full((4, 4), np.nan))
    history: list = field(default_factory=list)  # (t_s, x_m, y_m)


def _field(obj: Any, key: str) -> Any:
    return obj.get(key) if isinstance(obj, dict) else getattr(obj, key, None)


class PluginSurround:
    """A plug-in detector/tracker with `SurroundAnalyzer`'s interface (module docstring)."""

    def __init__(self, impl: Any, camera: CameraModel, mount: CameraMount) -> None:
        self.impl, self.camera = impl, camera
        # what the runner's pictures draw on
        self.detector = SimpleNamespace(
            plan=PlanView.build(camera, mount, 30.0, 0.1), valid=camera.valid_mask()
        )
        self._history: dict[int, list] = {}
        self._box: dict[int, Box] = {}

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
    ) -> SurroundFrame:
        if vehicle_mask is not None:
            raise ValueError("a given vehicle mask is for the built-in detector, not a plug-in")
        out = self.impl.step(frame, t_s, image, x, dt_s, speed_mps, yaw_rate_rps)
        tracks, dets, seen = [], [], set()
        for i, o in enumerate(out or []):
            tid, xm, ym = (_field(o, k) for k in ("track_id", "x_m", "y_m"))
            try:
                tid, xm, ym = int(tid), float(xm), float(ym)
            except (TypeError, ValueError):
                raise ValueError(
                    f"detector plug-in, frame {frame}, track {i}: needs track_id (int), x_m "
                    f"and y_m (numbers), got {o!r}"
                ) from None
            if tid < 0 or tid in seen or not (math.isfinite(xm) and math.isfinite(ym)):
                raise ValueError(
                    f"detector plug-in, frame {frame}, track {i}: track_id {tid} must be >= 0 "
                    f"and unique, x_m, y_m finite; got {o!r}"
                )
            seen.add(tid)
            v = [_field(o, k) for k in ("vx_mps", "vy_mps")]
            vel = [float(a) if a is not None else math.nan for a in v]
            hist = self._history.setdefault(tid, [])
            hist.append((t_s, xm, ym))
            tr = PluginTrack(tid, np.array([xm, ym, *vel]), history=hist)
            b = [_field(o, k) for k in BOX_FIELDS]
            box = None
            if all(a is not None for a in b) and all(math.isfinite(float(a)) for a in b):
                box = Box(*(float(a) for a in b), math.nan)
                self._box[tid] = box
            tracks.append(tr)
            dets.append(Detection(xm, ym, 0.0, (0, 0, 0, 0), box=box))
        self._history = {k: h for k, h in self._history.items() if k in seen}
        self._box = {k: b for k, b in self._box.items() if k in seen}
        h, w = self.camera.height, self.camera.width
        zero = np.zeros((h, w), np.float32)
        det = DetectionFrame(dets, lambda: zero, zero > 0, None, dets, None, (w, h))
        return SurroundFrame(frame, t_s, det, tracks)

    def track_box(self, track: PluginTrack) -> Box | None:
        """The box the plug-in gave for the track this frame (None: none)."""
        return self._box.get(track.id)

    def track_position_cov(self, track: PluginTrack) -> np.ndarray:
        """(2, 2) NaN: a plug-in gives no covariance."""
        return track.P[:2, :2]
