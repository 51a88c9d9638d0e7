"""The range of a vehicle whose ground contact is hidden, from the bearings it spans."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.surround.hidden import hidden_box_nearest_point

BOX = (4.7, 1.9)  # [m]


def span(centre_xy, box=BOX) -> tuple[float, float]:
    """Bearings [rad] (lo, hi) of a box's corners seen from the origin (independent of the
    fit: the corners' bearings, unwrapped around the centre's)."""
    half = 0.5 * np.asarray(box)
    corners = np.asarray(centre_xy) + half * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]])
    mid = np.arctan2(centre_xy[1], centre_xy[0])
    rel = np.angle(np.exp(1j * (np.arctan2(corners[:, 1], corners[:, 0]) - mid)))
    return mid + rel.min(), mid + rel.max()


def nearest(centre_xy, box=BOX) -> np.ndarray:
    half = 0.5 * np.asarray(box)
    c = np.asarray(centre_xy, float)
    return np.clip(0.0, c - half, c + half)


@settings(max_examples=40, deadline=None)
@given(st.floats(-6.0, 6.0), st.floats(2.6, 7.0), st.booleans())
def test_a_box_is_placed_back_where_its_bearings_came_from(x, y, right):
    c = np.array([x, -y if right else y])
    lo, hi = span(c)
    p = hidden_box_nearest_point(lo, hi, 9.0, BOX)
    assert p is not None
    assert np.linalg.norm(p - nearest(c)) < 0.2  # [m] grid steps: 0.05 m, span / 40


def test_a_wider_span_is_a_nearer_vehicle():
    near = hidden_box_nearest_point(*span((0.0, 3.5)), 9.0, BOX)
    far = hidden_box_nearest_point(*span((0.0, 7.5)), 9.0, BOX)
    assert near[1] == pytest.approx(2.55, abs=0.1) and far[1] == pytest.approx(6.55, abs=0.1)


def test_no_box_within_reach_gives_none():
    lo, hi = span((0.0, 20.0))  # a narrow span: a box far beyond the 9-m hidden zone
    assert hidden_box_nearest_point(lo, hi, 9.0, BOX) is None
    assert hidden_box_nearest_point(1.0, 0.9, 9.0, BOX) is None  # an empty span
