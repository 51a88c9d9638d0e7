"""Whether a coarse-to-fine fit is usable: the failures that keep the prior instead
(`fit_failure`) and the noise scale that marks a fit as unusual (`unusual_noise`).

A fit fails when its road is textureless (no level iterated), too few of its points are
inliers, its forward speed contradicts the CAN beyond the CAN's scale error (the images
locked onto a wrong motion, e.g. a sudden yaw traded for speed), or its residuals are
far above the expected noise (s² > ``max_noise_scale`` times the usual level: the road
did not align). A fit is unusual when its noise scale is far above that of the recent
good fits (``retry_noise_ratio``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.ego_estimator import UNUSED
from estimator.egomotion.fast_stats import fast_median
from estimator.egomotion.homography import V_SLICE
from estimator.egomotion.iekf import IteratedEKF


def unusual_noise(cfg: DirectConfig, s2_hist: list[float], s2: float) -> bool:
    """A fit's noise scale s² more than ``retry_noise_ratio`` times the median of the
    recent good fits' s2_hist (False until there are 3 of them)."""
    if len(s2_hist) < 3:
        return False
    usual = fast_median(np.asarray(s2_hist))
    return s2 > cfg.retry_noise_ratio * max(usual, 0.25)


def fit_failure(
    cfg: DirectConfig,
    res: dict[str, Any],
    s2_hist: list[float],
    ekf: IteratedEKF,
    v_can: float,
    R_car_cam: np.ndarray,
    n_view: int = 0,
) -> tuple[str, str] | None:
    """(flag, reason) when the fit res (`coarse_to_fine` fields) is unusable (the prior is
    then kept), else None.

    s2_hist: the noise scales of the recent good fits; ekf: the filter at the fit's
    estimate; v_can: the pair's CAN speed [m/s] (NaN: missing); R_car_cam (3, 3): camera
    to car axes (the reason's speed).
    n_view: for a refit or retry from a widened prior, the first fit's points (the road
    in view under the prior); the inliers are counted against the larger of it and the
    fit's own points. A wild motion that turns most of the road out of the image
    "fits" the few points left (rectilinear merge with filter.A_tau_s 0.5 and the CAN
    x 0.999, frame 102: a retry with 140 inliers of 482 points, ~5000 under the prior,
    yaw rate -138 deg/s, then held for six frames). A fit that keeps at least that
    fraction of them in view and fits most of what it sees (``seen_inlier_fraction``) is
    counted against what it sees instead: the rest is unmeasured.
    """
    n_pts, n_in = max(res["n_points"], n_view), res["n_inliers"]
    n_seen = int(np.count_nonzero(res["point_labels"] != UNUSED))  # landed in B's view
    if (
        cfg.seen_inlier_fraction > 0
        and n_in >= cfg.seen_inlier_fraction * n_seen > 0
        and n_seen >= cfg.min_inlier_fraction * n_view
        and not unusual_noise(cfg, s2_hist, res["noise_scale"])
    ):
        n_pts = n_seen  # those out of its view are unmeasured, not outliers
    if res["done_levels"] == 0:
        return (
            "textureless",
            f"textureless road: fewer than {cfg.min_points} usable points "
            f"with gradient > {cfg.grad_threshold} DN/px",
        )
    if n_in < max(cfg.min_points, cfg.min_inlier_fraction * n_pts):
        return (
            "few-inliers",
            f"only {n_in} of {n_pts} finest-level points are inliers"
            + (" (as many were in view under the prior)" if n_view > res["n_points"] else "")
            + ": estimate unreliable, prior kept",
        )
    if not math.isnan(v_can) and not ekf.can_consistent(v_can):
        speed = float((R_car_cam @ ekf.x[V_SLICE])[0])
        return (
            "can-contradiction",
            f"estimated speed {speed:.2f} m/s contradicts the CAN ({v_can:.2f} m/s) beyond "
            "its scale error: the images locked onto a wrong motion, prior kept",
        )
    usual = fast_median(np.asarray(s2_hist)) if len(s2_hist) >= 3 else 1.0
    if res["noise_scale"] > cfg.max_noise_scale * max(usual, 1.0):
        return (
            "poor-fit",
            f"residuals {math.sqrt(res['noise_scale']):.1f}x the expected noise at the "
            f"finest level ({math.sqrt(max(usual, 1.0)):.1f}x usually; motion outside "
            "the prior's reach?): estimate unreliable, prior kept",
        )
    return None
