"""The vehicle box fitted to the part of its outline the camera sees."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.surround.boxfit import BoxFitConfig, fit_box

SIZE = (4.7, 1.9)  # [m]


def seen_outline(cx, cy, yaw, size=SIZE, step_m=0.1, noise_m=0.0, seed=0):
    """(N, 2) points of a box's faces that turn towards the origin (the camera), sampled
    every step_m; each seen face whole (a convex box hides nothing of them)."""
    L, W = size
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[L, W], [-L, W], [-L, -W], [L, -W]]) / 2 @ np.array([[c, s], [-s, c]])
    corners += [cx, cy]
    pts = []
    for i in range(4):
        p0, p1 = corners[i], corners[(i + 1) % 4]
        mid = 0.5 * (p0 + p1)
        normal = mid - np.array([cx, cy])  # outward
        if normal @ mid < 0:  # faces the origin
            n = max(2, int(np.linalg.norm(p1 - p0) / step_m))
            pts.append(p0 + np.linspace(0, 1, n)[:, None] * (p1 - p0))
    out = np.concatenate(pts)
    return out + np.random.default_rng(seed).normal(0, noise_m, out.shape)


@settings(max_examples=40, deadline=None)
@given(
    rng_m=st.floats(6.0, 25.0),
    bearing=st.floats(-math.pi, math.pi),
    yaw=st.floats(-0.5, 0.5),
)
def test_box_is_recovered_from_its_seen_faces(rng_m, bearing, yaw):
    """Any pose within 25 m, heading within ~30 deg of the road: the centre to 0.25 m."""
    cx, cy = rng_m * math.cos(bearing), rng_m * math.sin(bearing)
    pts = seen_outline(cx, cy, yaw, noise_m=0.03)
    box = fit_box(pts)
    assert box is not None
    assert math.hypot(box.x_m - cx, box.y_m - cy) < 0.25
    assert (box.length_m, box.width_m) == SIZE


def test_l_shape_gives_the_heading_and_a_single_face_its_side():
    """Two faces seen: the heading to a few degrees; a car straight ahead, only its rear
    seen: the face is 1.9 m long, so it is the rear, not a side, and the box lies beyond."""
    box = fit_box(seen_outline(12.0, 6.0, 0.3))
    assert abs(box.yaw_rad - 0.3) < math.radians(4)
    ahead = fit_box(seen_outline(15.0, 0.0, 0.0))
    assert math.hypot(ahead.x_m - 15.0, ahead.y_m) < 0.2 and abs(ahead.yaw_rad) < 0.1
    side = fit_box(seen_outline(0.0, 6.0, 0.0))  # alongside: its side face, 4.7 m
    assert math.hypot(side.x_m, side.y_m - 6.0) < 0.2 and abs(side.yaw_rad) < 0.1


def test_too_few_points_and_bad_config():
    assert fit_box(np.array([[10.0, 1.0], [10.0, 1.5]])) is None
    with pytest.raises(ValueError, match="size_m"):
        BoxFitConfig(size_m=(4.7, 0.0))
    with pytest.raises(ValueError, match="heading_step_deg"):
        BoxFitConfig(heading_step_deg=20.0)
