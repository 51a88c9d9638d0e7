"""The yaw-jump refit: a fit that moved the car's yaw rate far beyond what the prior
allowed is refitted with the prior's yaw rate widened (``yaw_jump_*``).

The random walk of eq. 19 keeps a steady turn rate steady; when the road says the rate
changed by d, far beyond the prior's std (a steering step), the posterior is a
compromise that holds part of the old rate. Widening the prior's yaw rate by
``yaw_jump_widen`` x |d| (with the sideways speed it drags at the camera's lever arm)
from the same prior mean lets the images, not the old rate, tell the new one.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from estimator.egomotion.coarse_to_fine import Fit
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.homography import W_SLICE
from estimator.egomotion.iekf import IteratedEKF


def yaw_shift(ekf: IteratedEKF, n_yaw: np.ndarray) -> tuple[float, float]:
    """(shift, expected std) of the car's yaw rate from the prior to the fit [rad/s];
    n_yaw (3,): the car's z axis in camera axes (yaw rate = n_yaw . W).

    The filter expects the update to move x̂ with covariance P⁻ - P⁺ (that of the
    innovation mapped by the gain); a larger shift says the prior was off.
    """
    shift = float(n_yaw @ (ekf.x[W_SLICE] - ekf.x_prior[W_SLICE]))
    dP = ekf.P_prior[W_SLICE, W_SLICE] - ekf.P[W_SLICE, W_SLICE]
    return shift, math.sqrt(max(float(n_yaw @ dP @ n_yaw), 0.0))


def yaw_cov(sigma_rps: float, yaw_dir: np.ndarray) -> np.ndarray:
    """(9, 9) covariance of a change of the car's yaw rate with std sigma_rps along
    yaw_dir (9,) (`iekf.yaw_direction`: with the sideways speed it moves the camera by at
    the lever arm)."""
    return sigma_rps**2 * np.outer(yaw_dir, yaw_dir)


def yaw_refit(
    cfg: DirectConfig,
    ekf: IteratedEKF,
    n_yaw: np.ndarray,
    yaw_dir: np.ndarray,
    res: Fit,
    refit: Callable[[], Fit],
    failure: Callable[[Fit, int], tuple[str, str] | None],
) -> tuple[Fit, bool]:
    """(the fit kept, whether it is a refit) after the fit res, the filter at its estimate.

    Refits (refit(): a coarse-to-fine pass from the filter's prior) when the fit moved
    the yaw rate by more than ``yaw_jump_sigmas`` times the expected std (`yaw_shift`).
    A refit is kept when it does not fail (failure(fit, n_view), with n_view the first
    fit's points); the prior widened is then the filter's prior. A refit that moved the
    rate by more than half again its widened std (the step is larger than the first
    shift said) is refitted with the std its own shift asks for, up to
    ``yaw_jump_rounds`` refits, each kept when it does not fail. The filter ends at the
    fit kept, with its prior.
    """
    shift, sd = yaw_shift(ekf, n_yaw)
    if abs(shift) <= cfg.yaw_jump_sigmas * max(sd, 1e-9):
        return res, False
    x_prior, P_prior = ekf.x_prior.copy(), ekf.P_prior.copy()
    n_view = res["n_points"]
    best = res, ekf.x.copy(), ekf.P.copy(), P_prior
    refitted = False
    sigma = cfg.yaw_jump_widen * abs(shift)
    for _ in range(cfg.yaw_jump_rounds):
        wide = P_prior + yaw_cov(sigma, yaw_dir)
        ekf.set_prior(x_prior, wide)
        r = refit()
        if failure(r, n_view) is not None:
            break
        best, refitted = (r, ekf.x.copy(), ekf.P.copy(), wide), True
        shift = yaw_shift(ekf, n_yaw)[0]  # (from the same prior mean)
        if cfg.yaw_jump_widen * abs(shift) <= 1.5 * sigma:
            break
        sigma = cfg.yaw_jump_widen * abs(shift)
    res, x, P, prior_P = best
    # the filter's prior: the widened one of the refit kept (the fit's own when none)
    ekf.set_prior(x_prior, prior_P)  # (resets x̂ to the prior mean: set it after)
    ekf.x, ekf.P = x, P
    return res, refitted
