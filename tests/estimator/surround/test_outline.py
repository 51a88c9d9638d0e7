"""A vehicle's lower outline and the nearest point of its faces."""

from __future__ import annotations

import numpy as np

from estimator.surround.outline import nearest_on_contour


def _face(p0, p1, step_m=0.02):
    """Points along the road segment p0 -> p1 [m]."""
    t = np.arange(0.0, 1.0 + 1e-9, step_m / np.hypot(*np.subtract(p1, p0)))[:, None]
    return np.asarray(p0, float) + t * np.subtract(p1, p0)


def _quantise_range(xy, step_m=0.4, seed=0):
    """Moves points along their bearing onto a range grid (a pixel's radial size)."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    off = np.random.default_rng(seed).uniform(0, step_m)
    rq = np.round((r - off) / step_m) * step_m + off
    return xy * (rq / r)[:, None]


def test_nearest_on_contour_fits_the_faces_of_an_l_shaped_outline():
    # rear face x = 15, y 3..5 (nearly end-on: its range changes 0.5 m) and the side
    # y = 3 seen from x = 17.5 (its end at the corner is lost: aperture problem); the
    # ranges of single pixels are quantised by 0.4 m: their argmin lands anywhere on
    # the rear face, the line fit at its corner (15, 3), the point nearest the camera
    rear = _quantise_range(_face((15.0, 5.0), (15.0, 3.0)))
    side = _quantise_range(_face((17.5, 3.0), (20.0, 3.0)), seed=1)
    stray = np.array([[27.0, 9.5], [18.0, 6.4]])  # lone edges beyond the vehicle
    pts = np.vstack([rear, side, stray])
    q = nearest_on_contour(pts, 0.005, 0.75)
    assert np.hypot(*(q - (15.0, 3.0))) < 0.3
    single = pts[np.argmin(np.hypot(pts[:, 0], pts[:, 1]))]
    assert np.hypot(*(single - (15.0, 3.0))) > np.hypot(*(q - (15.0, 3.0)))


def test_nearest_on_contour_weak_points_only_extend_the_contour():
    strong = _face((15.0, 5.0), (15.0, 3.6))
    extension = _face((15.0, 3.6), (15.0, 3.0))  # weak: the face's end, no strong pixel
    road_mark = strong[::2] * (13.0 / 15.0)  # weak, nearer, at the strong bearings
    pts = np.vstack([strong, extension, road_mark])
    weak = np.r_[np.zeros(len(strong), bool), np.ones(len(extension) + len(road_mark), bool)]
    q = nearest_on_contour(pts, 0.005, 0.75, weak=weak)
    assert np.hypot(*(q - (15.0, 3.0))) < 0.15
    q_strong = nearest_on_contour(strong, 0.005, 0.75)
    assert np.hypot(*(q_strong - (15.0, 3.6))) < 0.15
