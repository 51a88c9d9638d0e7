"""The filter (eq. 17-21): update vs filterpy and vs a MAP solver, snooping, time update, CAN."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from scipy.optimize import least_squares

from estimator.camera.files import load_camera
from estimator.camera.mount import CameraMount
from estimator.egomotion.iekf import (
    FilterConfig,
    IteratedEKF,
    can_consistent,
    can_row,
    can_speed_update,
    data_snooping,
    iekf_update,
    initial_prior,
    reset_speed,
    robust_weights,
    stationary_A_cov,
    time_update,
    transition,
)

MOUNT = CameraMount()


def _spd(rng: np.random.Generator, n: int = 9) -> np.ndarray:
    M = rng.normal(size=(n, n))
    return M @ M.T + n * np.eye(n)


def test_one_iteration_is_the_kalman_update_of_filterpy() -> None:
    """Linear measurement, first iteration from x⁻: eq. 17-18 = the textbook KF update."""
    rng = np.random.default_rng(0)
    x_prior, P_prior = rng.normal(size=9), _spd(rng)
    C, R = rng.normal(size=(30, 9)), rng.uniform(0.5, 2.0, 30)
    z = rng.normal(size=30)
    x, P = iekf_update(x_prior, x_prior, np.linalg.inv(P_prior), C, z - C @ x_prior, R)
    kf = KalmanFilter(dim_x=9, dim_z=30)  # reference implementation
    kf.x, kf.P, kf.H, kf.R = x_prior.copy(), P_prior.copy(), C, np.diag(R)
    kf.update(z)
    assert np.allclose(x, kf.x, atol=1e-10)
    assert np.allclose(P, kf.P, atol=1e-10)
    # a second iteration on a linear model does not move: eq. 18 has reached the MAP
    x2, _ = iekf_update(x, x_prior, np.linalg.inv(P_prior), C, z - C @ x, R)
    assert np.allclose(x2, x, atol=1e-10)


def test_iterations_converge_to_the_map_of_a_nonlinear_model() -> None:
    rng = np.random.default_rng(1)
    x_true = rng.normal(size=3)
    x_prior, P_prior = x_true + 0.3, np.eye(3) * 0.5
    A = rng.normal(size=(40, 3))

    def h(x):  # mildly nonlinear measurement
        return np.sin(A @ x) + 0.1 * (A @ x) ** 2

    def jac(x):
        return (np.cos(A @ x) + 0.2 * (A @ x))[:, None] * A

    z = h(x_true) + rng.normal(0, 0.05, 40)
    R = np.full(40, 0.05**2)
    x = x_prior.copy()
    for _ in range(20):
        x, P = iekf_update(x, x_prior, np.linalg.inv(P_prior), jac(x), z - h(x), R)
    L_R, L_P = 1 / np.sqrt(R), np.linalg.cholesky(np.linalg.inv(P_prior)).T
    sol = least_squares(lambda y: np.r_[L_R * (z - h(y)), L_P @ (y - x_prior)], x_prior)
    assert np.allclose(x, sol.x, atol=1e-8)


def test_data_snooping_uses_eq_20_and_21() -> None:
    rng = np.random.default_rng(2)
    P = _spd(rng, 9) * 1e-3
    C = rng.normal(size=(4, 9))
    R = np.full(4, 4.0)
    cpc = np.einsum("ni,ij,nj->n", C, P, C)
    residual = np.array([1.0, 1.0, 30.0, 30.0])
    included = np.array([True, False, True, False])
    inl, d2 = data_snooping(residual, C, P, R, included, 9.0)
    assert np.allclose(d2[[0, 2]], residual[[0, 2]] ** 2 / (R[[0, 2]] - cpc[[0, 2]]))  # eq. 21
    assert np.allclose(d2[[1, 3]], residual[[1, 3]] ** 2 / (R[[1, 3]] + cpc[[1, 3]]))  # eq. 20
    assert inl.tolist() == [True, True, False, False]
    # eq. 21 never divides by a non-positive variance
    _, d2 = data_snooping(np.ones(4), C, P * 1e6, R, np.ones(4, bool), 9.0)
    assert np.all(np.isfinite(d2)) and np.all(d2 > 0)


def test_robust_weights() -> None:
    r, s = np.array([0.0, 1.0, 2.0, 10.0]), np.ones(4)
    assert np.allclose(robust_weights(r, s, "huber", 2.0), [1, 1, 1, 0.2])
    w = robust_weights(r, s, "tukey", 4.0)
    assert w[0] == 1.0 and w[-1] == 0.0 and np.all(np.diff(w) <= 0)
    with pytest.raises(ValueError, match="'cauchy'"):
        robust_weights(r, s, "cauchy", 1.0)


def test_time_update_links_A_to_the_roll_pitch_rotation() -> None:
    """eq. 19 with A_k+1 = rho (A_k + Π W_k dt): A follows the measured roll/pitch rotation.

    (Replaces the test of the former model, where A was an independent Gauss-Markov
    process with 0.6 deg of noise per frame, re-estimated almost from scratch each pair.)
    """
    cfg = FilterConfig()
    dt = 1 / 15
    x, P = initial_prior(cfg, MOUNT.R_car_cam, MOUNT.K0)
    n = MOUNT.K0 / np.linalg.norm(MOUNT.K0)
    roll_rate = MOUNT.R_car_cam.T @ np.array([0.05, 0.0, 0.0])  # about car x (in the plane)
    x[3:6] = roll_rate + 0.2 * n  # plus a yaw rate about the road normal
    x[6:] = MOUNT.R_car_cam.T @ np.array([0.01, -0.01, 0.0])
    B, Q = transition(dt, cfg, MOUNT.R_car_cam, MOUNT.K0)
    assert B.shape == Q.shape == (9, 9)
    assert np.allclose(Q, Q.T) and np.all(np.linalg.eigvalsh(Q) >= -1e-15)
    x2, P2 = time_update(x, P, B, Q)
    rho = np.exp(-dt / cfg.A_tau_s)
    # the roll rotation moves A, the yaw rate (the car turning) does not
    assert np.allclose(x2[6:], rho * (x[6:] + roll_rate * dt))
    assert np.allclose(x2[:6], x[:6])  # V, W: random walks
    # the uncertainty of W over the pair carries into A
    assert P2[6, 6] > rho**2 * P[6, 6]
    # process noise: yaw rate tighter than the roll/pitch rates (vibration)
    assert n @ Q[3:6, 3:6] @ n == pytest.approx(cfg.W_walk_yaw_rps**2 * dt)
    e = MOUNT.R_car_cam.T @ np.array([1.0, 0.0, 0.0])
    assert e @ Q[3:6, 3:6] @ e == pytest.approx(cfg.W_walk_rps**2 * dt)
    # process noise grows with dt: a long gap widens V and W
    _, Q_long = transition(1.0, cfg, MOUNT.R_car_cam, MOUNT.K0)
    assert np.allclose(Q_long[:6, :6], 15 * Q[:6, :6])
    # without the link, A is the mean-reverting process alone
    B0, _ = transition(dt, FilterConfig(A_from_W=False), MOUNT.R_car_cam, MOUNT.K0)
    assert np.allclose(B0[6:, 3:6], 0.0) and np.allclose(B0[6:, 6:], rho * np.eye(3))


def test_A_from_W_matches_the_true_camera_motion() -> None:
    """The link A_k+1 = A_k + Π W_k dt holds for the simulator's exact states (vibration)."""
    from estimator.synthetic import drive_poses
    from sim.camera_motion import CameraPose, motion_between

    dt = 1 / 15
    poses = drive_poses(MOUNT, np.arange(12) * dt, 20.0, 0.3, vib_amplitude_deg=0.5)
    B, _ = transition(dt, FilterConfig(A_tau_s=1e9), MOUNT.R_car_cam, MOUNT.K0)
    cams = [
        CameraPose(poses.T_world_nominal[k], poses.T_world_actual[k], poses.A_cam_rad[k])
        for k in range(12)
    ]
    B0, _ = transition(dt, FilterConfig(A_tau_s=1e9, A_from_W=False), MOUNT.R_car_cam, MOUNT.K0)
    worst, worst0 = 0.0, 0.0
    for k in range(10):
        a = motion_between(cams[k], cams[k + 1], dt)
        b = motion_between(cams[k + 1], cams[k + 2], dt)
        x = np.r_[a.V_mps, a.W_rps, a.A_rad]
        worst = max(worst, float(np.max(np.abs((B @ x)[6:] - b.A_rad))))
        worst0 = max(worst0, float(np.max(np.abs((B0 @ x)[6:] - b.A_rad))))
    # what is left is of second order, |A| |W dt| (0.5 deg x 1.1 deg of yaw per frame)
    assert worst < np.radians(0.015)
    assert worst0 > np.radians(0.1)  # the roll/pitch rotation between the frames itself


