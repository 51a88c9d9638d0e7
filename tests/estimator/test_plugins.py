"""Estimators from outside the project: names, the protocol's checks, entry points."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.egomotion.baselines import check_estimator, make_estimator
from estimator.egomotion.ego_estimator import EgoMotionRecord
from estimator.pipeline import record_row

PLUGIN_SRC = '''
from estimator.egomotion.ego_estimator import EgoMotionRecord

class Constant:
    """Reports the CAN speed and no turning."""
    def __init__(self, camera, mount, gain=1.0):
        self.mount, self.gain, self.k = mount, gain, 0
    def step(self, image, t_s, can_speed_mps):
        self.k += 1
        return EgoMotionRecord.from_rates(self.k - 1, t_s, 0.1, self.gain * can_speed_mps, 0.0,
                                          self.mount)

class NoStep:
    def __init__(self, camera, mount):
        pass

class BadInit:
    def __init__(self):
        pass
    def step(self, image, t_s, can_speed_mps):
        pass

class BadStep:
    def __init__(self, camera, mount):
        pass
    def step(self, image):
        pass

not_a_class = 3
'''


@pytest.fixture()
def plugin_dir(tmp_path: Path, monkeypatch):
    (tmp_path / "my_plugin.py").write_text(PLUGIN_SRC)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("my_plugin", None)


def test_a_plugin_is_named_by_module_and_class_and_built_with_settings(plugin_dir):
    cam, mount = load_camera("omni-near")
    assert check_estimator("my_plugin:Constant") == "my_plugin:Constant"
    est = make_estimator("my_plugin:Constant", cam, mount, gain=2.0)
    rec = est.step(np.zeros((cam.height, cam.width, 3), np.uint8), 0.0, 10.0)
    assert rec.speed_mps == pytest.approx(20.0)


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("my_plugin:Nope", "module 'my_plugin' has no 'Nope'"),
        ("no_such_module:X", "module 'no_such_module' does not import"),
        ("my_plugin:not_a_class", "3 is not a class"),
        ("my_plugin:NoStep", "NoStep has no method step"),
        ("my_plugin:BadInit", r"BadInit\(camera, mount, \*\*settings\) is not accepted"),
        ("my_plugin:BadStep", r"BadStep.step\(self, image\) does not accept"),
        ("my_plugin:", "write it as package.module:ClassName"),
        ("kalman", "unknown estimator 'kalman'; choose one of direct, can-only, features"),
    ],
)
def test_wrong_plugins_are_named_before_anything_runs(plugin_dir, name, match):
    with pytest.raises(ValueError, match=match):
        check_estimator(name)


def test_installed_packages_register_names_by_entry_point(plugin_dir):
    """A package's entry point in omnibench.estimators names its class."""
    dist = plugin_dir / "my_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: my-plugin\nVersion: 0.1\n")
    entry = "[omnibench.estimators]\nconstant = my_plugin:Constant\n"
    (dist / "entry_points.txt").write_text(entry)
    assert check_estimator("constant") == "constant"
    cam, mount = load_camera("omni-near")
    assert type(make_estimator("constant", cam, mount)).__name__ == "Constant"


def test_record_from_rates_writes_the_speed_and_yaw_rate_back():
    """The state of a forward speed and a yaw rate gives them back in egomotion.csv."""
    for preset in ("omni-near", "rectilinear-rear-left"):
        _, mount = load_camera(preset)
        rec = EgoMotionRecord.from_rates(3, 0.2, 0.0667, 21.5, math.radians(4.0), mount, 0.04)
        assert rec.speed_mps == 21.5 and rec.x.shape == (9,)
        R = np.asarray(mount.R_car_cam)
        assert (R @ rec.x[0:3])[0] == pytest.approx(21.5)
        assert (R @ rec.x[3:6])[2] == pytest.approx(math.radians(4.0))
        assert float(R[0] @ rec.P[0:3, 0:3] @ R[0]) == pytest.approx(0.04)
        row = record_row(rec, mount)
        assert float(row[-5]) == pytest.approx(21.5) and float(row[-4]) == pytest.approx(4.0)
