"""Ground-truth motion: the exact homography maps road points between frames."""

import numpy as np

from estimator.camera.mount import CameraMount
from estimator.geometry import skew
from sim.camera_motion import (
    T_world_car,
    Vibration,
    camera_pose,
    motion_between,
    road_plane_K,
)


def _road_points_in_cam(T_world_cam, rng, n=50):
    pts_w = np.c_[rng.uniform(-30, 30, n), rng.uniform(-15, 15, n), np.zeros(n)]
    T_cw = np.linalg.inv(T_world_cam)
    return pts_w @ T_cw[:3, :3].T + T_cw[:3, 3], pts_w


def test_exact_homography_maps_road_points():
    rng = np.random.default_rng(0)
    mount = CameraMount()
    vib = Vibration(0.5, 2.0, 0.3, 1.1)
    a = camera_pose(T_world_car(10.0, 2.0, 0.2), mount, vib, 0.0)
    b = camera_pose(T_world_car(11.7, 2.3, 0.23), mount, vib, 1 / 15)
    m = motion_between(a, b, 1 / 15)
    P_a, pts_w = _road_points_in_cam(a.T_world_actual, rng)
    T_bw = np.linalg.inv(b.T_world_actual)
    P_b = pts_w @ T_bw[:3, :3].T + T_bw[:3, 3]
    Hp = P_a @ m.H.T
    # same ray, positive scale (eq. 3)
    cos = np.sum(Hp * P_b, axis=1) / np.linalg.norm(Hp, axis=1) / np.linalg.norm(P_b, axis=1)
    assert np.all(cos > 1 - 1e-12)
    # road points satisfy K^T P = 1
    assert np.allclose(P_a @ road_plane_K(a.T_world_actual), 1.0)


def test_state_matches_first_order_homography():
    """V, W, A from poses give the paper's small-angle H (eq. 4, signs as in CONVENTIONS)."""
    mount = CameraMount()
    vib = Vibration(0.3, 2.0, 0.0, 0.5)
    dt = 1 / 30
    a = camera_pose(T_world_car(0.0, 0.0, 0.0), mount, vib, 0.0)
    b = camera_pose(T_world_car(25 * dt, 0.0, 0.1 * dt), mount, vib, dt)
    m = motion_between(a, b, dt)
    # forward 25 m/s: the omni camera's Y axis points backward
    assert np.allclose(m.V_mps, [0.0, -25.0, 0.0], atol=0.05)
    K0 = mount.K0
    Wx, Ax = skew(m.W_rps), skew(m.A_rad)
    R = np.eye(3) - Wx * dt
    D = -(np.eye(3) - Wx * dt - Ax) @ m.V_mps * dt
    K = (np.eye(3) - Ax) @ K0
    H1 = R + np.outer(D, K)
    assert np.abs(H1 - m.H).max() < 2e-3
