"""Baselines (CAN only, feature tracks) and the estimator registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.egomotion.baselines import (
    CanOnlyEstimator,
    FeatureEstimator,
    make_estimator,
)
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.ego_estimator import EgoMotionRecord
from tests.estimator.egomotion.road_pairs import (
    CAN_SCALE,
    DT,
    SPEED,
    preset_camera,
    road_pair,
    state_errors,
)


def test_registry_builds_each_and_names_unknown_choices() -> None:
    camera, mount, _ = preset_camera("omni-near")
    assert isinstance(make_estimator("direct", camera, mount), DirectEstimator)
    assert isinstance(make_estimator("can-only", camera, mount), CanOnlyEstimator)
    assert isinstance(make_estimator("features", camera, mount), FeatureEstimator)
    with pytest.raises(ValueError, match=r"'kalman'.*direct, can-only, features"):
        make_estimator("kalman", camera, mount)
    with pytest.raises(ValueError, match=r"features\.max_corner"):
        make_estimator("features", camera, mount, max_corner=10)
    with pytest.raises(ValueError, match=r"direct\.filter\.can_sigma"):
        make_estimator("direct", camera, mount, filter={"can_sigma": 1.0})
    est = make_estimator("direct", camera, mount, max_points=500, filter={"W_walk_rps": 0.1})
    assert est.cfg.max_points == 500 and est.cfg.filter.W_walk_rps == 0.1
    # a value of the wrong kind is named with its setting, not taken
    with pytest.raises(ValueError, match=r"direct\.road_appearance takes a bool.*'maybe'"):
        make_estimator("direct", camera, mount, road_appearance="maybe")
    with pytest.raises(ValueError, match=r"direct\.filter\.A_tau_s takes a float"):
        make_estimator("direct", camera, mount, filter={"A_tau_s": True})
    with pytest.raises(ValueError, match=r"direct\.outliers takes a str"):
        make_estimator("direct", camera, mount, outliers=3)
    assert make_estimator("direct", camera, mount, max_range_m=40).cfg.max_range_m == 40


def test_can_only_is_dead_reckoning() -> None:
    camera, mount, _ = preset_camera("omni-near")
    img_a, img_b, x_true = road_pair("omni-near")
    est = make_estimator("can-only", camera, mount)
    est.step(img_a, 0.3, 20.0)
    rec = est.step(img_b, 0.3 + DT, 20.0)
    assert isinstance(rec, EgoMotionRecord) and not rec.degraded
    assert rec.speed_mps == pytest.approx(20.0, rel=1e-3)
    assert np.allclose(rec.x, rec.x_prior) and np.allclose(rec.W, 0.0)
    rec = est.step(img_a, 0.3 + 2 * DT, math.nan)
    assert "can-missing" in rec.flags and rec.speed_mps == pytest.approx(20.0, rel=1e-3)
    with pytest.raises(ValueError, match="expected 640x640"):
        est.step(np.zeros((10, 10), np.uint8), 1.0, 20.0)


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_features_fit_the_planar_motion(preset: str) -> None:
    camera, mount, _ = preset_camera(preset)
    img_a, img_b, x_true = road_pair(preset)
    est = make_estimator("features", camera, mount)
    est.step(img_a, 0.3, SPEED * CAN_SCALE)
    rec = est.step(img_b, 0.3 + DT, SPEED * CAN_SCALE)
    assert not rec.degraded, rec.reason
    v_pct, w_dps, a_deg = state_errors(rec, x_true)
    print(
        f"features {preset}: {rec.n_inliers}/{rec.n_points} tracks, V {v_pct:.2f} %, "
        f"W {w_dps.round(2)} deg/s, A {a_deg.round(3)} deg"
    )
    assert v_pct < 2.0  # the CAN prior was 8 % off
    assert np.all(w_dps < 2.0)
    assert rec.n_inliers > 0.5 * rec.n_points
    assert np.all(np.linalg.eigvalsh(rec.P) > 0)


def test_features_on_textureless_road_keep_the_prior() -> None:
    camera, mount, _ = preset_camera("omni-near")
    img_a, _, _ = road_pair("omni-near")
    flat = np.where(img_a > 0, 120, 0).astype(np.uint8)
    est = make_estimator("features", camera, mount)
    est.step(flat, 0.3, 20.0)
    rec = est.step(flat, 0.3 + DT, 20.0)
    assert rec.degraded and "no-features" in rec.flags
    assert np.array_equal(rec.x, rec.x_prior)


@pytest.mark.parametrize("name", ["can-only", "features"])
def test_baselines_tell_no_point_pull(name: str) -> None:
    """`EgoMotionEstimator.point_pull`: a baseline's fit has no points to split (None, so
    the runner's `point_pull` section is NaN with its reason); a bad state is still named."""
    camera, mount, _ = preset_camera("omni-near")
    img_a, img_b, x_true = road_pair("omni-near")
    est = make_estimator(name, camera, mount)
    est.step(img_a, 0.3, SPEED * CAN_SCALE)
    est.step(img_b, 0.3 + DT, SPEED * CAN_SCALE)
    assert est.point_pull(x_true) is None
    with pytest.raises(ValueError, match="point_pull x"):
        est.point_pull(np.full(9, np.nan))
