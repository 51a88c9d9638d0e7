"""Settings of the direct estimator (`estimator.egomotion.direct`): `DirectConfig`, the camera-kind
defaults (``KIND_DEFAULTS``), the allowed range of every setting (``RANGES``, checked by
`check_settings`) and the checked construction from a mapping (`make_config`, shared by every
estimator's settings: a YAML ``estimator:`` block and ``omnibench estimate --set`` reach them here).

Each setting has one line: what it does, its unit and its range. Units: [level px] are pixels
of the point's pyramid level, [mask px] of the off-road map's level (``mask_level``).
docs/DESIGN.md holds the measurements that chose the values.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.egomotion.iekf import FilterConfig

# [m] the ego car's body below the beltline (length, width, height), centred on the car origin:
# the simulator's mid-size car, 5.0 x 1.94 m, beltline 0.80 m, the hood rising to 0.88 m
EGO_BODY_BOX_M = (5.0, 1.94, 0.88)


# ------------------------------------------------------------------ config
@dataclass(frozen=True)
class DirectConfig:
    """Settings of `DirectEstimator`, each with [unit] and range (``RANGES``)."""

    levels: int = 4  # pyramid levels, 0 = full resolution [-], >= 1
    iterations: tuple[int, ...] = (5, 4, 3, 2)  # IEKF iterations per level, coarse first [-], >= 0
    max_points: int = 1500  # points selected per level [-], >= 1
    grad_threshold: float = 2.0  # least gradient magnitude of a candidate [DN/level px], >= 0
    nms: bool = True  # keep only 3x3 local maxima of the gradient magnitude
    selection: str = "information"  # rank candidates by "information" or "gradient"
    select_cells: int = 16  # points spread over cells x cells with equal quotas [-], >= 1
    static_test: bool = True  # drop points that stay put while the road moves (body, mount)
    offroad_mask: bool = True  # skip the points that the previous pair's off-road map marks
    own_map: bool = True  # a pair without a map maps its first frame from its own fit, refits
    map_carry: int = 0  # pairs an unusual or failed fit carries the last usual map over [-], >= 0
    map_carry_px: int = 3  # dilation of a carried map per pair [mask px], >= 0
    first_map_residuals: bool = True  # the first pair's own map also marks large residuals
    first_fit_A: bool = True  # keep the first fit's A (False: A stays at the mount's prior)
    fit_A: bool = True  # keep every fit's A (False: A integrates the measured roll/pitch rates)
    mask_level: int = 0  # pyramid level of the off-road map [-], 0..levels-1
    coarse_without_map: bool = True  # coarse levels the map leaves < min_points select without it
    mask_motion_px: float = 0.5  # residual motion that marks a pixel off-road [mask px], >= 0
    parallax_level: int | None = None  # parallax test's level, None: mask_level [-], 0..levels-1
    # parallax test's plane scales h / (h - z) of surfaces z above the road [-], > 0; (): off
    parallax_lambdas: tuple[float, ...] = (1.08, 1.15, 1.3, 1.6)
    parallax_baseline_m: float = 0.5  # parallax test's least baseline [m], >= 0 (0: the pair)
    parallax_baseline_frames: int = 6  # most frame pairs the parallax baseline spans [-], >= 1
    parallax_ratio: float = 0.7  # residual energy share a lambda must get below [-], (0, 1]
    parallax_window_px: float = 1.5  # Gaussian window (sigma) of the energies [mask px], > 0
    parallax_min_px: float = 0.25  # least extra motion for a lambda to be tested [mask px], >= 0
    raised_memory: float = 0.7  # weight on the past of the raised-cell evidence [-], [0, 1)
    raised_level: int = 2  # pyramid level of the raised-evidence cells [-], 0..levels-1
    raised_share: float = 0.3  # averaged marked share that marks a whole cell [-], (0, 1]
    road_appearance: bool = False  # also exclude what does not look like the road near the car
    road_appearance_levels: int = 1  # finest levels the appearance map excludes [-], 0..levels
    mask_smear: float = 0.2  # marks smeared along +/- this share of their motion [-], >= 0
    mask_support_px: float = 2.0  # dilation of the map when a level selects [level px], >= 0
    coarse_fix_A: bool = True  # coarse levels (l > 0) leave A to the finest level
    search_levels: tuple[int, ...] = (2, 1, 0)  # levels with a grid search first, 0..levels-1
    search_points: int = 300  # points of the speed/yaw grid search [-], >= 1
    search_sigmas: float = 3.0  # half-width of the grid search [prior std], > 0
    search_steps: int = 3  # most grid steps each side of x̂ (beyond: coarser) [-], >= 0
    search_step_px: float = 1.5  # grid step, of the 90th-percentile motion [level px], > 0
    search_truncation: float = 9.0  # cap of a point's search cost [sigma_intensity²], > 0
    line_search: bool = True  # halve an iteration's step when it raised the cost
    max_halvings: int = 3  # step halvings per level [-], >= 0
    manoeuvre_retry: bool = True  # refit with a manoeuvre-wide prior when the road did not align
    retry_noise_ratio: float = 3.0  # s² over the recent median that also retries [-], > 0
    manoeuvre_W_sigma_rps: float = 1.0  # retry's added yaw-rate std [rad/s], >= 0
    manoeuvre_W_plane_sigma_rps: float = 0.2  # retry's added roll/pitch-rate std [rad/s], >= 0
    retry_gain: float = 3.0  # s² ratio by which a retry must beat a fit that held [-], >= 1
    # the retry's wide levels, a pass with a wide grid search from each [-], 0..levels-1
    manoeuvre_search_levels: tuple[int, ...] = (2, 1, 0)
    manoeuvre_fine_passes: bool = True  # a wide level also passes without the coarser levels
    manoeuvre_iterations: tuple[int, ...] = (5, 4, 10, 10)  # the retry's `iterations` [-], >= 0
    manoeuvre_local_search: bool = True  # the retry's finer levels start with a local search
    # share of the points a fit sees from which its inliers count against those [-], [0, 1]
    seen_inlier_fraction: float = 0.5
    manoeuvre_search_steps: int = 12  # grid steps each side of the retry's wide search [-], >= 0
    manoeuvre_search_points: int = 1200  # points of the retry's wide search [-], >= 1
    yaw_jump_sigmas: float = 3.0  # yaw shift that triggers a refit [shift std], >= 0 (0: off)
    yaw_jump_widen: float = 2.0  # refit's added yaw std [the shift seen], > 0
    yaw_jump_rounds: int = 3  # refits at most [-], >= 1
    # the retry's added std of V, forward / lateral / vertical in car axes [m/s], >= 0 each
    manoeuvre_V_sigma_mps: tuple[float, float, float] = (0.5, 3.0, 0.5)
    manoeuvre_slip_sigma_mps: float = 0.5  # retry's std of the rear axle's slip [m/s], >= 0
    presmooth_sigma_px: float = 0.7  # Gaussian blur of the full-resolution frame [px], >= 0
    sigma_intensity: float = 2.0  # noise of one brightness sample [DN], > 0
    sigma_flow_px: float = 0.2  # model/interpolation noise as a flow error [level px], >= 0
    flow_noise_frac: float = 0.0  # model noise as this share of a point's motion [-], >= 0
    offroad_depth_sigma: float = 1.0  # std of an unknown-depth point's plane scale [-], >= 0
    far_depth_m: float = 0.0  # road beyond this is of unknown depth [m], >= 0 (0: off)
    far_depth_levels: int = 1  # finest levels where far_depth_m applies [-], 0..levels
    independent_points: int = 100  # inliers weigh as at most this many points [-], >= 0 (0: all)
    outliers: str = "snooping"  # "snooping" (eq. 20-21), "huber", "tukey" or "none"
    snoop_threshold: float = 9.0  # Mahalanobis² above which a point is an outlier [-], > 0
    robust_k: float = 2.5  # Huber / Tukey tuning constant [sigma], > 0
    adaptive_noise: bool = True  # scale R by the robust (median) residual level
    max_noise_scale: float = 10.0  # s² above which a fit is "poor", x the usual s² [-], > 0
    step_tol: float = 0.05  # a level stops below this Mahalanobis step norm [-], >= 0
    gain_compensation: bool = True  # fit a global brightness gain B -> A each iteration
    max_range_m: float = 30.0  # farthest road point used, horizontal [m], > 0
    max_flow_px: float = 64.0  # road points moving farther are not selected [px], >= 0 (0: off)
    # the ego body, masked from the rays (length, width, height) [m], > 0 each; None: off
    ego_box_m: tuple[float, float, float] | None = EGO_BODY_BOX_M
    ego_margin_m: float = 0.1  # margin around ego_box_m [m], >= 0
    roi_erode_px: int = 3  # distance kept from the image edges [level px], >= 0
    min_points: int = 40  # fewer points or inliers at a level skip it [-], >= 1
    min_inlier_fraction: float = 0.25  # fewer inliers at the finest level: degraded [-], [0, 1]
    dark_level: float = 12.0  # mean brightness below which a frame is "dark" [DN], [0, 255]
    saturated_level: float = 250.0  # brightness counted as saturated [DN], [0, 255]
    saturated_fraction: float = 0.5  # saturated share of the ROI that flags a frame [-], [0, 1]
    can_missing_inflation: float = 4.0  # variance factor on V while the CAN is lost [-], >= 1
    flat_field: bool = False  # divide the camera's vignetting out of each frame
    compensate: bool = False  # return the motion-compensated previous frame
    filter: FilterConfig = field(default_factory=FilterConfig)  # the IEKF's settings

    def __post_init__(self) -> None:
        check_settings(self, "direct")


# ------------------------------------------------------------------ ranges
@dataclass(frozen=True)
class Setting:
    """The values one setting takes: its type and range (``RANGES``, `check_settings`)."""

    kind: type  # bool, int, float or str (a float setting takes an int too)
    lo: float | str | None = None  # least value; a str names a setting: "levels", "levels-1"
    hi: float | str | None = None  # greatest value, as ``lo``
    open_lo: bool = False  # lo itself excluded
    open_hi: bool = False  # hi itself excluded
    inf: bool = False  # +inf allowed ("never", "kept"); otherwise a float must be finite
    choices: tuple[str, ...] = ()  # the words a str setting takes
    n: int | str | None = (
        None  # a tuple of n values (a setting's name: its value; "any"); None: one
    )
    none: bool = False  # None allowed

    def check(self, value: Any, key: str, cfg: Any) -> None:
        """ValueError naming ``key``, ``value`` and the allowed values unless ``value`` is one."""
        if value is None and self.none:
            return
        if self.n is None:
            self._check_one(value, key, cfg)
            return
        n = None if self.n == "any" else self._resolve(self.n, cfg)
        if not isinstance(value, tuple) or (n is not None and len(value) != n):
            raise ValueError(f"{key} takes {self._describe_tuple(cfg)}, got {value!r}")
        for i, item in enumerate(value):
            self._check_one(item, f"{key}[{i}]", cfg)

    def _describe_tuple(self, cfg: Any) -> str:
        """A tuple setting's values in words: "None or 3 floats, each finite and > 0"."""
        what, kinds = self._range(cfg), f"{self.kind.__name__}s"
        if self.n == "any":
            text = f"a tuple of {kinds}"
        else:
            ref = f" (as many as {self.n})" if isinstance(self.n, str) else ""
            text = f"{self._resolve(self.n, cfg)} {kinds}{ref}"
        text += f", each {what}" if what else ""
        return f"None or {text}" if self.none else text

    def _check_one(self, value: Any, key: str, cfg: Any) -> None:
        if not _is_kind(value, self.kind):
            what = self._range(cfg)
            what = f"{_ARTICLE[self.kind]} ({what})" if what else _ARTICLE[self.kind]
            raise ValueError(f"{key} takes {what}, got {value!r}")
        if self.choices:
            ok = value in self.choices
        elif self.kind in (int, float):
            x = float(value)
            lo, hi = self._resolve(self.lo, cfg), self._resolve(self.hi, cfg)
            ok = (math.isfinite(x) or (self.inf and x == math.inf)) and not (
                (lo is not None and (x <= lo if self.open_lo else x < lo))
                or (hi is not None and (x >= hi if self.open_hi else x > hi))
            )
        else:
            ok = True
        if not ok:
            raise ValueError(f"{key} must be {self._range(cfg)}, got {value!r}")

    def _range(self, cfg: Any) -> str:
        """The range in words (empty for a flag): "in 0..levels-1 = 0..3", "finite and > 0"."""
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind not in (int, float):
            return ""
        lo, hi = self._resolve(self.lo, cfg), self._resolve(self.hi, cfg)
        ref = isinstance(self.lo, str) or isinstance(self.hi, str)
        if self.kind is int and lo is not None and hi is not None:
            text = f"in {self.lo}..{self.hi} = {lo}..{hi}" if ref else f"in {lo}..{hi}"
        elif lo is not None and hi is not None:
            left, right = "(" if self.open_lo else "[", ")" if self.open_hi else "]"
            text = f"in {left}{lo:g}, {hi:g}{right}"
        elif lo is not None:
            text = f"{'>' if self.open_lo else '>='} {lo:g}"
        elif hi is not None:
            text = f"{'<' if self.open_hi else '<='} {hi:g}"
        else:
            text = ""
        if self.kind is float and not self.inf and (hi is None):
            text = f"finite and {text}" if text else "finite"
        return text

    @staticmethod
    def _resolve(bound: float | str | None, cfg: Any) -> Any:
        """A bound's value: a number, or a setting of ``cfg`` ("levels-1": its value - 1)."""
        if not isinstance(bound, str):
            return bound
        name, _, minus = bound.partition("-")
        return getattr(cfg, name) - int(minus or 0)


