"""The settings' ranges (`estimator.egomotion.direct_config.RANGES`): every default passes, every
value outside a range is refused with its dotted key, the value and the allowed range."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

from estimator.egomotion.direct_config import (
    KIND_DEFAULTS,
    RANGES,
    DirectConfig,
    check_settings,
    default_config,
    make_config,
)
from estimator.egomotion.iekf import FilterConfig
from scenarios.cli import parse_settings


def test_every_setting_has_a_range() -> None:
    for cls in (DirectConfig, FilterConfig):
        names = {f.name for f in dataclasses.fields(cls)} - {"filter"}
        assert names == set(RANGES[cls]), names ^ set(RANGES[cls])


@pytest.mark.parametrize("kind", sorted(KIND_DEFAULTS))
def test_every_default_is_in_range(kind: str) -> None:
    cfg = default_config(kind)
    check_settings(cfg, "direct")
    check_settings(DirectConfig(), "direct")
    check_settings(FilterConfig(), "filter")


@pytest.mark.parametrize(
    "overrides, key, allowed",
    [
        ({"mask_level": -3}, "direct.mask_level", "in 0..levels-1 = 0..3"),
        ({"mask_level": 4}, "direct.mask_level", "in 0..levels-1 = 0..3"),
        (
            {"levels": 2, "iterations": (1, 1), "manoeuvre_iterations": (1, 1), "mask_level": 2},
            "direct.mask_level",
            "0..1",
        ),
        ({"mask_level": 1.5}, "direct.mask_level", "takes an int"),
        ({"levels": 0}, "direct.levels", ">= 1"),
        ({"levels": True}, "direct.levels", "takes an int"),
        ({"levels": 3}, "direct.iterations", "3 ints"),
        ({"iterations": (5, 4, -1, 2)}, "direct.iterations[2]", ">= 0"),
        ({"max_points": 0}, "direct.max_points", ">= 1"),
        ({"grad_threshold": -1.0}, "direct.grad_threshold", ">= 0"),
        ({"grad_threshold": math.nan}, "direct.grad_threshold", "finite and >= 0"),
        ({"sigma_intensity": 0.0}, "direct.sigma_intensity", "> 0"),
        ({"sigma_intensity": math.inf}, "direct.sigma_intensity", "finite and > 0"),
        ({"raised_memory": 1.0}, "direct.raised_memory", "in [0, 1)"),
        ({"parallax_ratio": 0.0}, "direct.parallax_ratio", "in (0, 1]"),
        ({"seen_inlier_fraction": 1.5}, "direct.seen_inlier_fraction", "in [0, 1]"),
        ({"parallax_level": 7}, "direct.parallax_level", "0..3"),
        ({"parallax_lambdas": (1.08, -1.0)}, "direct.parallax_lambdas[1]", "> 0"),
        ({"parallax_baseline_m": math.nan}, "direct.parallax_baseline_m", ">= 0"),
        ({"parallax_baseline_frames": 0}, "direct.parallax_baseline_frames", ">= 1"),
        ({"far_depth_m": -5.0}, "direct.far_depth_m", "finite and >= 0"),
        ({"far_depth_m": math.inf}, "direct.far_depth_m", "finite and >= 0"),
        ({"far_depth_levels": 5}, "direct.far_depth_levels", "0..levels = 0..4"),
        ({"search_levels": (2, 9)}, "direct.search_levels[1]", "0..3"),
        ({"manoeuvre_V_sigma_mps": (0.5, 3.0)}, "direct.manoeuvre_V_sigma_mps", "3 floats"),
        ({"ego_box_m": (5.0, 0.0, 1.0)}, "direct.ego_box_m[1]", "> 0"),
        ({"yaw_jump_rounds": 0}, "direct.yaw_jump_rounds", ">= 1"),
        ({"retry_gain": 0.5}, "direct.retry_gain", ">= 1"),
        ({"dark_level": 300.0}, "direct.dark_level", "in [0, 255]"),
        ({"selection": "random"}, "direct.selection", "'information', 'gradient'"),
        ({"outliers": 3}, "direct.outliers", "takes a str"),
        ({"road_appearance": "maybe"}, "direct.road_appearance", "takes a bool"),
        ({"filter": {"A_tau_s": 0.0}}, "direct.filter.A_tau_s", "> 0"),
        ({"filter": {"W_tau_s": -1.0}}, "direct.filter.W_tau_s", "> 0"),
        ({"filter": {"V_walk_mps": (1.5, -0.5, 0.2)}}, "direct.filter.V_walk_mps[1]", ">= 0"),
        ({"filter": {"nominal_dt_s": 0.0}}, "direct.filter.nominal_dt_s", "> 0"),
        ({"filter": {"gap_factor": math.nan}}, "direct.filter.gap_factor", ">= 1"),
        ({"filter": {"can_gate_rel": "x"}}, "direct.filter.can_gate_rel", "takes a float"),
    ],
)
@pytest.mark.parametrize("kind", ["omni", "pinhole"])
def test_out_of_range_is_named(kind: str, overrides: dict, key: str, allowed: str) -> None:
    with pytest.raises(ValueError) as err:
        default_config(kind, **overrides)
    msg = str(err.value)
    assert msg.startswith(f"{key} "), msg
    assert allowed in msg, msg
    value: object = overrides  # the value named: the override, or its item [i]
    for part in re.findall(r"\.(\w+)|\[(\d+)\]", key):
        name, index = part
        if isinstance(value, dict) and name in value:
            value = value[name]
        elif isinstance(value, tuple) and index:
            value = value[int(index)]
        else:  # another setting is out of range (levels 3: iterations)
            return
    assert msg.endswith(f"got {value!r}"), msg


def test_values_at_the_edges_are_taken() -> None:
    cfg = default_config(
        "omni",
        mask_level=3,
        parallax_level=None,
        parallax_lambdas=(),
        max_range_m=40,  # an int for a float
        raised_memory=0.0,
        seen_inlier_fraction=np.float64(1.0),
        yaw_jump_sigmas=0.0,
        parallax_baseline_m=math.inf,  # always the oldest frame kept
        ego_box_m=None,
        iterations=[0, 4, 3, 2],  # a list, as YAML gives it
        filter={"W_tau_s": math.inf, "nominal_dt_s": 1 / 15, "rate_bias_tau_s": 0},
    )
    assert cfg.iterations == (0, 4, 3, 2) and cfg.max_range_m == 40


def test_direct_construction_and_replace_are_checked() -> None:
    with pytest.raises(ValueError, match=r"^direct\.mask_level must be in 0\.\.levels-1 = 0\.\.3"):
        DirectConfig(mask_level=-1)
    with pytest.raises(ValueError, match=r"^direct\.filter\.A_tau_s must be finite and > 0"):
        dataclasses.replace(DirectConfig(), filter=FilterConfig(A_tau_s=-1.0))


def test_other_estimators_check_their_filter() -> None:
    from estimator.egomotion.baselines import CanOnlyConfig

    with pytest.raises(ValueError, match=r"^can-only\.filter\.can_rel_sigma must be"):
        make_config(CanOnlyConfig, {"filter": {"can_rel_sigma": -0.1}}, "can-only")


@pytest.mark.parametrize(
    "pair, key",
    [
        ("mask_level=-3", "direct.mask_level"),
        ("filter.A_tau_s=-0.5", "direct.filter.A_tau_s"),
        ("parallax_lambdas=[1.1, .nan]", "direct.parallax_lambdas[1]"),
        ("levels=1e9", "direct.levels"),
    ],
)
def test_cli_settings_are_checked(pair: str, key: str) -> None:
    """``omnibench estimate --set KEY=VALUE``'s path: parse_settings, then default_config."""
    with pytest.raises(ValueError, match=rf"^{re.escape(key)} "):
        default_config("pinhole", **parse_settings([pair]))
