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


@settings(max_examples=40, deadline=None)
@given(prior=st.floats(-3.0, 3.0), window=st.floats(0.02, 0.5))
def test_heading_window_keeps_the_fit_within_it(prior, window):
    """Only headings within the window of the prior (modulo half a turn) are tried, also
    where the window wraps past +-90 deg; the yaw stays in [-pi/2, pi/2)."""
    box = fit_box(
        seen_outline(14.0, -5.0, 1.2, noise_m=0.05), prior_yaw_rad=prior, yaw_window_rad=window
    )
    assert -math.pi / 2 <= box.yaw_rad < math.pi / 2
    off = (box.yaw_rad - prior + math.pi / 2) % math.pi - math.pi / 2
    assert abs(off) <= window + 1e-9


def test_known_heading_resolves_a_face_seen_end_on():
    """A car seen end-on (heading along its bearing: only its 1.9-m rear face, 0.15 m of
    noise) is placed up to 2 m off by the fit alone, which takes the face for either;
    with the heading known to 5 deg its centre is within 0.5 m."""
    worst_alone = 0.0
    for cx, cy, deg in [(10.0, 17.0, 60.0), (5.0, 18.0, 75.0), (-14.0, 14.0, -45.0)]:
        yaw = math.radians(deg)
        for seed in range(3):
            pts = seen_outline(cx, cy, yaw, noise_m=0.15, seed=seed)
            alone = fit_box(pts)
            known = fit_box(pts, prior_yaw_rad=yaw, yaw_window_rad=math.radians(5))
            err_alone = math.hypot(alone.x_m - cx, alone.y_m - cy)
            err_known = math.hypot(known.x_m - cx, known.y_m - cy)
            assert err_known < 0.5 and err_known <= err_alone
            worst_alone = max(worst_alone, err_alone)
    assert worst_alone > 1.5