_ARTICLE = {bool: "a bool", int: "an int", float: "a float", str: "a str"}


def _is_kind(value: Any, kind: type) -> bool:
    """Whether ``value`` is of ``kind`` (a float setting takes an int; a bool is no number)."""
    if isinstance(value, bool | np.bool_):
        return kind is bool
    if kind is int:
        return isinstance(value, int | np.integer)
    if kind is float:
        return isinstance(value, int | float | np.integer | np.floating)
    return isinstance(value, kind)


FLAG = Setting(bool)


def count(lo: int | str = 0, hi: int | str | None = None, **kw: Any) -> Setting:
    """An int setting in lo..hi (a bound may name a setting: "levels-1")."""
    return Setting(int, lo, hi, **kw)


def real(lo: float | None = None, hi: float | None = None, **kw: Any) -> Setting:
    """A float setting in [lo, hi] (``open_lo``/``open_hi``: excluded), finite unless ``inf``."""
    return Setting(float, lo, hi, **kw)


POSITIVE = real(0.0, open_lo=True)
NONNEG = real(0.0)
SHARE = real(0.0, 1.0)
LEVEL = count(0, "levels-1")

# The allowed values of every setting of `DirectConfig` and `FilterConfig` (the one-line comment
# beside each setting says the same in words), checked by `check_settings`.
RANGES: dict[type, dict[str, Setting]] = {
    DirectConfig: {
        "levels": count(1),
        "iterations": count(0, n="levels"),
        "max_points": count(1),
        "grad_threshold": NONNEG,
        "nms": FLAG,
        "selection": Setting(str, choices=("information", "gradient")),
        "select_cells": count(1),
        "static_test": FLAG,
        "offroad_mask": FLAG,
        "own_map": FLAG,
        "map_carry": count(0),
        "map_carry_px": count(0),
        "first_map_residuals": FLAG,
        "first_fit_A": FLAG,
        "fit_A": FLAG,
        "mask_level": LEVEL,
        "coarse_without_map": FLAG,
        "mask_motion_px": NONNEG,
        "parallax_level": count(0, "levels-1", none=True),
        "parallax_lambdas": real(0.0, open_lo=True, n="any"),
        "parallax_baseline_m": real(0.0, inf=True),
        "parallax_baseline_frames": count(1),
        "parallax_ratio": real(0.0, 1.0, open_lo=True),
        "parallax_window_px": POSITIVE,
        "parallax_min_px": NONNEG,
        "raised_memory": real(0.0, 1.0, open_hi=True),
        "raised_level": LEVEL,
        "raised_share": real(0.0, 1.0, open_lo=True),
        "road_appearance": FLAG,
        "road_appearance_levels": count(0, "levels"),
        "mask_smear": NONNEG,
        "mask_support_px": NONNEG,
        "coarse_fix_A": FLAG,
        "search_levels": count(0, "levels-1", n="any"),
        "search_points": count(1),
        "search_sigmas": POSITIVE,
        "search_steps": count(0),
        "search_step_px": POSITIVE,
        "search_truncation": POSITIVE,
        "line_search": FLAG,
        "max_halvings": count(0),
        "manoeuvre_retry": FLAG,
        "retry_noise_ratio": POSITIVE,
        "manoeuvre_W_sigma_rps": NONNEG,
        "manoeuvre_W_plane_sigma_rps": NONNEG,
        "retry_gain": real(1.0),
        "manoeuvre_search_levels": count(0, "levels-1", n="any"),
        "manoeuvre_fine_passes": FLAG,
        "manoeuvre_iterations": count(0, n="levels"),
        "manoeuvre_local_search": FLAG,
        "seen_inlier_fraction": SHARE,
        "manoeuvre_search_steps": count(0),
        "manoeuvre_search_points": count(1),
        "yaw_jump_sigmas": NONNEG,
        "yaw_jump_widen": POSITIVE,
        "yaw_jump_rounds": count(1),
        "manoeuvre_V_sigma_mps": real(0.0, n=3),
        "manoeuvre_slip_sigma_mps": NONNEG,
        "presmooth_sigma_px": NONNEG,
        "sigma_intensity": POSITIVE,
        "sigma_flow_px": NONNEG,
        "flow_noise_frac": NONNEG,
        "offroad_depth_sigma": NONNEG,
        "far_depth_m": NONNEG,
        "far_depth_levels": count(0, "levels"),
        "independent_points": count(0),
        "outliers": Setting(str, choices=("snooping", "huber", "tukey", "none")),
        "snoop_threshold": POSITIVE,
        "robust_k": POSITIVE,
        "adaptive_noise": FLAG,
        "max_noise_scale": POSITIVE,
        "step_tol": NONNEG,
        "gain_compensation": FLAG,
        "max_range_m": POSITIVE,
        "max_flow_px": NONNEG,
        "ego_box_m": real(0.0, open_lo=True, n=3, none=True),
        "ego_margin_m": NONNEG,
        "roi_erode_px": count(0),
        "min_points": count(1),
        "min_inlier_fraction": SHARE,
        "dark_level": real(0.0, 255.0),
        "saturated_level": real(0.0, 255.0),
        "saturated_fraction": SHARE,
        "can_missing_inflation": real(1.0),
        "flat_field": FLAG,
        "compensate": FLAG,
    },
    FilterConfig: {
        "V_walk_mps": real(0.0, n=3),
        "W_walk_rps": NONNEG,
        "W_walk_yaw_rps": NONNEG,
        "W_tau_s": real(0.0, open_lo=True, inf=True),
        "A_from_W": FLAG,
        "A_walk_rad": NONNEG,
        "A_tau_s": POSITIVE,
        "rate_bias_tau_s": NONNEG,
        "A_sigma_plane_rad": POSITIVE,
        "A_sigma_normal_rad": POSITIVE,
        "V0_sigma_mps": real(0.0, open_lo=True, n=3),
        "W0_sigma_rps": POSITIVE,
        "can_rel_sigma": NONNEG,
        "can_abs_sigma_mps": POSITIVE,
        "nonholonomic_sigma_mps": NONNEG,
        "vertical_speed_sigma_mps": NONNEG,
        "can_gate_rel": NONNEG,
        "nominal_dt_s": real(0.0, open_lo=True, none=True),
        "gap_factor": real(1.0),
    },
}