def test_can_gate_resets_a_lost_speed() -> None:
    cfg = FilterConfig()
    x, P = initial_prior(cfg, MOUNT.R_car_cam, MOUNT.K0)
    x[:3] = MOUNT.R_car_cam.T @ [20.0, 0.0, 0.0]
    P[:3, :3] = np.eye(3) * 0.1**2
    assert can_consistent(x, P, 21.5, MOUNT.R_car_cam, cfg)  # a 7.5 % CAN scale error is fine
    assert not can_consistent(x, P, 30.0, MOUNT.R_car_cam, cfg)  # 50 %: the state is lost
    assert can_consistent(x, P, 30.0, MOUNT.R_car_cam, FilterConfig(can_gate_rel=0.0))
    x2, P2 = reset_speed(x, P, 30.0, MOUNT.R_car_cam, cfg)
    assert (MOUNT.R_car_cam @ x2[:3])[0] == pytest.approx(30.0)
    assert np.allclose(x2[3:], x[3:])
    assert P2[3, 3] == pytest.approx(cfg.W0_sigma_rps**2) and np.all(np.linalg.eigvalsh(P2) > 0)


def test_can_prior_is_forward_and_not_overconfident() -> None:
    cfg = FilterConfig()
    x, P = initial_prior(cfg, MOUNT.R_car_cam, MOUNT.K0)
    x[:3] = MOUNT.R_car_cam.T @ [19.0, 0.0, 0.0]  # first CAN message (the estimators' start)
    x, P = can_speed_update(x, P, 20.0, MOUNT.R_car_cam, cfg)
    v_car = MOUNT.R_car_cam @ x[:3]
    assert v_car == pytest.approx([20.0, 0.0, 0.0], abs=0.05)  # V⁻ ≈ R_cam_car (v_can, 0, 0)
    sigma_fwd = np.sqrt(MOUNT.R_car_cam[0] @ P[:3, :3] @ MOUNT.R_car_cam[0])
    assert sigma_fwd > 0.1 * 20.0  # a 10 % scale error is within one sigma
    # a precise image measurement of the speed 10 % lower wins over the CAN prior
    C = np.zeros((1, 9))
    C[0, :3] = MOUNT.R_car_cam[0]
    x2, _ = iekf_update(x, x, np.linalg.inv(P), C, np.array([18.0 - C[0] @ x]), np.array([0.01]))
    assert MOUNT.R_car_cam[0] @ x2[:3] == pytest.approx(18.0, abs=0.02)


