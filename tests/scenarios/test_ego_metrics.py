"""Consistency of the estimator's printed covariance against the truth (NEES)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.camera.files import load_camera
from scenarios.metrics import ego_consistency


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_nees_of_speed_and_yaw_rate_in_car_axes(preset):
    """Errors of 0.2 m/s forward and 0.01 rad/s of yaw rate against stds of 0.1 and 0.02
    in car axes: NEES 4 and 0.25, whatever the camera's mount. A's roll off by 2 std and
    its pitch by 1 (its yaw, off by 10 std, is not in it): (4 + 1) / 2 dof = 2.5."""
    _, mount = load_camera(preset)
    R = mount.R_car_cam
    V_true, W_true = R.T @ np.array([20.0, 0.0, 0.0]), R.T @ np.array([0.0, 0.0, 0.1])
    A_true = R.T @ np.radians([0.2, -0.1, 0.0])
    x = np.concatenate(
        [
            R.T @ np.array([20.2, 0.0, 0.0]),
            R.T @ np.array([0.0, 0.0, 0.11]),
            A_true + R.T @ np.radians([0.1, 0.1, 0.5]),
        ]
    )
    P = np.eye(9)
    P[0:3, 0:3] = R.T @ np.diag([0.1**2, 1.0, 1.0]) @ R
    P[3:6, 3:6] = R.T @ np.diag([1.0, 1.0, 0.02**2]) @ R
    P[6:9, 6:9] = R.T @ np.diag(np.radians([0.05, 0.1, 0.05]) ** 2) @ R
    motion = {"V_mps": V_true.tolist(), "W_rps": W_true.tolist(), "A_rad": A_true.tolist()}
    gt = [{"frame": 0, "motion_from_prev": None}, {"frame": 1, "motion_from_prev": motion}]
    recs = [SimpleNamespace(frame=0, x=x, P=P), SimpleNamespace(frame=1, x=x, P=P)]
    c = ego_consistency(recs, gt, mount)
    assert c["speed_nees"] == pytest.approx(4.0)
    assert c["yaw_rate_nees"] == pytest.approx(0.25)
    assert c["angle_nees"] == pytest.approx(2.5)
    assert math.isnan(ego_consistency(recs[:1], gt, mount)["speed_nees"])


def test_exposure_yaw_rates_are_the_motion_between_mean_headings():
    """Independent model: the heading turns evenly between frames (the simulator's), each
    frame's heading averaged over its exposure samples; the rates between those averages.
    A constant rate is unchanged; a step moves the frames either side of it."""
    from scenarios.metrics import exposure_yaw_rates
    from sim.sensor import exposure_times

    _, mount = load_camera("rectilinear-rear-left")
    dt, T = 1 / 15, 0.01
    w_dps = np.array([np.nan, -5.0, -5.0, -85.0, -50.0, -30.0, -30.0])  # interval (k-1, k)
    t = np.arange(len(w_dps)) * dt
    yaw_rad = np.concatenate([[0.0], np.cumsum(np.radians(w_dps[1:]) * dt)])  # at t_k

    def heading(k: int, tau: float) -> float:  # evenly between frames; the ends extrapolate
        j = k + 1 if (tau > 0 and k + 1 < len(t)) or k == 0 else k - 1
        return yaw_rad[k] + tau / (t[j] - t[k]) * (yaw_rad[j] - yaw_rad[k])

    mean = [np.mean([heading(k, tau) for tau in exposure_times(T)]) for k in range(len(t))]
    expected = np.degrees(np.diff(mean)) / dt
    R = mount.R_car_cam
    gt = [{"frame": 0, "t_s": 0.0, "motion_from_prev": None}] + [
        {
            "frame": k,
            "t_s": float(t[k]),
            "motion_from_prev": {"W_rps": (R.T @ [0, 0, np.radians(w_dps[k])]).tolist()},
        }
        for k in range(1, len(t))
    ]
    got = exposure_yaw_rates(gt, mount, T)
    assert np.allclose([got[k] for k in range(1, len(t))], expected, atol=1e-9)
    assert got[2] == pytest.approx(-5.0 - 0.12 * T * 80 / dt)  # c = 0.12 T: -1.44 deg/s
    assert got[1] == pytest.approx(-5.0) and got[6] == pytest.approx(-30.0)
    assert exposure_yaw_rates(gt, mount, 0.0) == pytest.approx(
        {k: w_dps[k] for k in range(1, len(t))}
    )


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_angle_rmse_is_the_roll_and_pitch_in_car_axes(preset):
    """A's target is the roll and pitch of the camera (its vibration): the state holds A
    in camera axes, which mix roll, pitch and the mount's yaw on a tilted or turned
    camera. Errors of 0.1 deg of roll and 0.3 deg of the mount's yaw (car axes) give an
    A RMSE of sqrt(0.1² / 2) over roll and pitch; the yaw is reported apart."""
    from scenarios.metrics import STATE_COLS, ego_metrics, ego_series

    _, mount = load_camera(preset)
    R = mount.R_car_cam
    A_true = R.T @ np.radians([0.2, -0.2, 0.0])  # camera axes [rad]
    A_est = A_true + R.T @ np.radians([0.1, 0.0, 0.3])
    V = R.T @ np.array([20.0, 0.0, 0.0])
    n = 4
    x = np.concatenate([V, np.zeros(3), A_est])
    est = {"frame": np.arange(n), "t_s": np.arange(n) / 15.0}
    for i, c in enumerate(STATE_COLS):
        est[c] = np.full(n, x[i])
    motion = {"V_mps": V.tolist(), "W_rps": [0.0, 0.0, 0.0], "A_rad": A_true.tolist()}
    gt = [
        {"frame": k, "t_s": k / 15.0, "can_speed_mps": 20.0, "motion_from_prev": motion}
        for k in range(n)
    ]
    s = ego_series(est, gt, mount)
    assert np.allclose(s["A_gt"], [[0.2, -0.2, 0.0]] * n, atol=1e-12)  # roll, pitch, yaw
    m = ego_metrics(s)
    assert m["angle_rmse_deg"] == pytest.approx(0.1 / math.sqrt(2))
    assert m["roll_rmse_deg"] == pytest.approx(0.1)
    assert m["pitch_rmse_deg"] == pytest.approx(0.0, abs=1e-12)
    assert m["angle_yaw_rmse_deg"] == pytest.approx(0.3)
    assert m["prior_angle_rmse_deg"] == pytest.approx(0.2)  # CAN-only: A at the mount


def test_nonfinite_estimates_are_counted_apart_from_the_compared_frames():
    """A frame whose estimate is NaN or infinite is in no RMSE and not in frames_compared:
    frames_nonfinite counts it, and every RMSE (the prior's too) is over the others."""
    from scenarios.metrics import ego_metrics

    n = 10
    speed_gt = np.full(n, 20.0)
    speed_est = speed_gt + np.r_[0.1, -0.1, 0.2, -0.2, 0.1, -0.1, 0.3, -0.3, 0.0, 0.0]
    yaw_gt = np.zeros(n)
    yaw_est = np.full(n, 0.5)
    A_gt = np.zeros((n, 3))
    A_est = np.full((n, 3), 0.1)
    speed_est[2] = np.nan  # the speed alone is NaN
    yaw_est[5] = np.inf  # the yaw rate alone is infinite
    A_est[7, 1] = np.nan  # A's pitch alone is NaN
    prior = np.full(n, 21.0)
    prior[2] = prior[5] = prior[7] = 1000.0  # only on the frames left out
    series = {
        "t_s": np.arange(n) / 15.0,
        "speed_est": speed_est,
        "speed_gt": speed_gt,
        "speed_prior": prior,
        "yaw_est": yaw_est,
        "yaw_gt": yaw_gt,
        "yaw_prior": np.zeros(n),
        "A_est": A_est,
        "A_gt": A_gt,
    }
    m = ego_metrics(series)
    kept = np.setdiff1d(np.arange(n), [2, 5, 7])
    assert m["frames_compared"] == len(kept) == 7
    assert m["frames_nonfinite"] == 3
    rmse = float(np.sqrt(np.mean((speed_est[kept] - 20.0) ** 2)))
    assert m["speed_rmse_mps"] == pytest.approx(rmse)
    assert m["yaw_rate_rmse_dps"] == pytest.approx(0.5)
    assert m["angle_rmse_deg"] == pytest.approx(0.1)
    assert m["prior_speed_rmse_mps"] == pytest.approx(1.0)
    every = ego_metrics({k: v[kept] for k, v in series.items()})
    assert every["frames_nonfinite"] == 0 and every["frames_compared"] == 7
