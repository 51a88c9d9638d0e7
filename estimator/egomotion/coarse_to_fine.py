"""One coarse-to-fine pass of IEKF iterations over a frame pair's pyramid (paper section
4.2), from the filter's prior::

    for each level, coarsest to finest:
        0. the level's points of A (`level_points`); on ``search_levels``, a grid search
           over the speed scale and the yaw rate puts x̂ within reach (`grid_search`)
        then up to ``iterations`` times:
        1-3. constraints at x̂: Δz, C, R (`constraints.linearise`, eq. 13-16)
        4. reclassify the points (`constraints.classify`, eq. 20-21)
        5. IEKF update with the inliers (eq. 17-18); a step that raised the posterior
           cost is halved (``line_search``)

A pass returns the record's point fields of its finest level (a dict, `coarse_to_fine`);
its estimate is the filter's x̂, P. The manoeuvre retry runs passes that open with one
wide grid search at a chosen level (``wide_level``).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.constraints import classify, linearise
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.ego_estimator import INLIER, OUTLIER, UNUSED
from estimator.egomotion.fast_stats import fast_median
from estimator.egomotion.grid_search import grid_search
from estimator.egomotion.homography import A_SLICE, V_SLICE
from estimator.egomotion.iekf import IteratedEKF
from estimator.egomotion.level_points import LevelPoints, Pair, level_points
from estimator.egomotion.levels import Level
from estimator.egomotion.point_selection import column_scale
from estimator.egomotion.pyramid import Frame

Fit = dict[str, Any]  # a pass's record fields (`coarse_to_fine`)


class FitSetup(NamedTuple):
    """What a pass needs of the camera, fixed for an estimator: the config, the camera
    model, the road plane K0 (3,) and rotation R_car_cam (3, 3) of the mount, yaw_dir
    (9,) d x / d (car yaw rate) (`iekf.yaw_direction`), the pyramid levels and
    mask_scale, the scale 2^l of the off-road mask's level."""

    cfg: DirectConfig
    camera: CameraModel
    K0: np.ndarray
    R_car_cam: np.ndarray
    yaw_dir: np.ndarray
    levels: list[Level]
    mask_scale: float


class FineLevel(NamedTuple):
    """What a pass keeps of its finest level for `DirectEstimator.point_pull`: its points
    (`LevelPoints`), their pixels (N, 2) in frame A [full-resolution px], the pair's
    second frame B, dt [s], the points' labels (N,) and the noise scale s²."""

    pts: LevelPoints
    points_px: np.ndarray
    B: Frame
    dt: float
    labels: np.ndarray
    s2: float


def coarse_to_fine(
    setup: FitSetup,
    ekf: IteratedEKF,
    pair: Pair,
    excluded: list[np.ndarray] | None,
    gain: float,
    wide_level: int | None = None,
    from_wide: bool = False,
) -> tuple[Fit, float]:
    """One pass from the filter's prior; (the record's point fields, the brightness gain
    B -> A of the last linearisation). The filter ends at the pass's estimate.

    excluded: per level, (M,) bool candidates that the off-road masks keep out
    (`exclusion.excluded`), or None. gain: the last linearisation's gain before the pass
    (the static-point test reads it until the pass fits its own).
    wide_level: the manoeuvre retry's level of one wide grid search (``manoeuvre_search_*``)
    before the iterations, which then replaces the searches of ``search_levels``; its
    levels iterate up to ``manoeuvre_iterations``.
    from_wide: with wide_level, skip the levels coarser than it (`manoeuvre_fine_passes`).

    The fields: noise_scale, n_points, n_inliers, iterations (per level, coarse to fine),
    points_px (N, 2), point_labels (N,), point_speed_info (N,) of the finest level,
    done_levels (levels that iterated) and fine (`FineLevel`, or None).
    """
    cfg, camera, K0 = setup.cfg, setup.camera, setup.K0
    B, dt = pair.B, pair.dt
    ekf.set_prior(ekf.x_prior, ekf.P_prior)
    iters: list[int] = []
    done_levels = 0
    pts_out, labels_out, info_out = np.zeros((0, 2)), np.zeros(0, np.int8), np.zeros(0)
    s2 = noise_scale = math.nan
    fine = None
    speed = float((setup.R_car_cam @ ekf.x_prior[V_SLICE])[0])
    col_scale = column_scale(dt, speed)
    retry = wide_level is not None
    its = cfg.manoeuvre_iterations if retry else cfg.iterations

    def points(lvl: int, gain: float) -> LevelPoints:
        """The level's points at the current x̂ (`level_points`)."""
        exclude = excluded[lvl] if excluded is not None else None
        level = setup.levels[lvl]
        return level_points(
            cfg, camera, K0, ekf.x, ekf.P_prior, gain, level, lvl, pair, exclude, col_scale
        )

    def search(pts: LevelPoints, max_steps: int, n_points: int, local: bool = False) -> None:
        """x̂ to the grid point of lowest cost (`grid_search`)."""
        x = grid_search(cfg, camera, K0, setup.yaw_dir, ekf, pts, B, dt, max_steps, n_points, local)
        if x is not None:
            ekf.x = x

    if retry:
        # the retry: one wide grid search at wide_level, from the prior; all levels then
        # iterate from there (a finer level's search over the retry's wide prior in a
        # few coarse steps would jump out of the basin the wide search found)
        pts = points(wide_level, gain)
        if len(pts.sel) >= cfg.min_points:
            search(pts, cfg.manoeuvre_search_steps, cfg.manoeuvre_search_points)
    for lvl in reversed(range(cfg.levels)):
        if from_wide and retry and lvl > wide_level:
            iters.append(0)
            continue
        pts = points(lvl, gain)
        # a level with fewer points than a fit needs is skipped before its linearisation
        # (whose brightness gain would come from those few points)
        n_max = its[cfg.levels - 1 - lvl] if len(pts.sel) >= cfg.min_points else 0
        # the retry's levels iterate from its wide search, refined below it by a local one
        if retry:
            do_search = cfg.manoeuvre_local_search and lvl < wide_level
        else:
            do_search = lvl in cfg.search_levels
        if n_max and do_search:
            search(pts, cfg.search_steps, cfg.search_points, retry)
        n_it, labels, s2, last, gain = _iterate_level(setup, ekf, pts, B, dt, n_max, s2, gain)
        iters.append(n_it)
        done_levels += n_it > 0
        if lvl == 0:
            pts_out, labels_out, noise_scale = pts.level.roi_w[pts.sel], labels, s2
            fine = FineLevel(pts, pts_out, B, dt, labels, s2)
            info_out = np.zeros(len(pts.sel))
            if last is not None:  # the finest level's last linearisation
                idx, C, R = last
                info_out[idx] = (C[:, V_SLICE] @ setup.R_car_cam[0]) ** 2 / R
    res = {
        "noise_scale": noise_scale,
        "n_points": len(pts_out),
        "n_inliers": int(np.sum(labels_out == INLIER)),
        "iterations": tuple(iters),
        "points_px": pts_out,
        "point_labels": labels_out,
        "point_speed_info": info_out,
        "done_levels": done_levels,
        "fine": fine,
    }
    return res, gain


