"""A vehicle whose ground contact is hidden (the car-body mask): its box from its bearings.

Near the car the body hides where a vehicle meets the road; the camera sees the bearings
its body spans at the edge of the seen road, not its range. With the vehicle's size
known, the span gives the range: `hidden_box` fits a box along the ego car's heading
whose bearings span it (`estimator.surround.detection`, obstacle map where the road is
hidden).
"""

from __future__ import annotations

import math

import numpy as np


def hidden_box_nearest_point(
    bearing_lo_rad: float, bearing_hi_rad: float, max_range_m: float, box_m: tuple[float, float]
) -> np.ndarray | None:
    """(2,) the nearest point of `hidden_box`'s box [m], or None."""
    fit = hidden_box(bearing_lo_rad, bearing_hi_rad, max_range_m, box_m)
    return None if fit is None else fit[2:]


def hidden_box(
    bearing_lo_rad: float, bearing_hi_rad: float, max_range_m: float, box_m: tuple[float, float]
) -> np.ndarray | None:
    """(4,) centre and point nearest the camera [m] (x, y, x, y) of the box (length,
    width) [m], heading along x, whose bearings from the camera span
    bearing_lo..bearing_hi [rad] (bearing_hi ahead of bearing_lo counter-clockwise) and
    whose nearest point lies within max_range_m [m]; None when no such box matches the
    span to 2 deg.

    A vehicle whose ground contact is hidden shows its bearings but not its range: with
    its size known, the span it covers gives the range (nearer is wider). The fit is a
    grid search over the box's centre, coarse (0.25 m of range, span/10 of bearing) then
    fine around the best (0.05 m, span/40)."""
    span = float(np.angle(np.exp(1j * (bearing_hi_rad - bearing_lo_rad))))
    if span <= 0:
        return None
    mid = bearing_lo_rad + 0.5 * span
    half = 0.5 * np.asarray(box_m, float)
    cm, sm = math.cos(mid), math.sin(mid)
    offsets = half * np.array([[1, 1], [1, -1], [-1, 1], [-1, -1]])  # (4, 2) corners

    def fit(rho: np.ndarray, theta: np.ndarray) -> tuple[float, np.ndarray]:
        R, T = np.meshgrid(rho, theta, indexing="ij")
        c = np.stack([R * np.cos(T), R * np.sin(T)], axis=-1).reshape(-1, 2)  # (P, 2)
        corners = c[:, None, :] + offsets  # (P, 4, 2)
        # bearings relative to mid: the corners turned by -mid (no wrap within +-pi)
        x = corners[..., 0] * cm + corners[..., 1] * sm
        y = corners[..., 1] * cm - corners[..., 0] * sm
        rel = np.arctan2(y, x)
        lo, hi = rel.min(axis=1), rel.max(axis=1)
        # the box must not hold the camera (|x| < a and |y| < b): its bearings would wrap
        outside = (np.abs(c[:, 0]) > half[0]) | (np.abs(c[:, 1]) > half[1])
        near = np.clip(0.0, c - half, c + half)  # (P, 2) the box's point nearest the camera
        ok = outside & (np.hypot(near[:, 0], near[:, 1]) <= max_range_m)
        cost = np.where(ok, (lo + 0.5 * span) ** 2 + (hi - 0.5 * span) ** 2, np.inf)
        k = int(np.argmin(cost))
        return float(cost[k]), np.r_[c[k], near[k]]

    coarse_rho = np.arange(0.5, max_range_m + half[0] + 0.25, 0.25)
    cost, best = fit(coarse_rho, mid + np.linspace(-0.5, 0.5, 11) * span)
    if not np.isfinite(cost):
        return None
    rho0, theta0 = float(np.hypot(*best[:2])), math.atan2(best[1], best[0])
    rho = rho0 + np.arange(-0.25, 0.25 + 1e-9, 0.05)
    theta = theta0 + np.linspace(-0.1, 0.1, 9) * span
    cost, best = fit(rho[rho > 0], theta)
    if not np.isfinite(cost) or cost > 2 * np.radians(2.0) ** 2:
        return None
    return best
