"""The tracks' state against the truth: hand-made pairs, and honest covariances drawn
from an independent model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scenarios.detection_metrics import EvalFrame, GtVehicle, box_footprint, nearest_footprint_point
from scenarios.track_state import (
    NEES_BOUND,
    axis_error_deg,
    long_axis_rad,
    nees,
    pair_errors,
    track_state,
)


def car(vid: int, x: float, y: float, v=(10.0, 0.0)) -> GtVehicle:
    """A 4 x 2 m car centred at (x, y) along x, driving at v [m/s] over the ground."""
    return GtVehicle(vid, box_footprint(x, y, 4.0, 2.0, 0.0), "", np.array(v, float))


@given(st.floats(-3.1, 3.1), st.floats(2.5, 6.0), st.floats(1.0, 2.4))
def test_long_axis_is_the_yaw_modulo_180_deg(yaw, length, width):
    axis = long_axis_rad(box_footprint(3.0, -2.0, length, width, yaw))
    assert axis_error_deg(yaw, axis) == pytest.approx(0.0, abs=1e-6)
    assert -math.pi / 2 < axis <= math.pi / 2


def test_axis_error_ignores_the_front_and_is_at_most_90_deg():
    assert axis_error_deg(math.pi, 0.0) == pytest.approx(0.0, abs=1e-9)
    assert axis_error_deg(math.radians(100), 0.0) == pytest.approx(80.0)
    assert axis_error_deg(math.radians(-90), 0.0) == pytest.approx(90.0)


def test_nees_of_a_diagonal_covariance_and_of_a_singular_one():
    assert nees(np.array([1.0, 2.0]), np.diag([0.25, 4.0])) == pytest.approx(4.0 + 1.0)
    assert math.isnan(nees(np.array([1.0, 0.0]), np.zeros((2, 2))))
    assert math.isnan(nees(np.array([1.0, 0.0]), np.full((2, 2), np.nan)))


def test_one_pair_by_hand():
    """A car 8..12 m ahead (nearest point (8, 0)) at 10 m/s; the track 0.5 m beyond that
    point at 11 m/s, its box turned 10 deg, variances 0.25 m² and 0.25 m²/s²."""
    f = EvalFrame(
        [car(1, 10.0, 0.0)],
        [(7, 8.5, 0.0)],
        boxes=[(10.5, 0.0, math.radians(190.0), 4.0, 2.0)],
        velocities=[(11.0, 0.0)],
        covariances=[(0.25, 0.0, 0.25, 0.25, 0.0, 0.25)],
    )
    e = pair_errors([f])
    np.testing.assert_allclose(e, [[8.0, 1.0, 10.0, 1.0, 4.0]], atol=1e-9)
    s = track_state([f])
    assert s["pairs"] == 1 and s["velocity"]["median_error_mps"] == pytest.approx(1.0)
    assert s["position_nees"] == {"pairs": 1, "mean": pytest.approx(1.0), "within_95": 1.0}
    assert s["range_bands"]["5-10 m"]["velocity_nees"]["mean"] == pytest.approx(4.0)
    assert s["range_bands"]["15-25 m"]["velocity"]["pairs"] == 0
    assert s["ego_state"]["moving"]["heading"]["median_error_deg"] == pytest.approx(10.0)
    assert s["ego_state"]["stopped"]["velocity"]["pairs"] == 0


def test_a_track_file_without_state_columns_leaves_those_figures_out():
    f = EvalFrame([car(1, 10.0, 0.0)], [(7, 8.5, 0.0)])
    s = track_state([f])
    assert s["pairs"] == 1
    for key in ("velocity", "heading", "position_nees", "velocity_nees"):
        assert s[key]["pairs"] == 0
    assert math.isnan(s["velocity"]["median_error_mps"]) and math.isnan(s["position_nees"]["mean"])


def test_unmatched_tracks_and_vehicles_take_no_part():
    f = EvalFrame(
        [car(1, 10.0, 0.0), car(2, -20.0, 5.0)],
        [(7, 8.5, 0.0), (8, 0.0, 20.0)],
        velocities=[(10.0, 0.0), (0.0, 0.0)],
        covariances=[(1.0, 0.0, 1.0, 1.0, 0.0, 1.0)] * 2,
    )
    assert track_state([f])["pairs"] == 1


def test_honest_covariances_give_a_mean_nees_of_two():
    """Errors drawn from the covariances the tracks report (correlated, of every size):
    mean NEES 2 and 95 % within the chi-square bound; the covariances halved: overconfident."""
    rng = np.random.default_rng(3)
    frames, halved = [], []
    for k in range(3000):
        g = car(1, 10.0 + 10 * rng.random(), 3.0 * rng.standard_normal())
        near = nearest_footprint_point(g.footprint_xy)
        a = rng.uniform(0.01, 0.1, 2)  # [m²] within the gate (1.5 m) at 4.7 sigma
        rho = rng.uniform(-0.8, 0.8)
        P = np.array([[a[0], rho * math.sqrt(a[0] * a[1])], [rho * math.sqrt(a[0] * a[1]), a[1]]])
        dp, dv = rng.multivariate_normal(np.zeros(2), P, size=2)
        cov = (P[0, 0], P[0, 1], P[1, 1], P[0, 0], P[0, 1], P[1, 1])
        hyp = [(k, *(near + dp))]
        vel = [tuple(g.velocity_xy + dv)]
        frames.append(EvalFrame([g], hyp, velocities=vel, covariances=[cov]))
        halved.append(EvalFrame([g], hyp, velocities=vel, covariances=[tuple(np.divide(cov, 2))]))
    s = track_state(frames)
    assert s["pairs"] == 3000
    for key in ("position_nees", "velocity_nees"):
        assert s[key]["mean"] == pytest.approx(2.0, abs=0.15)
        assert s[key]["within_95"] == pytest.approx(0.95, abs=0.015)
    assert track_state(halved)["position_nees"]["mean"] == pytest.approx(4.0, abs=0.3)
    assert NEES_BOUND == pytest.approx(5.991, abs=1e-3)
