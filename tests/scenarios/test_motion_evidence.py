"""The motion-evidence bound: static points have none, moving ones the distance to the
nearest static explanation, and a rendered drive's counts are consistent."""

import numpy as np
import pytest

from estimator.camera.files import load_camera
from scenarios.config import load_scenario
from scenarios.motion_evidence import drive_evidence, pixel_evidence_px, pixel_road_px, summary
from sim.camera_motion import T_world_car, camera_pose
from sim.drive import render_drive


@pytest.fixture(scope="module")
def pair():
    """omni-near on a car that drove 3 m forward between an earlier frame and now, and
    world points 5-20 m around it at 0.1-1.2 m above the road."""
    camera, mount = load_camera("omni-near")
    T_e = camera_pose(T_world_car(0.0, 0.0, 0.0), mount, None, 0.0).T_world_actual
    T = camera_pose(T_world_car(3.0, 0.0, 0.0), mount, None, 0.0).T_world_actual
    rng = np.random.default_rng(0)
    r, b = rng.uniform(5.0, 20.0, 200), rng.uniform(-np.pi, np.pi, 200)
    P = np.c_[3.0 + r * np.cos(b), r * np.sin(b), rng.uniform(0.1, 1.2, 200)]
    return camera, T, T_e, P


def test_a_static_point_has_no_evidence(pair):
    camera, T, T_e, P = pair
    z_max = 2.0 / 3.0 * T[2, 3]  # 1.3 m: every point is within the static heights
    ev = pixel_evidence_px(camera, T, T_e, P, P, z_max)
    assert np.all(np.isfinite(ev)) and ev.max() < 0.1


def test_a_comoving_point_is_as_far_as_the_nearest_static_height(pair):
    """A point that moved with the car was 3 m behind; its evidence is its distance to
    the curve of static earlier pixels, here sampled 50 times finer."""
    camera, T, T_e, P = pair
    P_e = P - [3.0, 0.0, 0.0]
    z_max = 2.0 / 3.0 * T[2, 3]
    ev = pixel_evidence_px(camera, T, T_e, P, P_e, z_max)
    w_true = camera.project((P_e - T_e[:3, 3]) @ T_e[:3, :3])
    c, ray = T[:3, 3], P - T[:3, 3]
    brute = np.full(len(P), np.inf)
    for z in np.linspace(0.0, z_max, 2000):
        X = c + ((z - c[2]) / ray[:, 2])[:, None] * ray
        w = camera.project((X - T_e[:3, 3]) @ T_e[:3, :3])
        brute = np.fmin(brute, np.hypot(*(w_true - w).T))
    assert np.allclose(ev, brute, atol=0.25)
    assert np.median(ev) > 2.0  # 3 m of travel: most such points show it


def test_a_static_point_above_the_road_stands_and_a_road_point_does_not(pair):
    """A static point 0.1-1.2 m up: no motion evidence, but its earlier pixel is away from
    the road's prediction on its ray (as far as a brute-force projection says); a point on
    the road: at the road's prediction."""
    camera, T, T_e, P = pair
    d = pixel_road_px(camera, T, T_e, P, P)
    c, ray = T[:3, 3], P - T[:3, 3]
    X = c + ((0.0 - c[2]) / ray[:, 2])[:, None] * ray  # the road point on each ray
    w_road = camera.project((X - T_e[:3, 3]) @ T_e[:3, :3])
    w_true = camera.project((P - T_e[:3, 3]) @ T_e[:3, :3])
    assert np.allclose(d, np.hypot(*(w_true - w_road).T))
    assert np.median(d) > 2.0  # 3 m of travel: most such points stand out
    road = P * [1.0, 1.0, 0.0]
    assert np.nanmax(pixel_road_px(camera, T, T_e, road, road)) < 1e-6


def test_a_ray_above_the_camera_has_none(pair):
    camera, T, T_e, _ = pair
    P = np.array([[10.0, 0.0, T[2, 3] + 0.5]])
    assert np.isnan(pixel_evidence_px(camera, T, T_e, P, P - [1.0, 0, 0], 1.0))[0]


def test_a_rendered_dense_drive(tmp_path):
    """Per evaluated vehicle-frame: evident <= analysed <= visible pixels, evident edge
    pixels <= evident pixels; the dense freeway's vehicles move unlike the road."""
    sc = load_scenario("dense-freeway-omni-near")
    render_drive(sc, tmp_path, progress=False, max_frames=6)
    recs = drive_evidence(tmp_path, baseline=2, every=1)
    assert len(recs) >= 4 and {r["frame"] for r in recs} <= {2, 3, 4, 5}
    for r in recs:
        assert r["evident_edge_px"] <= r["evident_px"] <= r["analysed_px"] <= r["visible_px"]
        assert r["evident_px"] + r["standing_px"] <= r["analysed_px"]
    s = summary(recs)
    assert s["all"]["vehicle_frames"] == len(recs)
    assert s["all"]["evident_px>=20"] > 0.5
    assert s["all"]["evident_or_standing_px>=20"] >= s["all"]["evident_px>=20"]
    with pytest.raises(ValueError, match="baseline"):
        drive_evidence(tmp_path, baseline=0)


def test_the_summary_counts_evident_and_standing_pixels_together():
    """A vehicle-frame with 10 evident and 15 standing pixels has 20 of either, not 20
    evident ones; one with 25 evident pixels has both."""
    recs = [
        {"motion": "overtaken", "evident_px": 10, "evident_edge_px": 5, "standing_px": 15},
        {"motion": "overtaken", "evident_px": 25, "evident_edge_px": 0, "standing_px": 0},
    ]
    row = summary(recs, min_px=(20,))["overtaken"]
    assert row["vehicle_frames"] == 2
    assert row["evident_px>=20"] == 0.5 and row["evident_edge_px>=20"] == 0.0
    assert row["evident_or_standing_px>=20"] == 1.0
