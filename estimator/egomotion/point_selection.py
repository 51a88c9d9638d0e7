"""Point selection of the direct estimator (section 4): candidates of the road region by
gradient magnitude (and non-maximal suppression), ranked by the information they carry
under the prior and spread over the image."""

from __future__ import annotations

import numpy as np

from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.homography import A_SLICE, N_STATE
from estimator.egomotion.levels import Level
from estimator.egomotion.pyramid import Frame, roi_gradients


def column_scale(dt_s: float, speed_mps: float) -> np.ndarray:
    """(9,) factors turning `selection_jacobian` into dw/dx for this dt and speed."""
    f = np.full(N_STATE, dt_s)
    f[A_SLICE] = dt_s * max(abs(speed_mps), 0.5)
    return f


def select_points(
    level: Level,
    frame: Frame,
    lvl: int,
    cfg: DirectConfig,
    P: np.ndarray | None = None,
    col_scale: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
    x: np.ndarray | None = None,
) -> np.ndarray:
    """Indices into level.roi_idx of the selected points of frame A at a level.

    Candidates: gradient magnitude above ``grad_threshold`` (level px), 3x3 maxima
    with ``nms``, not ``exclude`` (M,) bool (off-road mask), and, given the state x (9,)
    and col_scale, not moved more than ``max_flow_px`` by it (`too_fast`). At most ``max_points``
    are kept, spread over a grid of ``select_cells``² cells (`_spread_top`), ranked:

    - ``selection="information"`` (with the prior covariance P (9, 9)): by how much the
      prior's uncertainty moves the point's brightness, relative to its noise. With
      ``c = gᵀ dw/dx`` (dw/dx from ``level.sel_J`` times ``col_scale`` (9,)) and
      ``P = L Lᵀ``, the whitened sensitivities ``u = Lᵀ c / sqrt(R)`` add up to eq. 20's
      ``c P cᵀ / R``; each of their 9 components is divided by its total over the
      candidates, so that a point informative about a direction few points see (A,
      the vertical speed) is not outranked by the many that see the speed;
    - ``"gradient"``: by gradient magnitude (the paper's choice).

    A gradient-strength ranking picks the strongest edges of the road ring: guard
    rails, posts, vehicles and the ego car's roof, not the road.
    """
    mag, lmax = roi_gradients(frame, level, lvl)
    keep = mag > cfg.grad_threshold
    if cfg.nms:
        keep &= lmax
    if exclude is not None:
        keep &= ~exclude
    sel = np.flatnonzero(keep)
    if x is not None and col_scale is not None and cfg.max_flow_px > 0:
        sel = sel[~too_fast(np.take(level.sel_J, sel, 0), x, col_scale, cfg.max_flow_px)]
    if len(sel) > cfg.max_points:
        if cfg.selection == "information" and P is not None and col_scale is not None:
            idx = level.roi_idx[sel]
            gu = frame.stacks[lvl][1].ravel()[idx].astype(np.float64)
            gv = frame.stacks[lvl][2].ravel()[idx].astype(np.float64)
            J = np.take(level.sel_J, sel, 0)
            s = 1.0 / level.scale  # level gradients -> per full-resolution pixel
            c = (gu[:, None] * J[:, 0] + gv[:, None] * J[:, 1]) * (col_scale * s)
            R = cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * mag[sel].astype(np.float64) ** 2
            # whitened sensitivities u = Lᵀ c / sqrt(R) (P = L Lᵀ): |u|² = c P cᵀ / R; each
            # direction's share of the total information, so that every direction counts
            u2 = np.square(c @ np.linalg.cholesky(P + 1e-18 * np.eye(N_STATE))) / R[:, None]
            score = np.sum(u2 / np.maximum(u2.sum(axis=0), 1e-300), axis=1)
        else:
            score = mag[sel]
        sel = np.sort(
            sel[_spread_top(np.take(level.roi_w, sel, 0), score, cfg.max_points, cfg.select_cells)]
        )
    return sel


def too_fast(
    sel_J: np.ndarray, x: np.ndarray, col_scale: np.ndarray, max_flow_px: float
) -> np.ndarray:
    """(N,) bool: points that state x (9,) moves more than max_flow_px (full-resolution
    px) over the pair, to first order: their selection Jacobian sel_J (N, 2, 9) times x
    scaled by `column_scale` (col_scale)."""
    flow = sel_J @ (x * col_scale).astype(np.float32)  # (N, 2) [px]
    return np.einsum("ij,ij->i", flow, flow) > max_flow_px**2


def _spread_top(w: np.ndarray, score: np.ndarray, n: int, cells: int) -> np.ndarray:
    """Indices of n of the points w (N, 2) [full-res px]: the best scores of each cell of a
    cells x cells grid over their bounding box (equal quota per occupied cell), then the
    best of the rest. Spreading the points over the image keeps the state's directions
    that only differ across the field of view (e.g. a pinhole's yaw and pitch) apart."""
    if cells <= 1:
        return np.argpartition(-score, n - 1)[:n]
    lo, hi = w.min(axis=0), w.max(axis=0)
    ij = np.minimum(((w - lo) / np.maximum(hi - lo, 1e-9) * cells).astype(np.int64), cells - 1)
    cell = ij[:, 1] * cells + ij[:, 0]
    order = np.lexsort((-score, cell))  # by cell, best score first
    c_sorted = cell[order]
    first = np.searchsorted(c_sorted, c_sorted, side="left")
    rank = np.empty(len(w), np.int64)
    rank[order] = np.arange(len(w)) - first  # rank of each point within its cell
    quota = max(1, n // len(np.unique(cell)))
    take = rank < quota
    chosen = np.flatnonzero(take)
    if len(chosen) > n:
        return chosen[np.argpartition(-score[chosen], n - 1)[:n]]
    rest = np.flatnonzero(~take)
    k = n - len(chosen)
    if k > 0 and len(rest):
        rest = rest[np.argpartition(-score[rest], min(k, len(rest)) - 1)[:k]]
        chosen = np.concatenate([chosen, rest])
    return chosen
