"""Which candidate points of each pyramid level a frame's masks keep out of the fit.

A mask at the off-road mask's level (``mask_level``, (H_m, W_m) uint8: the off-road map
of `estimator.egomotion.offroad_map`, the appearance map of
`estimator.egomotion.road_appearance`) or a given road mask at full resolution keeps out
every candidate whose support (``mask_support_px`` level pixels: the blur and gradient
kernels a point's brightness reads) touches a marked pixel. Per level the result is
(M,) bool over the level's candidates (``Level.roi_idx``), computed once per pair: every
pass of a pair (own map, yaw refit, manoeuvre retry) selects from it. `carry_map` keeps
the last usual fit's map for the pairs whose own fit makes none.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.levels import Level


def set_mask_index(levels: list[Level], mask_lvl: int) -> None:
    """Set each level's ``to_mask`` (M,): the flat index of its candidates' pixels in the
    grid of level mask_lvl (nearest pixel, clipped to the grid)."""
    grid = levels[mask_lvl]
    hm, wm = grid.shape
    sm = float(grid.scale)
    for level in levels:
        um = np.clip(np.rint(level.roi_w[:, 0] / sm), 0, wm - 1).astype(np.int64)
        vm = np.clip(np.rint(level.roi_w[:, 1] / sm), 0, hm - 1).astype(np.int64)
        level.to_mask = vm * wm + um


def union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """a | b of two (H, W) uint8 maps, either None (absent)."""
    if a is None or b is None:
        return a if b is None else b
    return a | b


def excluded(
    cfg: DirectConfig,
    levels: list[Level],
    mask_scale: float,
    offroad: np.ndarray | None,
    look: np.ndarray | None = None,
) -> list[np.ndarray] | None:
    """Per level, (M,) bool: candidates within their support of a pixel of the off-road
    map offroad (H_m, W_m), and at the ``road_appearance_levels`` finest levels of the
    appearance map look (H_m, W_m) too; None without either. mask_scale: the maps'
    level scale 2^l (full-resolution px per map px)."""
    n_look = min(cfg.road_appearance_levels, len(levels)) if look is not None else 0
    if n_look == 0:
        return dilations(cfg, levels, mask_scale, offroad)
    both = dilations(cfg, levels, mask_scale, union(offroad, look), stop=n_look)
    if offroad is None:
        return both + [np.zeros(len(level.roi_idx), bool) for level in levels[n_look:]]
    return both + dilations(cfg, levels, mask_scale, offroad, start=n_look)


def dilations(
    cfg: DirectConfig,
    levels: list[Level],
    mask_scale: float,
    offroad: np.ndarray | None,
    start: int = 0,
    stop: int | None = None,
) -> list[np.ndarray] | None:
    """`excluded` of one map (H_m, W_m) at levels start..stop-1 (stop None: all); None
    without a map."""
    if offroad is None:
        return None
    out = []
    m, done = offroad, 0  # the mask dilated by radius `done` [map px] so far
    for level in levels[start:stop]:
        r = math.ceil(cfg.mask_support_px * level.scale / mask_scale)
        if r < done:  # (radii grow with the level; else start over)
            m, done = offroad, 0
        if r > done:
            # a square dilation of a square dilation is one by the summed radius (max
            # is exact): each level dilates the previous one by the radius it adds
            m = cv2.dilate(m, np.ones((2 * (r - done) + 1,) * 2, np.uint8))
            done = r
        out.append(m.ravel()[level.to_mask] > 0)
    return out


def given_offroad(
    cfg: DirectConfig, levels: list[Level], road: np.ndarray | None
) -> list[np.ndarray] | None:
    """Per level, (M,) bool: candidates within their support of a pixel that the given
    road mask road (H, W) bool says is not road (their depth is unknown); None without a
    mask."""
    if road is None:
        return None
    off = (~road).astype(np.uint8) * 255
    r = math.ceil(cfg.mask_support_px)  # [level px]
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    out = []
    for level in levels:
        s = int(level.scale)
        h, w = off.shape[0] // s, off.shape[1] // s
        # any non-road pixel in the level pixel's block (area mean > 0)
        m = (cv2.resize(off, (w, h), interpolation=cv2.INTER_AREA) > 0) if s > 1 else off
        m = cv2.dilate(m.astype(np.uint8), kernel) if r else m
        u = np.rint(level.roi_w[:, 0] / s).astype(np.int64).clip(0, w - 1)
        v = np.rint(level.roi_w[:, 1] / s).astype(np.int64).clip(0, h - 1)
        out.append(m[v, u] > 0)
    return out


def carry_map(
    cfg: DirectConfig, carried: tuple[np.ndarray, int]
) -> tuple[np.ndarray | None, tuple[np.ndarray, int] | None]:
    """(map for the next pair, what carries on) from carried = (the last usual fit's
    off-road map (H_m, W_m) uint8, the pairs it has been carried): the map dilated by
    ``map_carry_px`` per pair carried; (None, None) after ``map_carry`` pairs."""
    m, age = carried
    if age >= cfg.map_carry:
        return None, None
    r = cfg.map_carry_px
    m = cv2.dilate(m, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) if r > 0 else m
    return m, (m, age + 1)