def check_settings(cfg: Any, where: str) -> None:
    """ValueError naming the dotted key (``where.filter.A_tau_s``), the value and the allowed
    values of the first setting of dataclass ``cfg``, or of a dataclass it nests, that lies
    outside its ``RANGES`` entry (settings of classes without one are not checked)."""
    table = RANGES.get(type(cfg), {})
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        key = f"{where}.{f.name}"
        if dataclasses.is_dataclass(value):
            check_settings(value, key)
        elif f.name in table:
            table[f.name].check(value, key, cfg)


# Settings that differ by camera kind (docs/DESIGN.md, "The pinhole camera"). A pinhole sees a
# narrow wedge of road, where a yaw rotation and a pitch offset of the camera move the image
# almost alike: it needs every textured pixel and the far road. Omni keeps the class defaults.
KIND_DEFAULTS: dict[str, dict[str, Any]] = {
    "omni": {},
    "pinhole": {
        "flat_field": True,  # its road crosses the vignetting, which read as a roll rate
        "mask_level": 1,  # its textured road is far, fine enough at level 1 (0 measured worse)
        "coarse_without_map": False,  # on: the merge's yaw rate measured worse
        "parallax_lambdas": (1.15, 1.3, 1.6),  # with 1.08 all four drives measured worse
        "parallax_min_px": 0.5,  # 0.25 measured worse (highway, merge, roundabout yaw)
        "parallax_baseline_m": 0.0,  # composed motions misalign over a narrow view
        "raised_memory": 0.0,  # 0.7 measured worse (merge, roundabout and racetrack yaw)
        "max_range_m": 60.0,  # the far road tells a yaw rotation from a pitch offset
        "far_depth_m": 20.0,  # far guard rails that the parallax test cannot resolve
        "nms": False,  # every textured pixel
        "max_points": 20000,  # every textured pixel
        "first_map_residuals": False,  # the first pair's residual marks followed the CAN's error
        "yaw_jump_sigmas": 2.0,  # its fits meet a steering step ~2 sigma short
        "map_carry": 2,  # a vehicle close behind fills the view
        "road_appearance": True,  # far rails and kerb islands within the parallax noise
        "flow_noise_frac": 0.03,  # its near road's look changes with the motion
        "grad_threshold": 2.0,  # every textured pixel
        "selection": "gradient",  # every textured pixel: nothing to rank
        "select_cells": 1,  # every textured pixel: nothing to spread
        "independent_points": 100,  # neighbouring pixels share much of their error
        "fit_A": False,  # a narrow view tells the plane's tilt poorly, the rates well
        "filter": {
            "rate_bias_tau_s": 2.0,  # A integrates the rates: their bias is learnt out
            "A_tau_s": 0.5,  # A reverts to the mount
            "nonholonomic_sigma_mps": 0.05,  # a roll rate looks like a side slip
            "vertical_speed_sigma_mps": 0.1,  # ... and like a vertical speed
        },
        "first_fit_A": False,  # the first fit, without a map, misreads A
        "manoeuvre_V_sigma_mps": (2.0, 3.0, 0.5),  # a collision changes the speed abruptly
    },
}


