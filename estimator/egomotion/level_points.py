"""The points of frame A that one pyramid level of a frame pair fits (paper section 4.2),
with what each point's noise needs to know about it.

`level_points` selects them (`point_selection.select_points`: gradient, information,
off-road mask), drops those that stay put in the image while the road moves
(`static_points`: the ego body, the mount, dirt on the lens), and gathers their rays,
A's brightness, the given road mask's off-road flags and the far-road flags
(`far_points`).

Why the selection and the masks matter (measured on rendered drives, see the tests): the
road ring of an omni image is crowded with guard rails, posts, vehicles and the ego
car's roof, whose image motion is not the road's; at the pyramid's coarse levels their
blur leaks into road points. Points picked by gradient strength sit on exactly those
structures, and a coarse level biased by them leaves the finest level in a wrong local
minimum a few pixels away (the brightness-constancy cost is not convex beyond about a
pixel).

Pyramid levels are addressed in full-resolution pixels: ``cv2.pyrDown`` puts level-l
pixel (i, j) at full-resolution pixel (2^l i, 2^l j), so a point's ray is
``camera.unproject`` of its full-resolution position and level gradients are divided by
2^l; everything that depends only on the camera (`levels.build_levels`) is computed
once. Rows of (N, k) arrays are gathered with np.take(a, i, 0) rather than a[i]: the
same values, 3-6x faster in numpy 2 (59k rays: 0.08 vs 0.47 ms).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.fast_stats import nan_to_num_fast
from estimator.egomotion.homography import homography
from estimator.egomotion.levels import Level
from estimator.egomotion.motion_model import map_rays
from estimator.egomotion.point_selection import select_points
from estimator.egomotion.pyramid import Frame, sample_points


class Pair(NamedTuple):
    """A frame pair to fit: frame A (the previous one), frame B, their time step dt [s],
    and ``given``: per level, (M,) bool over the level's candidates, those within their
    support of a pixel that A's given road mask says is not road
    (`exclusion.given_offroad`), or None without a mask."""

    A: Frame
    B: Frame
    dt: float
    given: list[np.ndarray] | None


class LevelPoints(NamedTuple):
    """A level's selected points of frame A.

    level, lvl: the `Level` and its index (0 the finest); sel: (N,) indices into
    ``level.roi_idx``; rays: (N, 3) their rays in camera frame c; a_val: (N,) A's
    brightness there [DN]; off: (N,) bool, off the road by the given road mask, or None
    without one; far: (N,) bool, road hit beyond ``far_depth_m`` (`far_points`), or None;
    w_a: (N, 2) their level pixels in A (for ``flow_noise_frac``), or None when off.
    """

    level: Level
    lvl: int
    sel: np.ndarray
    rays: np.ndarray
    a_val: np.ndarray
    off: np.ndarray | None
    far: np.ndarray | None
    w_a: np.ndarray | None


def level_points(
    cfg: DirectConfig,
    camera: CameraModel,
    K0: np.ndarray,
    x: np.ndarray,
    P_prior: np.ndarray,
    gain: float,
    level: Level,
    lvl: int,
    pair: Pair,
    exclude: np.ndarray | None,
    col_scale: np.ndarray,
) -> LevelPoints:
    """The points level lvl fits at the state x (9,) with the prior covariance P_prior
    (9, 9): selected outside the off-road mask (exclude: (M,) bool over the level's
    candidates, or None), the static ones (`static_points`, with the brightness gain
    B -> A) dropped. col_scale (9,): `point_selection.column_scale` of the pair.

    With ``coarse_without_map``, a coarse level that the mask leaves fewer than
    ``min_points`` selects without it: the mask, dilated by the level's support, then
    covers the road, and the level fits with its raised structure rather than not at all.
    """
    A, B, dt = pair.A, pair.B, pair.dt
    sel = select_points(level, A, lvl, cfg, P_prior, col_scale, exclude, x)
    sel = sel[~static_points(cfg, camera, K0, x, gain, level, lvl, sel, A, B, dt)]
    if cfg.coarse_without_map and lvl > 0 and exclude is not None and len(sel) < cfg.min_points:
        sel = select_points(level, A, lvl, cfg, P_prior, col_scale, None, x)
        sel = sel[~static_points(cfg, camera, K0, x, gain, level, lvl, sel, A, B, dt)]
    a_val = A.stacks[lvl][0].ravel()[level.roi_idx[sel]].astype(np.float64)
    off = pair.given[lvl][sel] if pair.given is not None else None
    w_a = np.take(level.roi_w, sel, 0) / float(level.scale) if cfg.flow_noise_frac else None
    far = far_points(cfg, level, lvl, sel)
    return LevelPoints(level, lvl, sel, np.take(level.roi_rays, sel, 0), a_val, off, far, w_a)


def far_points(cfg: DirectConfig, level: Level, lvl: int, sel: np.ndarray) -> np.ndarray | None:
    """(len(sel),) bool: the level's points sel whose road hit is farther than
    ``far_depth_m`` (their plane scale is unknown: `constraints.linearise` gives them the
    noise of an unknown depth), at the ``far_depth_levels`` finest levels; None elsewhere
    or when off."""
    if cfg.far_depth_m <= 0 or lvl >= cfg.far_depth_levels:
        return None
    return level.road_dist_m[sel] > cfg.far_depth_m


def static_points(
    cfg: DirectConfig,
    camera: CameraModel,
    K0: np.ndarray,
    x: np.ndarray,
    gain: float,
    level: Level,
    lvl: int,
    sel: np.ndarray,
    A: Frame,
    B: Frame,
    dt: float,
) -> np.ndarray:
    """(len(sel),) bool: points that stay put in the image while the road moves.

    Two hypotheses per point w_a: it is fixed to the camera (the ego body, the mount,
    dirt on the lens), then ``B(w_a) = A(w_a)``; or it moves with the road by
    ``dw = w_b(x) - w_a``, then B at w_a shows what A had at ``w_a - dw``: ``B(w_a) ~=
    A(w_a - dw)``. A point is "static" when B(w_a) matches A(w_a) within
    ``snoop_threshold`` times its noise R and is at least twice as far from the road
    hypothesis. Such points are dropped for the pair. gain: the brightness gain B -> A
    of the last linearisation; x (9,): the state the road moves with.
    """
    if not cfg.static_test or len(sel) == 0:
        return np.zeros(len(sel), bool)
    idx = level.roi_idx[sel]
    s = float(level.scale)
    a_val = A.stacks[lvl][0].ravel()[idx].astype(np.float64)
    b_val = gain * B.stacks[lvl][0].ravel()[idx].astype(np.float64)
    P_b = map_rays(np.take(level.roi_rays, sel, 0), homography(x, K0, dt))
    w_a = np.take(level.roi_w, sel, 0) / s  # [level px]
    dw = nan_to_num_fast(camera.project(P_b) / s - w_a)
    a_moved = sample_points(A.stacks[lvl][:1], w_a - dw)[:, 0].astype(np.float64)
    g2 = A.mags[lvl].ravel()[idx].astype(np.float64) ** 2
    thr = cfg.snoop_threshold * (cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * g2)
    return ((b_val - a_val) ** 2 <= thr) & ((b_val - a_moved) ** 2 > 4.0 * thr)
