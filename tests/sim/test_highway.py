"""sim/highway.py against the real highway-env (no mocks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.highway import (
    HighwayBridge,
    RoadGeometry,
    WorldFrame,
    road_geometry,
    simulate,
    world_from_hw_xy,
    world_yaw_from_hw_heading,
)

FPS = 15.0
N3S = 45  # 3 s at 15 fps
ENVS = {
    "highway-v0": {"vehicles_count": 20},  # fewer than the default 50: faster test
    "merge-v0": {},
    "roundabout-v0": {},
    "racetrack-v0": {},
    "intersection-v0": {},
}


@pytest.fixture(scope="module")
def drives() -> dict[str, tuple[HighwayBridge, list[WorldFrame]]]:
    """Each env driven 3 s at 15 fps, seed 0 (the bridge is kept to drive on)."""
    out = {}
    for env_id, cfg in ENVS.items():
        bridge = HighwayBridge(env_id, cfg, seed=0, fps=FPS)
        out[env_id] = (bridge, list(bridge.frames(N3S)))
    return out


# --------------------------------------------------------------------------- rates, frames


@pytest.mark.parametrize("env_id", list(ENVS))
def test_three_seconds_give_45_frames_at_k_over_15(drives, env_id):
    bridge, frames = drives[env_id]
    assert len(frames) == N3S
    assert [f.index for f in frames] == list(range(N3S))
    np.testing.assert_allclose([f.t_s for f in frames], np.arange(N3S) / FPS, atol=1e-12)
    # highway-env really advanced 1/fps per frame (policy rate = camera rate)
    base = bridge.env.unwrapped
    assert base.config["policy_frequency"] == FPS
    assert base.config["simulation_frequency"] == bridge.sim_hz == 15
    assert math.isclose(base.time, bridge._env_index / FPS)  # env runs 1 frame ahead


def test_simulate_counts_frames_and_returns_road():
    frames, road = simulate("highway-v0", ENVS["highway-v0"], 1, FPS, 3.0, return_road=True)
    assert len(frames) == N3S and isinstance(road, RoadGeometry)
    assert frames[-1].t_s == pytest.approx(44 / 15)


@pytest.mark.parametrize(("fps", "sim_hz", "substeps"), [(15.0, 15, 1), (10.0, 20, 2), (30, 30, 1)])
def test_sim_rate_is_an_integer_multiple_of_fps(fps, sim_hz, substeps):
    b = HighwayBridge("highway-v0", {"vehicles_count": 5}, 0, fps)
    assert (b.sim_hz, b.substeps) == (sim_hz, substeps)
    f = list(b.frames(4))
    assert b.env.unwrapped.steps == substeps * 4  # sim steps actually taken (1 ahead)
    np.testing.assert_allclose([x.t_s for x in f], np.arange(4) / fps)


# --------------------------------------------------------------------------- ego motion


@pytest.mark.parametrize("env_id", list(ENVS))
def test_ego_drives_forward_at_plausible_speed(drives, env_id):
    _, frames = drives[env_id]
    xy = np.array([(f.ego.x_m, f.ego.y_m) for f in frames])
    v = np.array([f.ego.speed_mps for f in frames])
    yaw = np.array([f.ego.yaw_rad for f in frames])
    step = np.diff(xy, axis=0)
    travelled = np.linalg.norm(step, axis=1).sum()
    integral = np.sum(0.5 * (v[1:] + v[:-1])) / FPS  # trapezoid of the speeds
    assert travelled == pytest.approx(integral, rel=0.05)
    assert 3.0 < travelled / 3.0 < 40.0  # [m/s] a car, not a plane
    # forward: each step goes along the (world) heading
    fwd = np.stack([np.cos(yaw[:-1]), np.sin(yaw[:-1])], axis=1)
    assert np.all(np.einsum("ij,ij->i", step, fwd) > 0)
    assert not any(f.ego.crashed for f in frames)


@pytest.mark.parametrize("env_id", ["roundabout-v0", "racetrack-v0"])
def test_ego_follows_curves(drives, env_id):
    bridge, frames = drives[env_id]
    yaw = np.unwrap([f.ego.yaw_rad for f in frames])
    assert np.ptp(yaw) > 0.2  # [rad] it turns with the road within 3 s
    # and the reported yaw rate is the central difference of the yaw
    fd = np.gradient(yaw, 1.0 / FPS)
    rate = np.array([f.ego.yaw_rate_rps for f in frames])
    np.testing.assert_allclose(rate[1:-1], fd[1:-1], atol=1e-9)
    # it stays on the road
    road = bridge.road
    assert road.contains_xy(np.array([(f.ego.x_m, f.ego.y_m) for f in frames])).all()


@pytest.mark.parametrize("env_id", list(ENVS))
def test_ego_drives_ten_seconds_without_crashing(env_id):
    b = HighwayBridge(env_id, ENVS[env_id], seed=1, fps=FPS)
    frames = list(b.frames(150))
    assert len(frames) == 150
    assert b.ego_crash_t_s is None
    xy = np.array([(f.ego.x_m, f.ego.y_m) for f in frames])
    assert np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() > 30.0  # [m] it drove


def test_idm_changes_lane_and_keep_lane_does_not():
    """Seed 1: the IDM ego overtakes by MOBIL within 6 s; "keep-lane" stays in lane."""
    cfg = {"vehicles_count": 30}
    ys = {}
    for policy in ("idm", "keep-lane"):
        b = HighwayBridge("highway-v0", cfg, 1, FPS, ego_policy=policy)
        ys[policy] = np.array([f.ego.y_m for f in b.frames(90)])
    assert np.ptp(ys["idm"]) > 3.5  # [m] one lane is 4 m
    assert np.ptp(ys["keep-lane"]) < 0.05  # [m] highway lanes are straight along x


def test_ego_target_speed_is_followed_and_bad_ones_refused():
    """An empty road: the ego's IDM reaches the asked speed instead of the env's own."""
    cfg = {"vehicles_count": 0}
    own = HighwayBridge("highway-v0", cfg, 1, FPS, ego_policy="keep-lane")
    slow = HighwayBridge("highway-v0", cfg, 1, FPS, ego_policy="keep-lane", ego_speed_mps=15.0)
    v_own = [f.ego.speed_mps for f in own.frames(150)][-1]
    v_slow = [f.ego.speed_mps for f in slow.frames(150)][-1]
    assert abs(v_slow - 15.0) < 0.5  # [m/s] after 10 s
    assert v_own > 19.0
    with pytest.raises(ValueError, match="ego_speed_mps"):
        HighwayBridge("highway-v0", cfg, 1, FPS, ego_speed_mps=-3.0)


def test_ego_crash_is_recorded_and_can_stop_the_drive():
    b = HighwayBridge("merge-v0", {}, 0, FPS, stop_on_ego_crash=True)
    first = list(b.frames(1))
    b._ego.crashed = True  # as highway-env's collision check would set it
    rest = list(b.frames(10))
    # the env runs one frame ahead: frame 1 was taken before the crash, frame 2 shows it
    assert [f.ego.crashed for f in first + rest] == [False, False, True]
    assert b.ego_crash_t_s == pytest.approx(2 / FPS)


# --------------------------------------------------------------------------- frames


def test_world_frame_is_right_handed():
    """highway-env lane 1 is to the right of lane 0 (larger y_hw): smaller world y."""
    b = HighwayBridge("highway-v0", {"vehicles_count": 5}, 0, FPS)
    net = b.env.unwrapped.road.network
    hw0 = net.get_lane(("0", "1", 0)).position(50.0, 0.0)
    hw1 = net.get_lane(("0", "1", 1)).position(50.0, 0.0)
    assert hw1[1] > hw0[1]  # highway-env: y grows to the right of travel
    w0, w1 = world_from_hw_xy(hw0), world_from_hw_xy(hw1)
    assert w1[1] < w0[1]
    # travel +x, lane 1 on the right: z of (travel x to-lane-1) is negative
    travel, to_1 = np.array([1.0, 0.0]), w1 - w0
    assert travel[0] * to_1[1] - travel[1] * to_1[0] < 0
    lanes = {ln.index: ln for ln in b.road.lanes}
    assert lanes[("0", "1", 1)].center_xy[0, 1] == pytest.approx(-4.0)
    # a vehicle state is the converted highway-env state
    f = next(b.frames(1))
    ego = b.env.unwrapped.road.vehicles[0]  # env is 1 frame ahead: compare headings' sign
    assert ego is b._ego
    assert f.ego.y_m == pytest.approx(-b._hist[0][0].y)
    assert world_yaw_from_hw_heading(0.3) == pytest.approx(-0.3)


@pytest.mark.parametrize("env_id", list(ENVS))
def test_lane_left_edges_are_left_of_travel(drives, env_id):
    bridge, _ = drives[env_id]
    for ln in bridge.road.lanes:
        d = np.stack([np.cos(ln.yaw_rad), np.sin(ln.yaw_rad)], axis=1)
        to_left = ln.left_xy - ln.center_xy
        cross = d[:, 0] * to_left[:, 1] - d[:, 1] * to_left[:, 0]
        assert np.all(cross > 0), ln.index
        np.testing.assert_allclose(
            np.linalg.norm(ln.left_xy - ln.right_xy, axis=1), ln.width_m, rtol=1e-6
        )


@pytest.mark.parametrize("env_id", list(ENVS))
def test_ids_are_stable_and_by_first_appearance(drives, env_id):
    _, frames = drives[env_id]
    seen: list[int] = []
    last: dict[int, tuple[float, float, float]] = {}
    for f in frames:
        assert f.ego.id == 0 and f.ego.is_ego
        ids = [o.id for o in f.others]
        assert len(set(ids)) == len(ids) and 0 not in ids
        assert not any(o.is_ego for o in f.others)
        new = sorted(set(ids) - set(seen))
        assert new == list(range(len(seen) + 1, len(seen) + 1 + len(new)))
        seen += new
        for v in f.vehicles:
            if v.id in last:  # same id -> same physical vehicle (continuous motion)
                x, y, s = last[v.id]
                assert math.hypot(v.x_m - x, v.y_m - y) <= max(s, v.speed_mps) / FPS * 1.2 + 0.3
            last[v.id] = (v.x_m, v.y_m, v.speed_mps)
            assert 1.4 <= v.height_m <= 1.7 and v.length_m > 0 and v.width_m > 0


def test_intersection_spawns_get_new_ids(drives):
    bridge, frames = drives["intersection-v0"]
    more = list(bridge.frames(60))  # continue the drive: vehicles spawn and leave
    ids_first = {o.id for o in frames[0].others}
    ids_all = {o.id for f in frames + more for o in f.others}
    assert ids_all - ids_first  # somebody appeared later with a new id
    assert more[0].index == N3S


def test_same_seed_same_frames_other_seed_differs():
    a = simulate("intersection-v0", {}, 5, FPS, 2.0)
    b = simulate("intersection-v0", {}, 5, FPS, 2.0)
    c = simulate("intersection-v0", {}, 6, FPS, 2.0)
    assert a == b
    assert a != c


def test_envs_do_not_leak_behaviour_into_each_other():
    """intersection-v0 writes IDM constants on the class: the bridge isolates them."""
    cfg = {"vehicles_count": 15}
    before = simulate("highway-v0", cfg, 2, FPS, 1.5)
    HighwayBridge("intersection-v0", {}, 0, FPS)
    after = simulate("highway-v0", cfg, 2, FPS, 1.5)
    assert before == after


def test_intersection_spawn_probability_is_per_second():
    b = HighwayBridge("intersection-v0", {"spawn_probability": 0.6}, 0, FPS)
    p = b.env.unwrapped.config["spawn_probability"]
    assert 1 - (1 - p) ** FPS == pytest.approx(0.6)


# --------------------------------------------------------------------------- road


def test_road_geometry_clips_the_10_km_highway():
    b = HighwayBridge("highway-v0", {"vehicles_count": 5}, 0, FPS)
    full = b.road
    assert full.bounds_xy()[1] == pytest.approx(10000.0)
    clipped = road_geometry(b.env, clip_xy=(100.0, 300.0, -30.0, 10.0))
    assert len(clipped.lanes) == 4
    for ln in clipped.lanes:
        assert ln.center_xy[:, 0].min() >= 100.0 - 30.0
        assert ln.center_xy[:, 0].max() <= 300.0 + 30.0
        assert np.diff(ln.s_m).max() <= 5.0 + 1e-9
    assert sum(len(ln.s_m) for ln in clipped.lanes) < 400


def test_curved_lanes_are_sampled_every_metre(drives):
    bridge, _ = drives["roundabout-v0"]
    kinds = {ln.kind for ln in bridge.road.lanes}
    assert {"circular", "sine", "straight"} <= kinds
    for ln in bridge.road.lanes:
        if ln.kind != "straight":
            assert np.diff(ln.s_m).max() <= 1.0 + 1e-9


def test_contains_xy_matches_lane_geometry(drives):
    bridge, _ = drives["racetrack-v0"]
    ln = bridge.road.lanes[3]
    nl = np.stack([-np.sin(ln.yaw_rad), np.cos(ln.yaw_rad)], axis=1)
    inside = ln.center_xy + 0.45 * ln.width_m[:, None] * nl
    assert bridge.road.contains_xy(inside).all()
    far = ln.center_xy + 200.0
    assert not bridge.road.contains_xy(far).any()


# --------------------------------------------------------------------------- bad input


def test_bad_inputs_name_the_problem():
    with pytest.raises(ValueError, match="ego_policy.*'fly'"):
        HighwayBridge("highway-v0", {}, 0, FPS, ego_policy="fly")
    with pytest.raises(ValueError, match="fps"):
        HighwayBridge("highway-v0", {}, 0, 0.0)
    with pytest.raises(ValueError, match="env_config.lanes_cont"):
        HighwayBridge("highway-v0", {"lanes_cont": 3}, 0, FPS)
    with pytest.raises(ValueError, match="policy_frequency"):
        HighwayBridge("highway-v0", {"policy_frequency": 1}, 0, FPS)
    with pytest.raises(ValueError, match="simulation_frequency"):
        HighwayBridge("highway-v0", {"simulation_frequency": 20}, 0, FPS)
    with pytest.raises(ValueError, match="unknown environment 'nowhere-v0'"):
        HighwayBridge("nowhere-v0", {}, 0, FPS)
    with pytest.raises(ValueError, match="clip_xy"):
        road_geometry(HighwayBridge("merge-v0", {}, 0, FPS).env, clip_xy=(1, 0, 0, 1))