def default_config(kind: str, **overrides: Any) -> DirectConfig:
    """`DirectConfig` for a camera kind (``KIND_DEFAULTS``) with ``overrides`` applied."""
    if kind not in KIND_DEFAULTS:
        raise ValueError(f"unknown camera kind {kind!r}; known: {', '.join(KIND_DEFAULTS)}")
    return make_config(DirectConfig, _merged(KIND_DEFAULTS[kind], overrides), "direct")


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``over``, nested mappings (``filter``) key by key."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merged(out[key], value) if both else value
    return out


def make_config(cls: type, overrides: dict[str, Any], where: str) -> Any:
    """Dataclass ``cls`` with ``overrides`` applied; nested dataclasses take dicts.

    An unknown key, or a value outside its range (``RANGES``; the type of the default for a
    class without one), raises ValueError with its dotted path (``direct.filter.bad``).
    """
    names = {f.name: f for f in dataclasses.fields(cls)}
    ranges = RANGES.get(cls, {})
    kw: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in names:
            raise ValueError(f"unknown setting {where}.{key}; known: {', '.join(sorted(names))}")
        default = names[key].default
        if default is dataclasses.MISSING and names[key].default_factory is not dataclasses.MISSING:
            default = names[key].default_factory()
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = make_config(type(default), value, f"{where}.{key}")
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        if key not in ranges:
            _check_type(value, default, f"{where}.{key}")
        kw[key] = value
    cfg = cls(**kw)
    check_settings(cfg, where)
    return cfg


def _check_type(value: Any, default: Any, where: str) -> None:
    """ValueError when value cannot stand for a setting whose default is ``default``: a
    flag takes true / false, a number a number, a word a word (other settings unchecked)."""
    if isinstance(default, bool):
        ok = isinstance(value, bool | np.bool_)
    elif isinstance(default, int | float):
        ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
            value, bool | np.bool_
        )
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        return
    if not ok:
        raise ValueError(
            f"setting {where} takes a {type(default).__name__} (default {default!r}), got {value!r}"
        )
