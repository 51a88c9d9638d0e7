"""Road-plane multi-vehicle tracker: synthetic scenes, ego-motion compensation, bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.surround.tracking import (
    Tracker,
    TrackerConfig,
    ego_displacement,
    ego_frame_change,
    frame_change_input_jacobian,
    gated_assignment,
    swept_measurement,
)

DT = 0.1  # [s] frame interval of the synthetic scenes


# ------------------------------------------------------------------ synthetic world
def ego_pose(t: float, speed: float, yaw_rate: float) -> tuple[np.ndarray, float]:
    """World pose (position (2,), yaw) of an ego frame starting at the origin, constant turn."""
    if abs(yaw_rate) < 1e-12:
        return np.array([speed * t, 0.0]), 0.0
    yaw = yaw_rate * t
    return np.array([speed * math.sin(yaw), speed * (1 - math.cos(yaw))]) / yaw_rate, yaw


def world_to_ego(p_world: np.ndarray, t: float, speed: float, yaw_rate: float) -> np.ndarray:
    pos, yaw = ego_pose(t, speed, yaw_rate)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, s], [-s, c]]) @ (np.asarray(p_world) - pos)


def run_scene(tracker, vehicles, n_frames, speed=0.0, yaw_rate=0.0, sigma=0.05, seed=0, drop=None):
    """Feed detections of ``vehicles`` (gt id -> t -> world xy) in shuffled order.

    drop(k, gt_id) -> True hides that vehicle in frame k. Returns, per frame, the
    gt id of each detection index (to read the tracker's assignments back).
    """
    rng = np.random.default_rng(seed)
    labels = []
    for k in range(n_frames):
        t = k * DT
        ids = [g for g in vehicles if drop is None or not drop(k, g)]
        ids = [ids[i] for i in rng.permutation(len(ids))]
        z = [world_to_ego(vehicles[g](t), t, speed, yaw_rate) for g in ids]
        z = np.array(z).reshape(-1, 2) + sigma * rng.standard_normal((len(ids), 2))
        tracker.step(t, z, speed, yaw_rate)
        labels.append(ids)
    return labels


def track_to_gt(tracker, labels) -> dict[int, set]:
    """Track id -> set of gt ids of the detections assigned to it."""
    out: dict[int, set] = {}
    for rec, lab in zip(tracker.records, labels, strict=True):
        for tid, j, _ in rec.assignments:
            out.setdefault(tid, set()).add(lab[j])
        born_from = [j for j in rec.unassigned if j not in rec.refused_births]
        for tid, j in zip(rec.births, born_from, strict=True):
            out.setdefault(tid, set()).add(lab[j])
    return out


def linear(p0, v):
    p0, v = np.asarray(p0, float), np.asarray(v, float)
    return lambda t: p0 + v * t


# ------------------------------------------------------------------ ego motion
def integrate_ego(dt, s, w, u, n=20000):
    """Displacement and yaw change by fine midpoint integration (independent check)."""
    h = dt / n
    pos, yaw = np.zeros(2), 0.0
    for _ in range(n):
        ym = yaw + 0.5 * w * h
        c, sn = math.cos(ym), math.sin(ym)
        pos += h * np.array([c * s - sn * u, sn * s + c * u])
        yaw += w * h
    return pos, yaw


@pytest.mark.parametrize("w", [0.0, 1e-6, 0.3, -1.2])
def test_ego_displacement_matches_integration(w):
    d, psi = ego_displacement(0.5, 12.0, w, 0.7)
    d_ref, psi_ref = integrate_ego(0.5, 12.0, w, 0.7)
    assert psi == pytest.approx(psi_ref, abs=1e-12)
    np.testing.assert_allclose(d, d_ref, atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(
    st.floats(0.01, 0.5),
    st.floats(-30, 30),
    st.one_of(st.floats(-1.5, 1.5), st.floats(-1e-5, 1e-5)),
    st.floats(-2, 2),
    st.lists(st.floats(-50, 50), min_size=4, max_size=4),
)
def test_frame_change_jacobian_vs_central_differences(dt, s, w, u, x):
    """(4, 2) d x'/d(s, ω) against central differences in float64."""
    x = np.array(x)

    def new_state(s_, w_):
        G, g, _ = ego_frame_change(dt, s_, w_, u)
        return G @ x + g

    J = frame_change_input_jacobian(x, dt, s, w, u)
    hs, hw = 1e-5, 1e-6
    Jn = np.stack(
        [
            (new_state(s + hs, w) - new_state(s - hs, w)) / (2 * hs),
            (new_state(s, w + hw) - new_state(s, w - hw)) / (2 * hw),
        ],
        axis=1,
    )
    np.testing.assert_allclose(J, Jn, atol=1e-5 * (1 + np.abs(x).max()))


def test_frame_change_moves_ground_points_like_world_to_ego():
    p_world = np.array([25.0, 8.0])
    s, w = 14.0, 0.25
    x_prev = np.concatenate([world_to_ego(p_world, 1.0, s, w), [0.0, 0.0]])
    G, g, _ = ego_frame_change(DT, s, w)
    np.testing.assert_allclose((G @ x_prev + g)[:2], world_to_ego(p_world, 1.0 + DT, s, w))


# ------------------------------------------------------------------ assignment
def test_gated_assignment_never_uses_forbidden_pair():
    cost = np.array([[0.1, 5.0], [9.0, 9.0]])
    allowed = np.array([[True, False], [False, False]])
    assert gated_assignment(cost, allowed) == [(0, 0)]
    assert gated_assignment(np.ones((2, 3)), np.zeros((2, 3), bool)) == []
    assert gated_assignment(np.zeros((0, 3)), np.zeros((0, 3), bool)) == []


def test_gated_assignment_prefers_more_pairs():
    # row 1 can only take column 0: the optimum gives row 0 column 1 (costlier)
    cost = np.array([[0.0, 3.0], [1.0, 0.0]])
    allowed = np.array([[True, True], [True, False]])
    assert sorted(gated_assignment(cost, allowed)) == [(0, 1), (1, 0)]


# ------------------------------------------------------------------ scenes
def test_smoke_and_shapes():
    tr = Tracker()
    assert tr.step(0.0, np.zeros((0, 2)), 10.0, 0.0) == []
    assert tr.step(0.1, [], 10.0, 0.0) == []
    out = tr.step(0.2, [[5.0, 2.0]], 10.0, 0.0, extras=[{"blob_px": 40}])
    assert out == []  # tentative
    (t,) = tr.tracks
    assert t.x.shape == (4,) and t.P.shape == (4, 4) and t.extra == {"blob_px": 40}
    assert len(tr.records) == 3 and tr.records[-1].births == [t.id]
    assert t.history == [(0.2, 5.0, 2.0)]


def test_two_vehicles_crossing_keep_their_ids():
    # ego straight at 10 m/s; A drifts left, B right, paths cross 1 m apart at t = 1.5 s
    vehicles = {"A": linear([20, -6], [10, 4]), "B": linear([21, 6], [10, -4])}
    tr = Tracker()
    labels = run_scene(tr, vehicles, 40, speed=10.0)
    mapping = track_to_gt(tr, labels)
    assert len(mapping) == 2, mapping  # no extra tracks born
    assert sorted(next(iter(g)) for g in mapping.values()) == ["A", "B"]
    assert all(len(g) == 1 for g in mapping.values()), mapping  # never swapped
    assert len(tr.confirmed_tracks) == 2


def test_occlusion_of_three_frames_keeps_id_five_frames_kills_it():
    veh = {"A": linear([15, 4], [12, 0])}
    tr = Tracker()  # delete_after_misses = 5
    run_scene(tr, veh, 30, speed=10.0, drop=lambda k, g: 10 <= k < 13)
    assert [r.births for r in tr.records if r.births] == [[1]]
    assert [t.id for t in tr.confirmed_tracks] == [1]
    occluded = list(tr.records)[10:13]
    assert [r.missed for r in occluded] == [[1], [1], [1]]
    assert tr.records[13].assignments[0][0] == 1  # re-acquired by the same id

    tr = Tracker()
    run_scene(tr, veh, 30, speed=10.0, drop=lambda k, g: 10 <= k < 15)
    assert tr.records[14].deaths and tr.records[14].deaths[0][0] == 1
    assert tr.records[15].births == [2]  # a new id, 1 is never reused
    assert [t.id for t in tr.confirmed_tracks] == [2]


def test_false_alarm_never_confirmed():
    veh = {"A": linear([12, -3], [8, 0])}
    rng = np.random.default_rng(3)
    tr = Tracker()
    confirmed_ids = set()
    false_ids = set()
    for k in range(30):
        t = k * DT
        z = [world_to_ego(veh["A"](t), t, 8.0, 0.0) + 0.05 * rng.standard_normal(2)]
        if k in (5, 12, 20):  # isolated false alarms, far from the vehicle
            z.append(rng.uniform([-20, 5], [20, 20]))
        confirmed_ids |= {tr_.id for tr_ in tr.step(t, np.array(z), 8.0, 0.0)}
        false_ids |= set(tr.records[-1].births) - {1}
    assert confirmed_ids == {1}
    assert len(false_ids) == 3
    deaths = {tid for r in tr.records for tid, _ in r.deaths}
    assert false_ids <= deaths  # each deleted (tentative, cannot reach 3 of 4)


def test_new_vehicle_gets_new_id():
    veh = {"A": linear([10, 3], [10, 0]), "B": linear([-5, -3.5], [11, 0])}
    tr = Tracker()
    run_scene(tr, veh, 25, speed=10.0, drop=lambda k, g: g == "B" and k < 10)
    births = [(k, r.births) for k, r in enumerate(tr.records) if r.births]
    assert births == [(0, [1]), (10, [2])]
    assert 2 in tr.records[12].confirmations  # 3 hits in frames 10, 11, 12
    assert [t.id for t in tr.confirmed_tracks] == [1, 2]


def test_gate_is_respected():
    # measurement noise fixed here (the default's range term changes): 0.3 + 0.02 * 10 m
    tr = Tracker(TrackerConfig(gate_m=4.0, meas_sigma_per_m=0.02))
    for k in range(10):  # a confirmed, well-settled parked car seen from a parked ego
        tr.step(k * DT, [[10.0, 0.0]], 0.0, 0.0)
    (track,) = tr.confirmed_tracks
    # 6 m away: beyond the metre gate; the lone detection is not forced onto the track
    tr.step(10 * DT, [[10.0, 6.0]], 0.0, 0.0)
    rec = tr.records[-1]
    assert rec.assignments == [] and rec.missed == [track.id] and rec.births == [2]
    assert np.isinf(rec.d2).all()
    # 2.5 m away: inside the metre gate but far beyond chi² for a settled track
    tr.step(11 * DT, [[10.0, -2.5]], 0.0, 0.0)
    rec = tr.records[-1]
    assert all(a[0] != track.id for a in rec.assignments)
    i = rec.track_ids.index(track.id)
    assert np.isinf(rec.d2[i, 0])


def test_parked_vehicle_stays_put_with_moving_turning_ego():
    p_world = np.array([30.0, 10.0])
    s, w = 15.0, 0.15
    tr = Tracker()
    run_scene(tr, {"P": lambda t: p_world}, 40, speed=s, yaw_rate=w, sigma=0.05, seed=1)
    (track,) = tr.confirmed_tracks
    np.testing.assert_allclose(track.velocity_xy, 0.0, atol=0.3)  # ground velocity
    odom = np.array([h[1:] for h in track.history_odom[-20:]])
    np.testing.assert_allclose(odom, np.broadcast_to(p_world, odom.shape), atol=0.15)
    pos, yaw = ego_pose(39 * DT, s, w)
    np.testing.assert_allclose(tr.pose_odom_ego, [*pos, yaw], atol=1e-9)


def test_ground_velocity_of_moving_vehicle_seen_from_turning_ego():
    v_world = np.array([12.0, -1.0])
    s, w = 10.0, -0.2
    tr = Tracker()
    run_scene(tr, {"M": linear([5, 6], v_world)}, 40, speed=s, yaw_rate=w, seed=2)
    (track,) = tr.confirmed_tracks
    _, yaw = ego_pose(39 * DT, s, w)
    c, sn = math.cos(yaw), math.sin(yaw)
    np.testing.assert_allclose(track.velocity_xy, np.array([[c, sn], [-sn, c]]) @ v_world, atol=0.3)


def test_max_tracks_refuses_births():
    tr = Tracker(TrackerConfig(max_tracks=2))
    tr.step(0.0, [[5, 0], [10, 5], [15, -5]], 0.0, 0.0)
    assert tr.records[-1].births == [1, 2] and tr.records[-1].refused_births == [2]


# ------------------------------------------------------------------ bad input
def test_bad_input():
    tr = Tracker()
    with pytest.raises(ValueError, match=r"shape \(N, 2\)"):
        tr.step(0.0, np.zeros((3, 3)), 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        tr.step(0.0, [[np.nan, 1.0]], 0.0, 0.0)
    with pytest.raises(ValueError, match="extras"):
        tr.step(0.0, [[1.0, 1.0]], 0.0, 0.0, extras=[1, 2])
    with pytest.raises(ValueError, match="ego_speed_mps"):
        tr.step(0.0, [[1.0, 1.0]], np.inf, 0.0)
    tr.step(1.0, [[1.0, 1.0]], 0.0, 0.0)
    with pytest.raises(ValueError, match="increase"):
        tr.step(1.0, [[1.0, 1.0]], 0.0, 0.0)


def test_bad_config():
    with pytest.raises(ValueError, match="confirm_hits"):
        TrackerConfig(confirm_hits=5, confirm_window=4)
    with pytest.raises(ValueError, match="TrackerConfig.gate_chi2"):
        TrackerConfig(gate_chi2=-1.0)
    with pytest.raises(KeyError, match="TrackerConfig.gate"):
        TrackerConfig.from_dict({"gate": 3.0})
    assert TrackerConfig.from_dict({"gate_m": None}).gate_m is None


# ------------------------------------------------------------------ hidden ground points
def test_hidden_detection_covariance_is_long_along_the_bearing():
    cfg = TrackerConfig(bearing_sigma_rad=0.05, hidden_range_sigma_m=2.0)
    tr = Tracker(cfg)
    z = np.array([0.0, 4.0])  # abeam, left
    R = tr._hidden_cov(z)
    evals, evecs = np.linalg.eigh(R)
    assert np.allclose(np.sort(evals), [(4.0 * 0.05) ** 2, 2.0**2])
    assert abs(abs(evecs[:, np.argmax(evals)] @ np.array([0.0, 1.0])) - 1.0) < 1e-9


def test_hidden_detections_keep_a_track_through_the_blind_zone():
    """A car overtaking on the left: seen with its ground point, then only by bearing
    (the detector puts it at an assumed range 3.0 m, the car is at 4 m); the track
    follows it with one id and keeps its lateral offset near the last measured one."""
    tr = Tracker(TrackerConfig())
    ego_v, car_v = 20.0, 24.0
    ids = set()
    for k in range(40):
        t = k * DT
        p = np.array([-12.0 + (car_v - ego_v) * t, 4.0])  # ego frame, ego driving straight
        if np.hypot(*p) > 7.3:
            tr.step(t, [p], ego_v, 0.0)
        else:
            b = math.atan2(p[1], p[0])
            tr.step(t, [[3.0 * math.cos(b), 3.0 * math.sin(b)]], ego_v, 0.0, bearing_only=[True])
        ids |= {a[0] for a in tr.records[-1].assignments}
        if k > 5:
            assert len(tr.confirmed_tracks) == 1
    (track,) = tr.confirmed_tracks
    assert ids == {track.id}
    assert abs(track.x[2] - car_v) < 2.0  # ground speed
    assert 2.0 < track.x[1] < 5.0


def test_bearing_only_flags_must_match_detections():
    tr = Tracker()
    with pytest.raises(ValueError, match="bearing_only"):
        tr.step(0.0, [[1.0, 2.0]], 0.0, 0.0, bearing_only=[True, False])


def test_vehicle_alongside_keeps_one_id_while_its_nearest_point_jumps_along_it():
    """A car overtaking on the left, its ground hidden by the body mask: the detector's
    nearest point jumps between its front and its rear (5 m apart) from frame to frame.
    Gated against the car's extended body (`TrackerConfig.vehicle_length_m`) the track
    keeps one id; with point gating only, the rear detections start other tracks."""
    ego_v, car_v = 20.0, 22.0

    def run(cfg: TrackerConfig) -> set[int]:
        tr = Tracker(cfg)
        ids: set[int] = set()
        for k in range(60):
            t = k * DT
            front = np.array([-14.0 + (car_v - ego_v) * t, 3.0])  # ego frame
            # from frame 20 on, every other detection is the car's rear
            z = front - [5.0, 0.0] if k >= 20 and k % 2 else front
            tr.step(t, [z], ego_v, 0.0)
            ids |= {a[0] for a in tr.records[-1].assignments}
            ids |= set(tr.records[-1].births)
        return ids

    assert len(run(TrackerConfig())) == 1
    assert len(run(TrackerConfig(vehicle_length_m=0.0))) > 1


def test_extended_body_does_not_take_a_detection_within_a_point_gate():
    """Point gating first: two vehicles in one lane, 7 m apart (nearest points); each
    keeps its own detections although the nearer one's body reaches the other's."""
    tr = Tracker(TrackerConfig(body_min_hits=1))
    vehicles = {1: linear([-10.0, 3.5], [20.0, 0.0]), 2: linear([-17.0, 3.5], [20.0, 0.0])}
    labels = run_scene(tr, vehicles, 40, speed=20.0)
    groups = track_to_gt(tr, labels)
    assert all(len(g) == 1 for g in groups.values())
    assert len(tr.confirmed_tracks) == 2


# ------------------------------------------------------------------ the road a vehicle uncovered
def swept_box_nearest(x_rear, y_near, length, width, back_m):
    """Nearest point to the camera of a box [x_rear - back, x_rear + length] x [y_near,
    y_near + width] (y_near > 0): the box of a vehicle driving along x and the road it
    uncovered over the baseline (independent model: the box's own nearest point)."""
    return np.array([np.clip(0.0, x_rear - back_m, x_rear + length), y_near])


@settings(max_examples=200, deadline=None)
@given(
    x_rear=st.floats(-15.0, 25.0),
    y_near=st.floats(1.0, 8.0),
    speed=st.floats(0.5, 35.0),
    swept=st.floats(0.02, 0.3),
)
def test_swept_measurement_is_the_nearest_point_of_the_swept_box(x_rear, y_near, speed, swept):
    length, width = 4.7, 1.9
    p = swept_box_nearest(x_rear, y_near, length, width, 0.0)  # the vehicle's nearest point
    X = np.array([[*p, speed, 0.0]])
    H = swept_measurement(X, np.array([swept]))[0, 0]
    expected = swept_box_nearest(x_rear, y_near, length, width, speed * swept)
    np.testing.assert_allclose(H @ X[0], expected, atol=1e-9)


def test_swept_measurement_cases():
    X = np.array(
        [
            [10.0, 0.0, 20.0, 0.0],  # ahead, driving away: the whole sweep
            [-10.0, 0.0, 20.0, 0.0],  # behind, driving towards the camera: none
            [1.0, 3.0, 20.0, 0.0],  # alongside: the foot of the perpendicular
            [10.0, 0.0, 0.0, 0.0],  # parked: none
        ]
    )
    H = swept_measurement(X, np.array([0.1, 0.0]))  # (4, 2, 2, 4)
    z = np.einsum("tnij,tj->tni", H, X)
    np.testing.assert_allclose(z[:, 0], [[8.0, 0.0], [-10.0, 0.0], [0.0, 3.0], [10.0, 0.0]])
    np.testing.assert_allclose(z[:, 1], X[:, :2])  # swept_s = 0: [I 0]


def test_track_of_a_vehicle_ahead_finds_it_in_front_of_the_road_it_uncovers():
    """Each detection is the vehicle's rear swept back by its own displacement over the
    baseline; with swept_s the track's point is the vehicle's rear, without it lies
    that displacement behind."""
    speed, v_car, baseline = 20.0, 25.0, 0.2
    rear = linear([8.0, 0.0], [v_car, 0.0])  # world: the vehicle's rear, ahead in the lane
    for swept, off in ((baseline, 0.0), (0.0, -v_car * baseline)):
        tr = Tracker()
        rng = np.random.default_rng(3)
        for k in range(40):
            t = k * DT
            z = world_to_ego(rear(t), t, speed, 0.0) - [v_car * baseline, 0.0]
            tr.step(t, z[None] + 0.05 * rng.standard_normal((1, 2)), speed, 0.0, swept_s=[swept])
        (track,) = tr.confirmed_tracks
        p_true = world_to_ego(rear(39 * DT), 39 * DT, speed, 0.0)
        np.testing.assert_allclose(track.position_xy, p_true + [off, 0.0], atol=0.2)
        np.testing.assert_allclose(track.velocity_xy, [v_car, 0.0], atol=0.3)


def test_swept_times_must_match_detections_and_be_finite():
    tr = Tracker()
    for bad in ([0.1, 0.1], [-0.1], [float("nan")]):
        with pytest.raises(ValueError, match="swept_s"):
            tr.step(0.0, [[1.0, 2.0]], 0.0, 0.0, swept_s=bad)
