"""Steps 1-4 of one IEKF iteration at a pyramid level (paper section 4.2): the brightness
constraints of a level's points at the state x̂ (`linearise`) and which of them the
update uses (`classify`).

1. warp frame B at the points of A with x̂ (motion model, eq. 3, 6-10)
2. spatial gradients of B there, temporal gradient g_t = B(w_b) - A(w_a)
3. constraint rows C = gᵀ dw_b/dx and innovation Δz = -g_t (eq. 13-16), with each
   point's noise R (intensity, flow, the unknown depth of points off the road)
4. data snooping (eq. 20-21) or robust weights, R scaled by the robust residual level s²
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.fast_stats import fast_median
from estimator.egomotion.homography import V_SLICE, dh_dx, homography
from estimator.egomotion.iekf import data_snooping, robust_weights
from estimator.egomotion.level_points import LevelPoints
from estimator.egomotion.motion_model import constraint_rows, map_rays
from estimator.egomotion.pyramid import Frame, in_level, sample_points, valid_at


class Linearisation(NamedTuple):
    """A level's constraints at x̂: idx (M,) the points that land in B (indices into the
    level's points), dz (M,) the innovations Δz [DN], C (M, 9) the constraint rows, R (M,)
    their noise variances [DN²], and gain, the brightness gain B -> A fitted over them."""

    idx: np.ndarray
    dz: np.ndarray
    C: np.ndarray
    R: np.ndarray
    gain: float


def linearise(
    cfg: DirectConfig,
    camera: CameraModel,
    K0: np.ndarray,
    x: np.ndarray,
    pts: LevelPoints,
    B: Frame,
    dt: float,
    included: np.ndarray,
    mask_scale: float,
) -> Linearisation:
    """Steps 1-3 at the state x (9,) for the level's points pts, frame B, time step dt [s].

    included: (N,) bool, the points the current estimate uses: the brightness gain is
    fitted over those that land in B when they are at least ``min_points``, else over all.
    mask_scale: the scale 2^l of the off-road mask's level, that of ``B.offroad_look``: a
    point that lands where B does not look like the road (a vehicle moved over it) is not
    measured, unless the given road mask already puts it off the road.

    Points that a given road mask puts off the road (``pts.off``) or whose road hit is far
    (``pts.far``) have an unknown plane scale lambda (std ``offroad_depth_sigma``); since
    the plane-induced motion is linear in V, the residual's derivative w.r.t. lambda is
    the one w.r.t. the speed scale, ``C V``, and ``(sigma C V)²`` joins R: they tell the
    rotation, hardly the speed.
    """
    level, lvl, rays, a_val = pts.level, pts.lvl, pts.rays, pts.a_val
    off, w_a, far = pts.off, pts.w_a, pts.far
    s = float(level.scale)
    # step 1: warp the points into B with x̂ (eq. 3, 6-10)
    P_b = map_rays(rays, homography(x, K0, dt))
    w_b = camera.project(P_b) / s  # level pixels
    inside = in_level(w_b, P_b, K0, level.shape)
    idx = np.flatnonzero(valid_at(level.valid_b, w_b, inside))
    if B.offroad_look is not None and len(idx):
        look = B.offroad_look
        f = s / mask_scale  # level px -> mask px
        u = np.clip(np.rint(w_b[idx, 0] * f), 0, look.shape[1] - 1).astype(np.intp)
        v = np.clip(np.rint(w_b[idx, 1] * f), 0, look.shape[0] - 1).astype(np.intp)
        keep = look[v, u] == 0
        if off is not None:
            keep |= off[idx]
        idx = idx[keep]
    # step 2: brightness and spatial gradient of B at w_b, temporal gradient
    smp = sample_points(B.stacks[lvl], np.take(w_b, idx, 0))
    b_val, g = smp[:, 0].astype(np.float64), smp[:, 1:3].astype(np.float64)
    a_i = a_val[idx]
    gain = 1.0
    if cfg.gain_compensation and len(idx):
        use = included[idx] if included[idx].sum() >= cfg.min_points else slice(None)
        gain = float(np.dot(a_i[use], b_val[use]) / max(np.dot(b_val[use], b_val[use]), 1e-9))
    # eq. 15: Δz = -g_t, g_t = B(w_b) - A(w_a) (B scaled by the brightness gain)
    dz = a_i - gain * b_val
    g *= gain
    g2 = g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1]  # (the sum over axis 1, ~3x faster)
    R = cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * g2
    if cfg.flow_noise_frac > 0 and w_a is not None:
        flow = np.take(w_b, idx, 0) - np.take(w_a, idx, 0)  # [level px]
        R = R + cfg.flow_noise_frac**2 * np.sum(flow * flow, axis=1) * g2
    # step 3, eq. 14-16: C_i = g_i^T dw_b/dx (gradient per full-resolution pixel)
    C = constraint_rows(
        camera, np.take(rays, idx, 0), np.take(P_b, idx, 0), g / s, dh_dx(x, K0, dt)
    )
    if far is not None:
        off = far if off is None else off | far
    if off is not None and cfg.offroad_depth_sigma > 0:
        lam_var = np.square(cfg.offroad_depth_sigma * (C[:, V_SLICE] @ x[V_SLICE]))
        R = R + np.where(off[idx], lam_var, 0.0)
    return Linearisation(idx, dz, C, R, gain)


def classify(
    cfg: DirectConfig,
    P: np.ndarray,
    dz: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    included: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Step 4: (use (M,) bool, R (M,) possibly rescaled/reweighted, noise scale s²) of the
    constraints dz (M,), C (M, 9), R (M,) at the current covariance P (9, 9); included
    (M,) bool: the points the current estimate uses (eq. 21) or not (eq. 20).

    s² = median(Δz²/R) / 0.455 (the median of a chi² with 1 dof): about 1 when
    the residuals match R; ``adaptive_noise`` multiplies R by it (clipped).
    """
    s2 = fast_median(dz * dz / R) / 0.455
    if cfg.adaptive_noise:
        R = R * min(max(s2, 0.25), 100.0)
    if cfg.outliers == "snooping":
        # eq. 20-21: each residual against its expected variance, reclassified
        use, _ = data_snooping(dz, C, P, R, included, cfg.snoop_threshold)
        return use, R, s2
    if cfg.outliers in ("huber", "tukey"):
        wgt = robust_weights(dz, np.sqrt(R), cfg.outliers, cfg.robust_k)
        return wgt > 0, R / np.maximum(wgt, 1e-12), s2
    return np.ones(len(dz), bool), R, s2
