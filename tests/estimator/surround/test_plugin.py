"""Surround detectors from outside the project behind the analyzer's interface."""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DetectorConfig
from estimator.surround.plugin import PluginSurround, check_detector, make_surround

PLUGIN_SRC = '''
class Fixed:
    """One vehicle 12 m ahead, as a dict with a box; a second as an object."""
    def __init__(self, camera, mount, ahead_m=12.0):
        self.ahead_m = ahead_m
    def step(self, frame, t_s, image, x, dt_s, speed_mps, yaw_rate_rps):
        class T:
            track_id, x_m, y_m = 8, -9.0, 3.5
        return [{"track_id": 3, "x_m": self.ahead_m, "y_m": 0.0, "vx_mps": 1.0,
                 "box_x_m": self.ahead_m + 2.3, "box_y_m": 0.0, "box_yaw_rad": 0.0,
                 "box_length_m": 4.7, "box_width_m": 1.9}, T()]

class Broken:
    def __init__(self, camera, mount):
        pass
    def step(self, frame, t_s, image, x, dt_s, speed_mps, yaw_rate_rps):
        return [{"track_id": 1, "x_m": float("nan"), "y_m": 0.0}]

class OldStyle:
    def __init__(self, camera, mount):
        pass
    def step(self, image):
        return []
'''


@pytest.fixture()
def plugins(tmp_path: Path, monkeypatch):
    (tmp_path / "my_detectors.py").write_text(PLUGIN_SRC)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("my_detectors", None)


def test_plugin_tracks_are_read_as_the_analyzers(plugins):
    cam, mount = load_camera("omni-near")
    sur = make_surround("my_detectors:Fixed", cam, mount, DetectorConfig(), ahead_m=15.0)
    assert isinstance(sur, PluginSurround)
    img = np.zeros((cam.height, cam.width, 3), np.uint8)
    for k in range(3):
        sf = sur.step(k, k / 15, img, np.zeros(9), 1 / 15, 20.0, 0.0)
    a, b = sf.tracks
    assert (a.id, *a.x[:3]) == (3, 15.0, 0.0, 1.0) and math.isnan(a.x[3])
    assert len(a.history) == 3 and np.isnan(a.P).all()
    assert sur.track_box(a).x_m == pytest.approx(17.3) and sur.track_box(b) is None
    assert np.isnan(sur.track_position_cov(a)).all()  # a plug-in gives no covariance
    assert [(d.x_m, d.y_m) for d in sf.detection.detections] == [(15.0, 0.0), (-9.0, 3.5)]
    assert isinstance(make_surround("paper", cam, mount, DetectorConfig()), SurroundAnalyzer)


def test_wrong_detector_plugins_and_outputs_are_named(plugins):
    with pytest.raises(ValueError, match=r"OldStyle.step\(self, image\) does not accept"):
        check_detector("my_detectors:OldStyle")
    with pytest.raises(ValueError, match="unknown detector 'yolo'"):
        check_detector("yolo")
    cam, mount = load_camera("omni-near")
    sur = make_surround("my_detectors:Broken", cam, mount, DetectorConfig())
    img = np.zeros((cam.height, cam.width, 3), np.uint8)
    with pytest.raises(ValueError, match="frame 4, track 0: track_id 1 must be >= 0"):
        sur.step(4, 0.3, img, np.zeros(9), 1 / 15, 20.0, 0.0)


def test_a_run_scores_a_plugin_detector(plugins, tmp_path: Path):
    """A short run with the plug-in: its tracks in tracks.csv with their boxes, scored."""
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    sc = load_scenario("highway-omni-near")
    with pytest.raises(ValueError, match="vehicle_mask is for the built-in detectors"):
        run_scenario(sc, tmp_path / "x", detector="my_detectors:Fixed", vehicle_mask="gt")
    m = run_scenario(
        sc, tmp_path, max_frames=6, progress=False, video=False, detector="my_detectors:Fixed"
    )
    assert m["detector"] == "my_detectors:Fixed"
    rows = list(csv.DictReader(open(tmp_path / "tracks.csv")))
    assert {r["track_id"] for r in rows} == {"3", "8"} and len(rows) == 12
    assert {float(r["box_x_m"]) for r in rows if r["track_id"] == "3"} == {14.3}
    assert m["track_detection"]["gt_count"] > 0 and math.isfinite(m["tracking"]["mota"])
