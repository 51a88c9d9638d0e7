"""The manoeuvre retry: a fit that fails, or whose residuals are far above the recent
ones, is fitted again from the same prior mean with the manoeuvre covariance added
(`manoeuvre_cov`): an abrupt turn or side slip that the random walk of eq. 19 cannot
follow (``manoeuvre_*``).

The retry makes one pass per ``manoeuvre_search_levels`` level, each opening with one
wide grid search at that level: a coarse level sees a large yaw jump within a few grid
steps, a fine one has the points to rank the grid when the coarse levels have few (a far
camera, a slow drive). With ``manoeuvre_fine_passes``, a level whose full pass iterated
a coarser level gets one more pass that skips the coarser ones. The best fit of those
that do not fail is kept if it fits (`manoeuvre_retry`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from estimator.egomotion.coarse_to_fine import Fit
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.homography import N_STATE, V_SLICE, W_SLICE
from estimator.egomotion.iekf import IteratedEKF, yaw_direction

# the failures a retry may mend: the road did not align from the prior
RETRIED_FAILURES = ("few-inliers", "poor-fit", "can-contradiction")


def manoeuvre_cov(cfg: DirectConfig, R_car_cam: np.ndarray, lever_m: float | None) -> np.ndarray:
    """(9, 9) covariance added to the prior for the manoeuvre retry (camera axes);
    R_car_cam (3, 3): camera to car axes; lever_m: the viewpoint's distance ahead of the
    rear axle [m] (None: axle unknown)."""
    # car axes: roll and pitch rates (vibration), the yaw rate (the manoeuvre); with the
    # rear axle known (kinematic model), a turn also moves the viewpoint sideways by
    # lever x yaw rate (`yaw_direction`) and the slip at the axle is the small part,
    # manoeuvre_slip_sigma_mps
    sig_W = np.array([cfg.manoeuvre_W_plane_sigma_rps] * 2 + [cfg.manoeuvre_W_sigma_rps])
    G = np.zeros((N_STATE, 3))  # car-frame W -> state (W and the coupled V)
    G[W_SLICE, :2] = R_car_cam.T[:, :2]
    G[:, 2] = yaw_direction(lever_m, R_car_cam)
    Q = G @ np.diag(np.square(sig_W)) @ G.T
    var_V = np.square(np.array(cfg.manoeuvre_V_sigma_mps, float))
    if lever_m is not None:
        var_V[1] = cfg.manoeuvre_slip_sigma_mps**2
    Q[V_SLICE, V_SLICE] += R_car_cam.T @ np.diag(var_V) @ R_car_cam
    return Q


def manoeuvre_retry(
    cfg: DirectConfig,
    ekf: IteratedEKF,
    added_cov: np.ndarray,
    res: Fit,
    failed: bool,
    refit: Callable[[int, bool], Fit],
    failure: Callable[[Fit, int], tuple[str, str] | None],
) -> tuple[Fit, bool]:
    """(the fit kept, whether it is the retry's) after the fit res, the filter at its
    estimate; failed: whether res failed.

    refit(wide_level, from_wide): a coarse-to-fine pass from the filter's prior
    (`coarse_to_fine`); failure(fit, n_view): its failure, counted against res's points.
    added_cov (9, 9): `manoeuvre_cov`. The retry's best fit replaces a failed res, or one
    whose noise scale is ``retry_gain`` times higher; the filter's prior is then the
    widened one. The filter ends at the fit kept, with its prior.
    """
    first = res, ekf.x.copy(), ekf.P.copy()
    x_prior, P_prior = ekf.x_prior.copy(), ekf.P_prior.copy()
    # one pass per level of the wide search (a coarse level sees farther, a fine one
    # has the points): the best fit of those that did not fail
    wide_prior = P_prior + added_cov
    best = None
    for wide_level in cfg.manoeuvre_search_levels:
        if not 0 <= wide_level < cfg.levels:
            continue
        coarser = False  # the full pass iterated a level coarser than wide_level
        for from_wide in (False, True):
            # a pass from the wide level itself is the full one again unless that
            # iterated a coarser level (which may lack the points to)
            if from_wide and not (cfg.manoeuvre_fine_passes and coarser):
                break
            ekf.set_prior(x_prior, wide_prior)
            r = refit(wide_level, from_wide)
            coarser = any(r["iterations"][: cfg.levels - 1 - wide_level])
            if failure(r, first[0]["n_points"]) is None and (
                best is None or r["noise_scale"] < best[0]["noise_scale"]
            ):
                best = r, ekf.x.copy(), ekf.P.copy()
    better = best is not None and (
        failed or best[0]["noise_scale"] < first[0]["noise_scale"] / cfg.retry_gain
    )
    if better:
        ekf.set_prior(x_prior, wide_prior)  # the record's prior: the retry's
        res, ekf.x, ekf.P = best
        return res, True
    ekf.set_prior(x_prior, P_prior)
    res, ekf.x, ekf.P = first
    return res, False
