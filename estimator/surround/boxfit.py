"""A vehicle's box on the road from the part of its outline the camera sees.

The camera sees a box-shaped vehicle's lower outline only on the faces that
turn towards it: one face (a car straight ahead, or alongside) or two (an L,
a car seen across its corner). With the vehicle's size known (`BoxFitConfig.size_m`),
the box is the rectangle of that size, on the far side of the seen faces, whose
camera-facing faces lie on the outline: the L-shape fit of laser scanners
(Zhang et al., "Efficient L-shape fitting for vehicle detection using laser
scanners", IV 2017), here with the size as a prior instead of a measurement.

For each heading (a grid over half a turn), the box's extent along each of its
axes is placed from the outline points: on an axis along which the camera lies
beyond the points, the face nearest the camera is at the nearest point and the
box extends away from the camera by its size; on an axis whose span holds the
camera, the face is seen whole, and the box is centred on the points. The
heading whose camera-facing faces the points fit best (squared distance to the
faces, plus how far each seen face's extent is from its true length) wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BoxFitConfig:
    """Settings of `fit_box` (units beside each value)."""

    size_m: tuple[float, float] = (4.7, 1.9)  # [m] (length, width) of a typical car
    heading_step_deg: float = 3.0  # [deg] grid step over half a turn, 1..10
    residual_cap_m: float = 0.5  # [m] a point's distance to the faces counts at most this
    extent_weight: float = 0.25  # [-] weight of a seen face's extent against its length
    # [-] weight of sin^2(heading - prior) per point: vehicles drive along the road
    heading_prior_weight: float = 0.02

    def __post_init__(self) -> None:
        if min(self.size_m) <= 0 or not (1.0 <= self.heading_step_deg <= 10.0):
            raise ValueError(
                f"BoxFitConfig: size_m > 0 and heading_step_deg in 1..10, got "
                f"{self.size_m}, {self.heading_step_deg}"
            )


@dataclass(frozen=True)
class Box:
    """A vehicle's box on the road, ego road frame (x forward, y left) [m]."""

    x_m: float  # centre
    y_m: float
    yaw_rad: float  # heading of the length axis (0: along the ego car), in [-pi/2, pi/2)
    length_m: float
    width_m: float
    cost: float  # [m^2] mean squared residual of the fit


def _axis_extent(p: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per heading (rows of p (A, N): the points' coordinate along one box axis): the
    box's (lo, hi) on that axis and the coordinate of its camera-facing face (NaN where
    the camera lies within the span: no face along this axis faces it)."""
    pmin, pmax = p.min(axis=1), p.max(axis=1)
    lo = np.where(pmin > 0, pmin, np.where(pmax < 0, pmax - size, 0.5 * (pmin + pmax) - 0.5 * size))
    hi = lo + size
    face = np.where(pmin > 0, pmin, np.where(pmax < 0, pmax, np.nan))
    return lo, hi, face


def _span(p: np.ndarray, on: np.ndarray) -> np.ndarray:
    """(A,) extent max - min of p (A, N) over the points ``on`` (A, N) bool; 0 without any."""
    hi = np.where(on, p, -np.inf).max(axis=1)
    lo = np.where(on, p, np.inf).min(axis=1)
    return np.where(on.any(axis=1), hi - lo, 0.0)


def fit_box(
    outline_xy: np.ndarray,
    cfg: BoxFitConfig | None = None,
    prior_yaw_rad: float = 0.0,
    yaw_window_rad: float | None = None,
) -> Box | None:
    """The vehicle box whose camera-facing faces fit the seen outline.

    outline_xy: (N, 2) points [m] of the vehicle's lower outline (ego road frame; the
    camera at the origin). prior_yaw_rad: the heading expected (the road's).
    yaw_window_rad: only headings within this of the prior (modulo half a turn) are
    tried (a heading known from elsewhere, e.g. the vehicle's track); None: all.
    Returns None for fewer than 3 points.
    """
    cfg = cfg or BoxFitConfig()
    p = np.asarray(outline_xy, float).reshape(-1, 2)
    if len(p) < 3:
        return None
    L, W = (float(v) for v in cfg.size_m)
    th = np.radians(np.arange(-90.0, 90.0, cfg.heading_step_deg))  # (A,)
    if yaw_window_rad is not None:
        off = np.radians(np.arange(-90.0, 90.0, 1.0))  # a 1-deg grid within the window
        off = off[np.abs(off) <= max(yaw_window_rad, np.radians(1.0))]
        th = np.mod(prior_yaw_rad + off + np.pi / 2, np.pi) - np.pi / 2
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    u = c * p[:, 0] + s * p[:, 1]  # (A, N) along the length
    v = -s * p[:, 0] + c * p[:, 1]  # across
    ulo, uhi, uface = _axis_extent(u, L)
    vlo, vhi, vface = _axis_extent(v, W)
    # distance of each point to the camera-facing faces (segments of the box's outline)
    cap = cfg.residual_cap_m
    big = np.full_like(u, np.inf)
    du = np.where(
        np.isfinite(uface)[:, None],
        np.hypot(u - uface[:, None], np.maximum(0, np.maximum(vlo[:, None] - v, v - vhi[:, None]))),
        big,
    )
    dv = np.where(
        np.isfinite(vface)[:, None],
        np.hypot(v - vface[:, None], np.maximum(0, np.maximum(ulo[:, None] - u, u - uhi[:, None]))),
        big,
    )
    d = np.minimum(np.minimum(du, dv), cap)
    cost = (d**2).mean(axis=1)
    # a face seen whole spans its length: the points' extent along it
    on_u = du <= dv  # points on the face across the length (extent along v: width)
    span_u = _span(v, on_u)
    span_v = _span(u, ~on_u)
    # only where the seen extent is longer than the face: a face partly hidden (another
    # vehicle, the field of view) is shorter, and says nothing
    pen = np.maximum(0, span_u - W) ** 2 + np.maximum(0, span_v - L) ** 2
    cost = cost + cfg.extent_weight * pen
    cost = cost + cfg.heading_prior_weight * np.sin(th - prior_yaw_rad) ** 2
    k = int(np.argmin(cost))
    uc, vc = 0.5 * (ulo[k] + uhi[k]), 0.5 * (vlo[k] + vhi[k])
    ck, sk = math.cos(th[k]), math.sin(th[k])
    return Box(
        float(uc * ck - vc * sk), float(uc * sk + vc * ck), float(th[k]), L, W, float(cost[k])
    )