def _iterate_level(
    setup: FitSetup,
    ekf: IteratedEKF,
    pts: LevelPoints,
    B: Frame,
    dt: float,
    n_max: int,
    s2: float,
    gain: float,
) -> tuple[int, np.ndarray, float, tuple[np.ndarray, ...] | None, float]:
    """Up to n_max IEKF iterations (steps 1-5) of a level's points pts, moving the filter.

    Returns (iterations done, labels (N,) of the points, noise scale s² of the last
    classification (the given s2, a coarser level's, when this level classifies none),
    (idx, C, R) of the last linearisation or None, the last linearisation's gain (the
    given gain when none)). A step that leaves fewer than ``min_points`` points in B or
    inliers stops the level; so does one below ``step_tol`` (Mahalanobis, P before it).
    """
    cfg = setup.cfg
    n_sel = len(pts.sel)
    labels = np.full(n_sel, UNUSED, np.int8)
    included = np.zeros(n_sel, bool)  # used in x̂ (eq. 21) or not (eq. 20)
    n_it, last = 0, None
    s2_ref, best, halvings = math.nan, None, 0
    while n_it < n_max:
        lin = linearise(cfg, setup.camera, setup.K0, ekf.x, pts, B, dt, included, setup.mask_scale)
        idx, dz, C, R, gain = lin
        if len(idx) < cfg.min_points:
            break
        last = idx, C, R  # the record's point information (audits) comes from it
        if cfg.line_search:
            # posterior cost at x̂: truncated residuals (points that left B count as
            # truncated) + prior term; a step that raised it is halved (backtracking)
            if not math.isfinite(s2_ref):
                s2_ref = min(max(fast_median(dz * dz / R) / 0.455, 0.25), 100.0)
            e2 = np.minimum(dz * dz / (s2_ref * R), cfg.snoop_threshold)
            d = ekf.x - ekf.x_prior
            cost = float(e2.sum()) + cfg.snoop_threshold * (n_sel - len(idx))
            cost += float(d @ ekf.P_prior_inv @ d)
            if best is not None and cost > best[0] and halvings < cfg.max_halvings:
                ekf.x, ekf.P = 0.5 * (ekf.x + best[1]), best[2]
                halvings += 1
                continue
            best = (cost, ekf.x.copy(), ekf.P.copy())
        use, R, s2 = classify(cfg, ekf.P, dz, C, R, included[idx])
        included[:] = False
        included[idx[use]] = True
        labels[:] = UNUSED
        labels[idx] = np.where(use, INLIER, OUTLIER)
        if use.sum() < cfg.min_points:
            break
        P_old = ekf.P
        if pts.lvl > 0 and cfg.coarse_fix_A:
            C = C.copy()
            C[:, A_SLICE] = 0.0
        n_use = int(use.sum())
        if cfg.independent_points > 0 and n_use > cfg.independent_points:
            # neighbouring points share errors (smoothing, blur, resampling): count
            # their information as that of `independent_points` independent ones
            R = R * (n_use / cfg.independent_points)
        # step 5, eq. 17-18: IEKF measurement update with the inliers
        dx = ekf.update(C[use], dz[use], R[use])
        n_it += 1
        if float(dx @ np.linalg.solve(P_old, dx)) < cfg.step_tol**2:
            break
    return n_it, labels, s2, last, gain
