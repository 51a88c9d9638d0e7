"""Shared geometry helpers (`estimator.geometry`)."""

import numpy as np

from estimator.camera.mount import CameraMount
from estimator.geometry import road_distance_m, road_normal


def test_road_distance_is_horizontal_to_the_road_hit() -> None:
    K0 = np.array([0.0, 0.5, 0.0])  # camera 2 m above the road, y down
    d = np.radians([90.0, 45.0, 10.0, -5.0])  # depression of each ray below the horizon
    rays = np.c_[np.zeros(4), np.sin(d), np.cos(d)]
    got = road_distance_m(rays, K0)
    assert np.allclose(got[:3], 2.0 / np.tan(d[:3]), atol=1e-12)
    assert not got[3] > 0  # above the horizon: no hit in front of the camera


def test_road_normal_is_the_cars_down_axis_in_camera_axes() -> None:
    """K0 = n / h: its unit normal is the car's -z (towards the road) in camera axes, and
    1 / |K0| is the mount's height."""
    mount = CameraMount(position_m=(0.3, 0.95, 1.2), yaw_deg=160, pitch_deg=15, base="pinhole")
    n = road_normal(mount.K0)
    assert np.allclose(n, -mount.R_car_cam[2], atol=1e-12)
    assert np.isclose(np.linalg.norm(n), 1.0, atol=1e-15)
    assert np.isclose(1.0 / np.linalg.norm(mount.K0), 1.2)
