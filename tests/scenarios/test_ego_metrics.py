"""Consistency of the estimator's printed covariance against the truth (NEES)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.camera_io import load_camera
from scenarios.metrics import ego_consistency


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_nees_of_speed_and_yaw_rate_in_car_axes(preset):
    """Errors of 0.2 m/s forward and 0.01 rad/s of yaw rate against stds of 0.1 and 0.02
    in car axes: NEES 4 and 0.25, whatever the camera's mount."""
    _, mount = load_camera(preset)
    R = mount.R_car_cam
    V_true, W_true = R.T @ np.array([20.0, 0.0, 0.0]), R.T @ np.array([0.0, 0.0, 0.1])
    x = np.concatenate(
        [R.T @ np.array([20.2, 0.0, 0.0]), R.T @ np.array([0.0, 0.0, 0.11]), [0, 0, 0]]
    )
    P = np.eye(9)
    P[0:3, 0:3] = R.T @ np.diag([0.1**2, 1.0, 1.0]) @ R
    P[3:6, 3:6] = R.T @ np.diag([1.0, 1.0, 0.02**2]) @ R
    gt = [
        {"frame": 0, "motion_from_prev": None},
        {"frame": 1, "motion_from_prev": {"V_mps": V_true.tolist(), "W_rps": W_true.tolist()}},
    ]
    recs = [SimpleNamespace(frame=0, x=x, P=P), SimpleNamespace(frame=1, x=x, P=P)]
    c = ego_consistency(recs, gt, mount)
    assert c["speed_nees"] == pytest.approx(4.0)
    assert c["yaw_rate_nees"] == pytest.approx(0.25)
    assert math.isnan(ego_consistency(recs[:1], gt, mount)["speed_nees"])
