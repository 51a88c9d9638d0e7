"""Shared geometry helpers (`estimator.geometry`)."""

import numpy as np

from estimator.geometry import road_distance_m


def test_road_distance_is_horizontal_to_the_road_hit() -> None:
    K0 = np.array([0.0, 0.5, 0.0])  # camera 2 m above the road, y down
    d = np.radians([90.0, 45.0, 10.0, -5.0])  # depression of each ray below the horizon
    rays = np.c_[np.zeros(4), np.sin(d), np.cos(d)]
    got = road_distance_m(rays, K0)
    assert np.allclose(got[:3], 2.0 / np.tan(d[:3]), atol=1e-12)
    assert not got[3] > 0  # above the horizon: no hit in front of the camera