def _side_camera_in_a_turn(v_mps: float, yaw_rate_rps: float) -> tuple[CameraMount, np.ndarray]:
    """The rectilinear preset's mount (0.95 m left of the centreline) and the true state of
    a rigid car whose centreline moves forward at v_mps, turning at yaw_rate_rps, by the
    rigid-body velocity field v(p) = v(o) + w x (p - o) (independent of `can_row`)."""
    _, mount = load_camera("rectilinear-rear-left")
    w_car = np.array([0.0, 0.0, yaw_rate_rps])
    v_view_car = np.array([v_mps, 0.0, 0.0]) + np.cross(w_car, mount.position_m)
    R = mount.R_car_cam
    return mount, np.r_[R.T @ v_view_car, R.T @ w_car, np.zeros(3)]


def test_can_row_is_the_forward_speed_of_the_centreline() -> None:
    """The CAN reports the car's (centreline's) speed; a side viewpoint's own forward speed
    differs by yaw rate x its offset (0.36 m/s at 22 deg/s and 0.95 m)."""
    mount, x = _side_camera_in_a_turn(7.5, np.radians(22.0))
    y = float(mount.position_m[1])
    assert y == pytest.approx(0.95)
    assert can_row(mount.R_car_cam, y) @ x == pytest.approx(7.5, abs=1e-12)
    v_view = (mount.R_car_cam @ x[:3])[0]
    assert v_view == pytest.approx(7.5 - 0.95 * np.radians(22.0), abs=1e-12)
    assert can_row(mount.R_car_cam) @ x == pytest.approx(v_view)  # offset 0: the viewpoint


