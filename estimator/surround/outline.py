"""A vehicle's lower outline in the obstacle map, and the nearest point of its faces.

The refinement (`estimator.surround.detection.VehicleDetector._refine`) turns a blob's
moving edge pixels into road points; one pixel is ~0.4 m of range at 15 m, so the nearest
single point lands anywhere along a face seen nearly end-on. These functions keep the
nearest point per bearing bin (the lower outline), cut it into faces and fit each with a
line: the fit's nearest point averages the range quantisation of single pixels.
"""

from __future__ import annotations

import math

import numpy as np


def lower_outline(
    xy_m: np.ndarray, bin_rad: float, weak: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A vehicle's lower outline: of road points xy_m (N, 2) [m], the nearest to the
    origin per bearing bin of ``bin_rad`` [rad] (``weak`` (N,) bool: points taken only in
    bins without any other), ordered by bearing; and the bins' indices (M,)."""
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    b = np.arctan2(xy[:, 1], xy[:, 0])
    r = np.hypot(xy[:, 0], xy[:, 1])
    # bins relative to the mean bearing (no wrap at +-pi)
    b0 = math.atan2(float(np.sin(b).mean()), float(np.cos(b).mean()))
    k = np.round(np.angle(np.exp(1j * (b - b0))) / bin_rad).astype(int)
    w = np.zeros(len(xy), bool) if weak is None else np.asarray(weak, bool)
    order = np.lexsort((r, w, k))
    first = order[np.r_[True, k[order][1:] != k[order][:-1]]]
    return xy[first], k[first]


def nearest_on_contour(
    xy_m: np.ndarray,
    bin_rad: float,
    split_m: float,
    min_points: int = 3,
    weak: np.ndarray | None = None,
) -> np.ndarray:
    """(2,) nearest point to the origin of a vehicle's lower contour, fitted [m].

    xy_m: (N, 2) road points of a blob's moving edge pixels (ego road frame). The
    contour is the nearest point per bearing bin of ``bin_rad``, ordered by bearing;
    ``weak`` (N,) bool marks points taken only in bins without any other point.
    It is cut where bins are missing (more than 2) and then split recursively at
    the point farthest from a piece's chord while that is more than ``split_m``
    away (iterative end-point fit, Ramer-Douglas-Peucker: the faces of an L-shaped
    outline, and stray edges apart). Each piece of at least ``min_points`` points is
    fitted with a total-least-squares line (principal axis) and the nearest point
    of the fitted segment (the piece's extent along its line) to the origin taken;
    the nearest of them is returned (the nearest contour point when no piece has
    enough points). The fit averages the range quantisation of single pixels.
    """
    return nearest_on_outline(*lower_outline(xy_m, bin_rad, weak), split_m, min_points)


def nearest_on_outline(
    c: np.ndarray, kc: np.ndarray, split_m: float, min_points: int = 3
) -> np.ndarray:
    """`nearest_on_contour` of a lower outline (`lower_outline`: points (M, 2) [m] ordered
    by bearing, their bins (M,))."""
    cuts = np.flatnonzero(np.diff(kc) > 3) + 1
    stack = list(np.split(c, cuts))
    pieces = []
    while stack:
        p = stack.pop()
        if len(p) >= 2 * min_points:
            t = (p[-1] - p[0]) / max(float(np.linalg.norm(p[-1] - p[0])), 1e-9)
            off = np.abs((p - p[0]) @ np.array([-t[1], t[0]]))  # distance from the chord
            j = int(np.argmax(off))
            if off[j] > split_m:
                stack += [p[: j + 1], p[j:]]
                continue
        pieces.append(p)
    best, best_r = c[int(np.argmin(np.hypot(c[:, 0], c[:, 1])))], math.inf
    for p in pieces:
        if len(p) < min_points:
            continue
        m = p.mean(axis=0)
        d = np.linalg.svd(p - m, full_matrices=False)[2][0]  # line: m + s d
        s = (p - m) @ d
        # nearest point of the line to the origin (s = -m.d), clipped to the piece
        q = m + float(np.clip(-(m @ d), s.min(), s.max())) * d
        if float(np.hypot(*q)) < best_r:
            best, best_r = q, float(np.hypot(*q))
    return best
