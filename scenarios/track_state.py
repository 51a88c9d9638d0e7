"""The tracks' state against the truth: velocity, box heading, and whether the reported
covariances are honest.

A track reports, besides its point, its velocity over the ground, a box and the
covariance of its position and velocity (``tracks.csv``). For every pair of a vehicle and
a track that `scenarios.detection_metrics` matches (its gate, its optimal assignment per
frame):

- velocity error [m/s]: ``|v_track - v_vehicle|``, both over the ground in the ego road
  frame's axes (the vehicle's: its speed along its heading, from the simulator);
- heading error [deg]: between the track's box yaw and the vehicle's long axis, modulo
  180 deg (a box has no front);
- NEES, the normalised estimation error squared ``eᵀ P⁻¹ e`` (Bar-Shalom, Li &
  Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, sec.
  5.4.2), of the position (``e`` from the vehicle's footprint point nearest the camera,
  the point the tracker tracks and `localization` measures from, to the track's point)
  and of the velocity, 2 degrees of freedom each. Where the covariance is honest the
  mean NEES is 2 and a share 0.95 of the pairs lies within chi²₂(0.95) = 5.99
  (`scipy.stats.chi2`); a larger mean is an overconfident covariance, a smaller one an
  underconfident covariance.

A pair whose track lacks a value (a file without the velocity, box or covariance
columns; a singular covariance) is left out of that figure: each figure's ``pairs``
counts the pairs it was computed on, and a figure without pairs is NaN.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.stats import chi2

from scenarios.detection_metrics import (
    BAND_NAMES,
    NAN,
    EvalFrame,
    MetricsConfig,
    band_labels,
    match_frames,
    nearest_footprint_point,
)

NEES_DOF = 2  # [-] position and velocity are each 2-D
NEES_BOUND = float(chi2.ppf(0.95, NEES_DOF))  # [-] 5.99: 95 % of honest NEES lie below


def long_axis_rad(footprint_xy: np.ndarray) -> float:
    """Direction [rad] of the longer side of a box's footprint (4, 2), in (-pi/2, pi/2]."""
    fp = np.asarray(footprint_xy, float)
    a, b = fp[1] - fp[0], fp[2] - fp[1]
    side = a if np.hypot(*a) >= np.hypot(*b) else b
    yaw = math.atan2(side[1], side[0])
    return yaw - math.pi if yaw > math.pi / 2 else yaw + math.pi if yaw <= -math.pi / 2 else yaw


def axis_error_deg(yaw_rad: float, axis_rad: float) -> float:
    """Angle [deg] between a heading and an axis, modulo 180 deg: 0 .. 90."""
    d = (yaw_rad - axis_rad) % math.pi
    return math.degrees(min(d, math.pi - d))


def nees(error: np.ndarray, cov: np.ndarray) -> float:
    """``eᵀ P⁻¹ e`` of an error (2,) and a covariance (2, 2); NaN where P is not finite and
    positive definite."""
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(error))):
        return NAN
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        return NAN
    z = np.linalg.solve(L, error)
    return float(z @ z)


def _cov2(row: np.ndarray) -> np.ndarray:
    """(2, 2) of (var_a, cov_ab, var_b)."""
    return np.array([[row[0], row[1]], [row[1], row[2]]])


def pair_errors(frames: Sequence[EvalFrame], config: MetricsConfig | None = None) -> np.ndarray:
    """(P, 5) per matched pair: range [m] of the vehicle's nearest footprint point,
    velocity error [m/s], heading error [deg], position NEES, velocity NEES (NaN where
    the track or the truth lacks what it needs)."""
    return _pairs(list(frames), config)[0]


def _pairs(frames: list[EvalFrame], config: MetricsConfig | None) -> tuple[np.ndarray, np.ndarray]:
    """(`pair_errors` (P, 5), whether the ego car moved in each pair's frame (P,) bool),
    the frames matched once."""
    cfg = config if config is not None else MetricsConfig()
    _, matches = match_frames(frames, cfg)
    cam = np.asarray(cfg.camera_xy, float)
    out = np.full((len(matches), 5), NAN)
    moving = np.array([frames[k].ego_moving for k, _, _ in matches], bool)
    for i, (k, r, c) in enumerate(matches):
        f, g = frames[k], frames[k].gt[r]
        near = nearest_footprint_point(g.footprint_xy, cam)
        out[i, 0] = float(np.hypot(*(near - cam)))
        dv = f.hyp_velocity[c] - g.velocity_xy
        out[i, 1] = float(np.hypot(*dv))
        if math.isfinite(f.hyp_yaw[c]):
            out[i, 2] = axis_error_deg(float(f.hyp_yaw[c]), long_axis_rad(g.footprint_xy))
        out[i, 3] = nees(f.hyp_xy[c] - near, _cov2(f.hyp_cov[c, :3]))
        out[i, 4] = nees(dv, _cov2(f.hyp_cov[c, 3:]))
    return out, moving


def _figures(e: np.ndarray) -> dict:
    """The figures of pairs e (P, 5) of `pair_errors`."""

    def spread(x: np.ndarray, unit: str) -> dict:
        x = x[np.isfinite(x)]
        if not x.size:
            return {"pairs": 0, f"median_error_{unit}": NAN, f"p90_error_{unit}": NAN}
        return {
            "pairs": int(x.size),
            f"median_error_{unit}": float(np.median(x)),
            f"p90_error_{unit}": float(np.percentile(x, 90)),
        }

    def consistency(x: np.ndarray) -> dict:
        x = x[np.isfinite(x)]
        if not x.size:
            return {"pairs": 0, "mean": NAN, "within_95": NAN}
        return {
            "pairs": int(x.size),
            "mean": float(x.mean()),
            "within_95": float(np.mean(x <= NEES_BOUND)),
        }

    return {
        "velocity": spread(e[:, 1], "mps"),
        "heading": spread(e[:, 2], "deg"),
        "position_nees": consistency(e[:, 3]),
        "velocity_nees": consistency(e[:, 4]),
    }


def track_state(frames: Sequence[EvalFrame], config: MetricsConfig | None = None) -> dict:
    """{"pairs", "velocity", "heading", "position_nees", "velocity_nees", "nees_bound",
    "range_bands": {band: the same four}, "ego_state": {"moving", "stopped": the same
    four}} of the matched pairs of frames (module docstring)."""
    e, moving = _pairs(list(frames), config)
    bands = band_labels(np.column_stack([e[:, 0], np.zeros(len(e))]))  # (range, 0): its band
    ego = {"moving": _figures(e[moving]), "stopped": _figures(e[~moving])}
    return {
        "pairs": len(e),
        **_figures(e),
        "nees_bound": NEES_BOUND,
        "range_bands": {n: _figures(e[bands == n]) for n in BAND_NAMES},
        "ego_state": ego,
    }