def test_exact_can_leaves_a_side_cameras_true_speed_in_a_turn() -> None:
    """An exact CAN speed does not pull a side camera's (correct) state in a turn: the
    update's innovation is zero. Without the offset it would pull the viewpoint's speed
    up towards the centreline's, by most of 0.36 m/s."""
    cfg = FilterConfig()
    mount, x_true = _side_camera_in_a_turn(7.5, np.radians(22.0))
    y = float(mount.position_m[1])
    P = np.diag([3.0**2] * 3 + [0.01**2] * 3 + [0.01**2] * 3)  # V still open: the CAN leads
    x, _ = can_speed_update(x_true, P, 7.5, mount.R_car_cam, cfg, y)
    assert np.allclose(x, x_true, atol=1e-12)
    ekf = IteratedEKF(cfg, mount.R_car_cam, mount.K0, can_offset_y_m=y)
    ekf.x, ekf.P = x_true.copy(), P.copy()
    ekf.fuse_can(7.5)
    assert np.allclose(ekf.x, x_true, atol=1e-12)
    x0, _ = can_speed_update(x_true, P, 7.5, mount.R_car_cam, cfg)  # the viewpoint's speed
    assert (mount.R_car_cam @ (x0 - x_true)[:3])[0] > 0.2
    # the gate and the reset use the same row: the reset puts the viewpoint at v - r y
    x2, _ = reset_speed(x_true, P, 7.5, mount.R_car_cam, cfg, y)
    v2_car = mount.R_car_cam @ x2[:3]
    assert v2_car[0] == pytest.approx(7.5 - y * np.radians(22.0), abs=1e-12)
    assert np.allclose(x2[3:], x_true[3:])
    assert can_consistent(x_true, P, 7.5, mount.R_car_cam, cfg, y)
    # the filter's own gate and reset (what the estimators call) carry the mount's offset
    ekf.x, ekf.P = x_true.copy(), P.copy()
    assert ekf.can_consistent(7.5)
    ekf.reset_to_can(7.5)
    assert np.array_equal(ekf.x, x2)


def test_filter_class_cycle() -> None:
    ekf = IteratedEKF(FilterConfig(), MOUNT.R_car_cam, MOUNT.K0)
    ekf.predict(1 / 15)
    ekf.fuse_can(25.0)
    ekf.begin_update()
    assert np.array_equal(ekf.x, ekf.x_prior) and ekf.n_iterations == 0
    rng = np.random.default_rng(3)
    C = rng.normal(size=(50, 9))
    dx = ekf.update(C, rng.normal(size=50), np.ones(50))
    assert dx.shape == (9,) and ekf.n_iterations == 1
    assert np.allclose(ekf.P, ekf.P.T) and np.all(np.linalg.eigvalsh(ekf.P) > 0)
    assert np.all(np.diag(ekf.P) <= np.diag(ekf.P_prior) + 1e-12)
    with pytest.raises(ValueError, match=r"shape \(9,\)"):
        ekf.set_prior(np.zeros(3), np.eye(3))


def test_stationary_A_cov_is_the_limit_of_the_time_update() -> None:
    """A's process alone (A_from_W off), iterated at a small dt until it forgets its start,
    settles at `stationary_A_cov`: A_walk² tau / 2 in the road plane, A_sigma_normal² about
    the normal."""
    cfg = FilterConfig(A_from_W=False, A_tau_s=0.5)
    dt = 1e-3
    B, Q = transition(dt, cfg, MOUNT.R_car_cam, MOUNT.K0)
    Pa = np.zeros((3, 3))
    Ba, Qa = B[6:, 6:], Q[6:, 6:]
    for _ in range(int(10 * cfg.A_tau_s / dt)):  # e^-20 of the start left
        Pa = Ba @ Pa @ Ba.T + Qa
    S = stationary_A_cov(cfg, MOUNT.K0)
    assert np.allclose(Pa, S, rtol=0.01, atol=0.0)
    n = MOUNT.K0 / np.linalg.norm(MOUNT.K0)
    assert n @ S @ n == pytest.approx(cfg.A_sigma_normal_rad**2)
    e = MOUNT.R_car_cam.T @ np.array([1.0, 0.0, 0.0])
    assert e @ S @ e == pytest.approx(cfg.A_walk_rad**2 * cfg.A_tau_s / 2)


