"""Grid search over the forward speed scale and the yaw rate, run before a level's IEKF
iterations (paper section 4.2 iterates from the prior; this puts x̂ within their reach).

The brightness-constancy cost is not convex beyond about a pixel (the texture's
correlation length): Gauss-Newton from a prior that is a few pixels off (a biased CAN
speed, an unexpected turn) stops in the nearest local minimum. The two directions the
prior knows least, the speed scale and the yaw rate, are searched over
+/- ``search_sigmas`` prior std around x̂ in steps that move the points by
``search_step_px`` pixels of the level; the grid point of lowest cost (truncated
residuals plus the prior term) is where the iterations start.
"""

from __future__ import annotations

import math

import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.fast_stats import fast_percentile, nan_to_num_fast
from estimator.egomotion.homography import N_STATE, V_SLICE, homographies
from estimator.egomotion.iekf import IteratedEKF
from estimator.egomotion.level_points import LevelPoints
from estimator.egomotion.pyramid import Frame, in_level, sample_points


def grid_search(
    cfg: DirectConfig,
    camera: CameraModel,
    K0: np.ndarray,
    yaw_dir: np.ndarray,
    ekf: IteratedEKF,
    pts: LevelPoints,
    B: Frame,
    dt: float,
    max_steps: int,
    n_points: int,
    local: bool = False,
) -> np.ndarray | None:
    """(9,) the grid point of lowest cost around the filter's x̂, or None when the grid is
    x̂ alone (the prior is narrower than a step along both directions).

    The grid spans +/- ``search_sigmas`` std of the filter's prior (x⁻, P⁻) along each
    direction, at most ``max_steps`` steps per side, ranked over at most n_points of the
    level's points pts (an evenly spread subset) of frame B, time step dt [s]. K0 (3,):
    the road plane (`CameraMount.K0`); yaw_dir (9,): d x / d (car yaw rate)
    (`iekf.yaw_direction`: with a known rear axle the viewpoint slides with the turn).
    local: at most ``max_steps`` steps of ``search_step_px`` each side, however wide the
    prior (the manoeuvre retry's finer levels: a local refinement, not a new search).
    """
    level, lvl, rays, a_val = pts.level, pts.lvl, pts.rays, pts.a_val
    s = float(level.scale)
    x0 = ekf.x.copy()
    if len(rays) > n_points:  # an evenly spread subset is enough to rank the grid
        sub = np.linspace(0, len(rays) - 1, n_points).astype(int)
        rays, a_val = np.take(rays, sub, 0), a_val[sub]
    dirs = np.zeros((2, N_STATE))
    dirs[0, V_SLICE] = x0[V_SLICE]  # d x / d (relative speed scale)
    dirs[1] = yaw_dir  # d x / d (car yaw rate) [rad/s]
    # prior std of the coefficient along each direction: sqrt(dᵀ P⁻ d) / |d|²
    dPd = np.einsum("ij,jk,ik->i", dirs, ekf.P_prior, dirs)
    sig = np.sqrt(np.maximum(dPd, 0.0)) / np.maximum(np.sum(dirs**2, axis=1), 1e-24)
    steps = _grid_steps(cfg, camera, K0, x0, dirs, sig, rays, s, dt, max_steps, local)
    if all(len(st) == 1 for st in steps):
        return None
    # all grid points at once: (G, 9) states -> (G, N) costs
    ga, gb = np.meshgrid(steps[0], steps[1], indexing="ij")
    X = x0 + ga.reshape(-1, 1) * dirs[0] + gb.reshape(-1, 1) * dirs[1]
    Hs = homographies(X, K0, dt)  # (G, 3, 3)
    # float32 (`CameraModel.project`): the grid is only ranked, ~1e-4 px is plenty
    P_b = (rays.astype(np.float32) @ Hs.transpose(0, 2, 1).astype(np.float32)).reshape(-1, 3)
    w_b = camera.project(P_b, np.float32) / np.float32(s)
    ok = in_level(w_b, P_b, K0, level.shape)
    b_val = sample_points(B.stacks[lvl][:1], w_b)[:, 0].astype(np.float64).reshape(len(X), -1)
    ok = ok.reshape(len(X), -1)
    # each grid point with its own brightness gain B -> A (as `constraints.linearise` fits
    # one): with a stale gain, a motion that slides the image along a smooth brightness
    # gradient (vignetting, the road's shading) would pass for the exposure change
    # (rectilinear intersection, frame pair 1: a 1.3 % gain step read as -43 % speed)
    gain = np.ones(len(X))
    if cfg.gain_compensation:  # least squares a = gain b over the points in view
        b_ok = np.where(ok, b_val, 0.0)
        gain = np.sum(a_val * b_ok, axis=1) / np.maximum(np.sum(b_ok * b_ok, axis=1), 1e-9)
    r2 = (a_val - gain[:, None] * b_val) ** 2 / cfg.sigma_intensity**2
    r2 = np.where(ok, np.minimum(r2, cfg.search_truncation), cfg.search_truncation)
    D = X - ekf.x_prior
    cost = r2.sum(axis=1) + np.einsum("gi,ij,gj->g", D, ekf.P_prior_inv, D)
    return X[int(np.argmin(cost))].copy()


def _grid_steps(
    cfg: DirectConfig,
    camera: CameraModel,
    K0: np.ndarray,
    x0: np.ndarray,
    dirs: np.ndarray,
    sig: np.ndarray,
    rays: np.ndarray,
    s: float,
    dt: float,
    max_steps: int,
    local: bool,
) -> list[np.ndarray]:
    """Per direction dirs[j] (2, 9), the grid's coefficients (2k + 1,) about x0 (9,): +/-
    ``search_sigmas`` x sig[j] (the prior std of the coefficient) in steps that move the
    points (rays (N, 3)) by about ``search_step_px`` pixels of the level of scale s (their
    90th percentile); (0,) alone when a single step spans the range."""
    # the points at x0 and a small step along each direction, the three warps at once
    # (`homographies`, a batched `map_rays`: the same values as one by one)
    eps = [1e-3 / max(np.linalg.norm(d), 1e-12) for d in dirs]
    Hs = homographies(np.stack([x0, x0 + eps[0] * dirs[0], x0 + eps[1] * dirs[1]]), K0, dt)
    P3 = rays @ np.ascontiguousarray(Hs.transpose(0, 2, 1))  # (3, N, 3)
    w0, *w1s = camera.project(P3.reshape(-1, 3)).reshape(3, len(rays), 2)
    steps = []
    for j, w1 in enumerate(w1s):
        # level px per unit
        disp = nan_to_num_fast(np.linalg.norm(w1 - w0, axis=1)) / eps[j] / s
        d90 = fast_percentile(disp, 90) if len(disp) else 0.0
        half = cfg.search_sigmas * sig[j]
        if local and d90 > 0:
            half = min(half, max_steps * cfg.search_step_px / d90)
        if d90 <= 0 or half * d90 < cfg.search_step_px:
            steps.append(np.zeros(1))
            continue
        k = min(max_steps, math.ceil(half * d90 / cfg.search_step_px))
        steps.append(np.linspace(-half, half, 2 * k + 1))
    return steps
