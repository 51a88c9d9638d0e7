"""The manoeuvre retry (`estimator.egomotion.manoeuvre`): an abrupt turn or side slip out of the
random walk's reach is fitted again with the manoeuvre covariance added to the prior; which
retry fit replaces the first, and how its passes search."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from estimator.egomotion import coarse_to_fine
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import DirectConfig, default_config
from estimator.egomotion.ego_estimator import INLIER, OUTLIER, UNUSED
from estimator.egomotion.homography import W_SLICE, make_state
from estimator.egomotion.manoeuvre import manoeuvre_cov
from tests.estimator.egomotion.direct_pairs import run_pair, turn_pair
from tests.estimator.egomotion.road_pairs import (
    CAN_SCALE,
    DT,
    SPEED,
    preset_camera,
    road_pair,
    state_errors,
)


@pytest.mark.parametrize("wide_levels", [(2, 1, 0), (1,), (0,)])
def test_manoeuvre_retry_follows_an_abrupt_turn(wide_levels) -> None:
    """A yaw rate of 70 deg/s from a prior of 0 (the simulator's abrupt steering steps):
    out of the random walk's reach, found by the retry with the manoeuvre prior, whichever
    level its wide grid search runs at (a far camera's coarse levels may lack points)."""
    preset = "omni-near"
    camera, mount, angle = preset_camera(preset)
    speed, yaw_rate, t0 = 10.0, 1.2, 0.3
    img_a, img_b, ms = turn_pair(camera, mount, angle, speed, yaw_rate, t0)
    x_true = make_state(ms.V_mps, ms.W_rps, ms.A_rad)
    # W's prior std as in steady state (~1.5 deg/s): the turn is 45 sigma away
    tight = default_config(
        "omni", filter={"W0_sigma_rps": 0.025}, manoeuvre_search_levels=wide_levels
    )
    _, rec = run_pair(preset, img_a, img_b, t0=t0, can=speed, config=tight)
    assert "manoeuvre" in rec.flags and not rec.degraded, rec.flags
    assert rec.yaw_rate_rps == pytest.approx(yaw_rate, abs=np.radians(1.0))
    assert state_errors(rec, x_true)[0] < 2.0


def _surprising_pair_with_retry(monkeypatch, cfg: DirectConfig, retry_result):
    """Record of the omni-near pair whose first fit is forced surprising (noise scale 4.0
    against a usual 0.3) and whose retries' results retry_result(res) rewrites; asserts
    that the retry ran."""
    camera, mount, _ = preset_camera("omni-near")
    img_a, img_b, _ = road_pair("omni-near")
    real = DirectEstimator._coarse_to_fine
    seen = []

    def fake(self, A, B, dt, excluded, wide_level=None, from_wide=False):
        res = real(self, A, B, dt, excluded, wide_level, from_wide)
        seen.append(wide_level)
        if wide_level is None:
            res["noise_scale"] = 4.0
        else:
            retry_result(res)
        return res

    est = DirectEstimator(camera, mount, cfg)
    est._s2_hist = [0.3, 0.3, 0.3]  # the usual level: 4.0 is surprising
    monkeypatch.setattr(DirectEstimator, "_coarse_to_fine", fake)
    est.step(img_a, 0.3, SPEED * CAN_SCALE)
    rec = est.step(img_b, 0.3 + DT, SPEED * CAN_SCALE)
    assert seen[0] is None and len(seen) > 1  # the retry ran
    return rec


@pytest.mark.parametrize("gain, replaced", [(1.5, True), (3.0, False)])
def test_retry_replaces_a_surprising_fit_only_when_much_better(monkeypatch, gain, replaced):
    """A fit that did not fail but whose noise scale is unusual is retried; the retry's
    fit replaces it only when its noise scale is ``retry_gain`` times lower (here 2x)."""

    def twice_lower(res):
        res["noise_scale"] = 2.0

    cfg = default_config("omni", retry_gain=gain, yaw_jump_sigmas=0.0)
    rec = _surprising_pair_with_retry(monkeypatch, cfg, twice_lower)
    assert ("manoeuvre" in rec.flags) == replaced
    assert rec.noise_scale == (2.0 if replaced else 4.0)


def _keep_in_view(share: float, inlier_share: float):
    """A retry result rewrite: the fit keeps ``share`` of its points in view (the rest
    turned out of B: unused), ``inlier_share`` of those inliers, at noise scale 0.5."""

    def rewrite(res):
        n = int(res["n_points"] * share)
        n_in = int(n * inlier_share)
        labels = res["point_labels"].copy()
        labels[:] = UNUSED
        labels[:n_in] = INLIER
        labels[n_in:n] = OUTLIER
        res.update(noise_scale=0.5, n_inliers=n_in, point_labels=labels)

    return rewrite


@pytest.mark.parametrize("min_fraction, replaced", [(0.25, False), (0.0, True)])
def test_retry_must_keep_the_road_in_view(monkeypatch, min_fraction, replaced):
    """A retry's fit whose inliers are fewer than ``min_inlier_fraction`` of the first fit's
    points (the road in view under the prior) is no fit of the road (a wild motion that
    turns the road out of the image fits the few points left): it is not taken however low
    its noise scale and however well those points fit; without the rule (fraction 0) it is."""
    cfg = default_config("omni", min_inlier_fraction=min_fraction, yaw_jump_sigmas=0.0)
    rec = _surprising_pair_with_retry(monkeypatch, cfg, _keep_in_view(0.1, 1.0))
    assert ("manoeuvre" in rec.flags) == replaced
    assert rec.noise_scale == (0.5 if replaced else 4.0)


@pytest.mark.parametrize(
    "inlier_share, seen_fraction, replaced",
    [(0.6, 0.5, True), (0.6, 0.0, False), (0.4, 0.5, False)],
)
def test_retry_counts_inliers_against_what_it_sees(
    monkeypatch, inlier_share, seen_fraction, replaced
):
    """A sharp swerve turns much of the road out of view (validation-rect's merge, seed 1,
    frame 148: 481 of the prior's 1759 points stay in view, 391 of them inliers). A retry
    that keeps a third of the points in view and fits most of them (``seen_inlier_fraction``)
    is counted against what it sees and taken; one that fits fewer than that fraction of
    them, or with the rule off (0), fails for few inliers."""
    cfg = default_config("omni", seen_inlier_fraction=seen_fraction, yaw_jump_sigmas=0.0)
    rec = _surprising_pair_with_retry(monkeypatch, cfg, _keep_in_view(0.33, inlier_share))
    assert ("manoeuvre" in rec.flags) == replaced
    assert rec.noise_scale == (0.5 if replaced else 4.0)
    if replaced:
        assert not rec.degraded and np.sum(rec.point_labels == UNUSED) > 0.5 * len(rec.points_px)


def test_retry_refines_locally_below_its_wide_level(monkeypatch) -> None:
    """The retry's levels finer than its wide level start with a local grid search (a few
    steps of ``search_step_px`` about x̂, not the wide prior's width: the coarse level's fit
    is refined, not searched for again); the first fit's levels search as usual."""
    calls: list[tuple[int, bool, int | None]] = []
    real_search, real_ctf = coarse_to_fine.grid_search, DirectEstimator._coarse_to_fine
    wide: list[int | None] = [None]

    def ctf(self, A, B, dt, excluded, wide_level=None, from_wide=False):
        wide[0] = wide_level
        return real_ctf(self, A, B, dt, excluded, wide_level, from_wide)

    def search(cfg, camera, K0, yaw_dir, ekf, pts, B, dt, max_steps, n_points, local=False):
        calls.append((pts.lvl, local, wide[0]))
        return real_search(cfg, camera, K0, yaw_dir, ekf, pts, B, dt, max_steps, n_points, local)

    monkeypatch.setattr(DirectEstimator, "_coarse_to_fine", ctf)
    monkeypatch.setattr(coarse_to_fine, "grid_search", search)
    cfg = default_config("omni", yaw_jump_sigmas=0.0)
    rec = _surprising_pair_with_retry(monkeypatch, cfg, lambda res: None)
    local = [(lvl, w) for lvl, is_local, w in calls if is_local]
    assert local and all(w is not None and lvl < w for lvl, w in local)
    assert {w for _, w in local} == {lvl for lvl in cfg.manoeuvre_search_levels if lvl > 0}
    assert all(not is_local for _, is_local, w in calls if w is None)
    assert "manoeuvre" in rec.flags and not rec.degraded


def test_retry_passes_from_the_wide_level_only_when_they_differ(monkeypatch) -> None:
    """A retry pass that starts at its wide level (``manoeuvre_fine_passes``) follows the full
    pass of that level only when the full pass iterated a level coarser than it; otherwise
    the two would be the same pass run twice. Here the retry's coarsest level does not
    iterate (``manoeuvre_iterations`` 0): wide level 2 makes one pass, levels 1 and 0 two."""
    passes: list[tuple[int | None, bool, tuple[int, ...]]] = []
    real_ctf = DirectEstimator._coarse_to_fine

    def ctf(self, A, B, dt, excluded, wide_level=None, from_wide=False):
        res = real_ctf(self, A, B, dt, excluded, wide_level, from_wide)
        passes.append((wide_level, from_wide, res["iterations"]))
        return res

    monkeypatch.setattr(DirectEstimator, "_coarse_to_fine", ctf)
    cfg = default_config("omni", yaw_jump_sigmas=0.0, manoeuvre_iterations=(0, 4, 10, 10))
    _surprising_pair_with_retry(monkeypatch, cfg, lambda res: None)
    retry = [(w, fw, its) for w, fw, its in passes if w is not None]
    assert [(w, fw) for w, fw, _ in retry] == [
        (2, False),
        (1, False),
        (1, True),
        (0, False),
        (0, True),
    ]
    assert retry[0][2][0] == 0 and retry[1][2][1] > 0  # level 3 idle; level 2 iterated
    assert retry[2][2][:2] == (0, 0)  # the pass from level 1 skipped levels 3 and 2


@pytest.mark.parametrize("rear_axle_x_m", [None, -2.5])
@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_manoeuvre_prior_widens_the_yaw_rate_not_roll_and_pitch(preset, rear_axle_x_m) -> None:
    """The manoeuvre retry's added covariance: std ``manoeuvre_W_sigma_rps`` on the car's
    yaw rate, ``manoeuvre_W_plane_sigma_rps`` on its roll and pitch rates (car axes), with
    and without a rear axle (the kinematic model then moves V with the yaw rate too)."""
    camera, mount, _ = preset_camera(preset)
    mount = replace(mount, rear_axle_x_m=rear_axle_x_m)
    cfg = default_config(camera.kind)
    Q = manoeuvre_cov(cfg, mount.R_car_cam, mount.lever_arm_m)
    Rc = mount.R_car_cam
    W_car = Rc @ Q[W_SLICE, W_SLICE] @ Rc.T
    want = [cfg.manoeuvre_W_plane_sigma_rps] * 2 + [cfg.manoeuvre_W_sigma_rps]
    np.testing.assert_allclose(W_car, np.diag(np.square(want)), atol=1e-12)
    assert cfg.manoeuvre_W_plane_sigma_rps < cfg.manoeuvre_W_sigma_rps


def test_manoeuvre_with_side_slip_and_the_kinematic_constraint() -> None:
    """highway-env's abrupt steering: the rear axle turns on a circle at 69 deg/s, the
    camera 2.5 m ahead of it slides sideways at 3 m/s. With the mount's rear axle known,
    the retry's prior ties the sideways speed to the yaw rate and finds both."""
    preset = "omni-near"
    camera, mount0, angle = preset_camera(preset)
    mount = replace(mount0, rear_axle_x_m=-2.5)
    speed, yaw_rate, t0, lever = 9.0, 1.2, 0.3, 2.5
    img_a, img_b, ms = turn_pair(camera, mount, angle, speed, yaw_rate, t0, lever_m=lever)
    v_true = mount.R_car_cam @ ms.V_mps
    # the camera slides: lever x yaw rate, plus the chord's turn over the frame (V is the
    # mean velocity in frame A's axes; the constraint leaves that to its sigma)
    assert v_true[1] == pytest.approx(lever * yaw_rate + speed * yaw_rate * DT / 2, rel=0.02)
    tight = default_config("omni", filter={"W0_sigma_rps": 0.025})
    est = DirectEstimator(camera, mount, tight)
    est.step(img_a, t0, speed)
    rec = est.step(img_b, t0 + DT, speed)
    assert "manoeuvre" in rec.flags and not rec.degraded, rec.flags
    assert rec.yaw_rate_rps == pytest.approx(yaw_rate, abs=np.radians(1.0))
    v_est = mount.R_car_cam @ rec.V
    print(f"yaw {np.degrees(rec.yaw_rate_rps):.2f} deg/s, sideways {v_est[1]:.2f} m/s")
    assert v_est[1] == pytest.approx(v_true[1], abs=0.3)