def test_hold_A_drops_the_measurement_of_A_only() -> None:
    """`IteratedEKF.hold_A`: A back to the prior's mean with the stationary covariance,
    uncorrelated with V and W, whose estimate and covariance the update keeps."""
    ekf = IteratedEKF(FilterConfig(), MOUNT.R_car_cam, MOUNT.K0)
    ekf.predict(1 / 15)
    ekf.begin_update()
    rng = np.random.default_rng(5)
    ekf.update(rng.normal(size=(80, 9)), rng.normal(size=80), np.ones(80))
    x_fit, P_fit = ekf.x.copy(), ekf.P.copy()
    assert not np.allclose(x_fit[6:], ekf.x_prior[6:])
    ekf.hold_A()
    assert np.array_equal(ekf.x[6:], ekf.x_prior[6:])
    assert np.array_equal(ekf.x[:6], x_fit[:6]) and np.array_equal(ekf.P[:6, :6], P_fit[:6, :6])
    assert np.all(ekf.P[6:, :6] == 0) and np.all(ekf.P[:6, 6:] == 0)
    assert np.allclose(ekf.P[6:, 6:], stationary_A_cov(ekf.cfg, MOUNT.K0))
    assert np.all(np.linalg.eigvalsh(ekf.P) > 0)


def test_nonholonomic_update_ties_the_sideways_speed_to_the_yaw_rate() -> None:
    """The kinematic pseudo-measurement: the rear axle does not slide, so the viewpoint
    (lever_m ahead of it) slides at yaw_rate x lever_m; the update removes the mismatch in
    proportion to the prior's variances and matches the textbook scalar Kalman update."""
    from estimator.egomotion.iekf import nonholonomic_row, nonholonomic_update, scalar_update

    mount = CameraMount(position_m=(0.3, 0.95, 1.2), yaw_deg=160, pitch_deg=15, base="pinhole")
    Rc, lever = mount.R_car_cam, 2.8
    x = np.zeros(9)
    x[0:3] = Rc.T @ np.array([20.0, -0.5, 0.0])  # 0.5 m/s sideways, no yaw: inconsistent
    P = np.diag([1.0, 1.0, 1.0, 0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4])
    h = nonholonomic_row(lever, Rc)
    assert h @ x == pytest.approx(-0.5)  # the axle's sideways speed
    x1, P1 = nonholonomic_update(x, P, lever, Rc, sigma_mps=0.01)
    assert abs(h @ x1) < 0.01  # now consistent
    v1, w1 = Rc @ x1[0:3], Rc @ x1[3:6]
    assert v1[1] == pytest.approx(lever * w1[2], abs=0.01)
    assert v1[1] > -0.5 and w1[2] < 0  # both moved: sideways speed less, a right turn
    assert np.all(np.linalg.eigvalsh(P1) > 0) and np.trace(P1) < np.trace(P)
    # the same as the Kalman update of filterpy with H = h, R = sigma²
    kf = KalmanFilter(dim_x=9, dim_z=1)
    kf.x, kf.P, kf.H, kf.R = x.copy(), P.copy(), h[None, :], np.array([[1e-4]])
    kf.update(np.array([0.0]))
    assert np.allclose(kf.x, x1) and np.allclose(kf.P, P1)
    assert np.allclose(scalar_update(x, P, h, 0.0, 1e-4)[0], x1)


def test_vertical_speed_update_keeps_the_camera_on_the_road_plane() -> None:
    """The pseudo-measurement of a car that stays on the road: the camera's speed along the
    road normal (the car's z in car axes) is pulled to 0 in proportion to the prior's
    variances, the same as filterpy's Kalman update with H = (n, 0, 0); off (std <= 0) it
    leaves the state alone."""
    from estimator.egomotion.iekf import vertical_speed_update

    mount = CameraMount(position_m=(0.3, 0.95, 1.2), yaw_deg=160, pitch_deg=15, base="pinhole")
    Rc, K0 = mount.R_car_cam, mount.K0
    x = np.zeros(9)
    x[0:3] = Rc.T @ np.array([20.0, 0.0, -0.4])  # sinking at 0.4 m/s
    x[6:9] = 0.002
    P = np.diag([1.0, 1.0, 1.0, 0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4])
    P[2, 8] = P[8, 2] = 0.005  # correlated with A: A moves with it
    x1, P1 = vertical_speed_update(x, P, K0, sigma_mps=0.01)
    assert (Rc @ x1[0:3])[2] == pytest.approx(0.0, abs=0.01)
    assert (Rc @ x1[0:3])[0] == pytest.approx(20.0, abs=0.05)  # the forward speed stays
    assert x1[8] != x[8] and np.array_equal(x1[3:6], x[3:6])
    assert np.all(np.linalg.eigvalsh(P1) > 0) and np.trace(P1) < np.trace(P)
    h = np.zeros(9)
    h[0:3] = K0 / np.linalg.norm(K0)
    kf = KalmanFilter(dim_x=9, dim_z=1)
    kf.x, kf.P, kf.H, kf.R = x.copy(), P.copy(), h[None, :], np.array([[1e-4]])
    kf.update(np.array([0.0]))
    assert np.allclose(kf.x, x1) and np.allclose(kf.P, P1)
    # the filter's switch: off by default, on where configured
    ekf = IteratedEKF(FilterConfig(), Rc, K0)
    ekf.x, ekf.P = x.copy(), P.copy()
    ekf.fuse_vertical()
    assert np.array_equal(ekf.x, x) and np.array_equal(ekf.P, P)
    ekf = IteratedEKF(FilterConfig(vertical_speed_sigma_mps=0.01), Rc, K0)
    ekf.x, ekf.P = x.copy(), P.copy()
    ekf.fuse_vertical()
    assert np.allclose(ekf.x, x1) and np.allclose(ekf.P, P1)


@pytest.mark.parametrize("base", ["omni", "pinhole"])
def test_yaw_direction_is_a_car_yaw_that_keeps_the_rear_axle_straight(base: str) -> None:
    """A unit step along yaw_direction is 1 rad/s of car yaw rate, moves the viewpoint
    sideways by the lever arm (a point ahead of the rear axle) and leaves the rear axle's
    sideways speed (the kinematic pseudo-measurement) at 0; without an axle, W only."""
    from estimator.egomotion.iekf import nonholonomic_row, yaw_direction

    mount = CameraMount(position_m=(1.2, 0.3, 1.5), yaw_deg=30.0, base=base, rear_axle_x_m=-1.3)
    Rc, lever = mount.R_car_cam, mount.lever_arm_m
    g = yaw_direction(lever, Rc)
    assert Rc @ g[3:6] == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)
    assert Rc @ g[0:3] == pytest.approx([0.0, 2.5, 0.0], abs=1e-12)
    assert float(nonholonomic_row(lever, Rc) @ g) == pytest.approx(0.0, abs=1e-12)
    assert not yaw_direction(None, Rc)[0:3].any()


def test_a_constant_rate_bias_is_learnt_and_left_out_of_A() -> None:
    """The images' roll/pitch rates carry a constant bias: without ``rate_bias_tau_s``
    A settles at about A_tau_s x the bias; with it, the running mean takes the bias (not
    the yaw rate, which is the car's) and A stays near the mount."""
    dt = 1 / 15
    n = MOUNT.K0 / np.linalg.norm(MOUNT.K0)
    bias = MOUNT.R_car_cam.T @ np.radians([0.15, -0.1, 0.0])  # [rad/s] in the road plane
    A_end = {}
    for tau in (0.0, 2.0):
        ekf = IteratedEKF(FilterConfig(rate_bias_tau_s=tau), MOUNT.R_car_cam, MOUNT.K0)
        for _ in range(150):
            ekf.predict(dt)
            ekf.begin_update()
            ekf.x[3:6] = bias + 0.2 * n  # what the measurement said, with a yaw rate
            ekf.learn_rate_bias(dt)
        A_end[tau] = np.degrees(MOUNT.R_car_cam @ ekf.x[6:])
        if tau > 0:
            assert np.allclose(ekf.rate_bias, bias, atol=0.01 * np.linalg.norm(bias))
        else:
            assert np.array_equal(ekf.rate_bias, np.zeros(3))
    # off: A holds about A_tau_s (1 s) x the bias; on: the last 0.7 % of it
    assert A_end[0.0][:2] == pytest.approx([0.15, -0.1], rel=0.1)
    assert np.all(np.abs(A_end[2.0]) < 0.01)
