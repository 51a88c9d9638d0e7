"""A tiny real drive: highway-env -> pyrender/OSMesa -> omni frames + ground truth."""

import json

import cv2
import numpy as np
import pytest

from estimator.camera.files import load_body_mask, load_camera
from estimator.fileio import read_png
from sim import drive as drive_mod
from sim.drive import DriveError, load_groundtruth, render_drive
from sim.scenario import scenario_from_dict
from sim.shadows import OCCLUSION_REACH_M

N = 6


def tiny(**over):
    d = {
        "name": "tiny",
        "env": "highway-v0",
        "env_config": {"vehicles_count": 15, "lanes_count": 3},
        "seed": 3,
        "duration_s": N / 15,
        "fps": 15,
        "camera": {"preset": "omni-near", "width": 200, "height": 200},
        "sensor": {
            "noise_std": 0,
            "motion_blur": False,
            "jpeg_quality": None,
            "gain_drift": 0,
            "vignetting": 0,
        },
    }
    d.update(over)
    return scenario_from_dict(d)


@pytest.fixture(scope="module")
def drive_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("drive")
    res = render_drive(tiny(), out, progress=False)
    assert res.n_frames == N and res.rendered == N
    return out


def test_the_manifest_names_the_machine_that_rendered(drive_dir):
    m = json.loads((drive_dir / "manifest.json").read_text())["machine"]
    assert m["cpu"] and m["cpus"] >= 1 and m["opencv"] and m["numpy"]
    # the OpenGL renderer that drew the frames (llvmpipe with OSMesa)
    assert m["gl_renderer"] and m["gl_version"]


def test_outputs_complete(drive_dir):
    for name in (
        "drive.mp4",
        "camera.yaml",
        "scenario.yaml",
        "can.csv",
        "timestamps.csv",
        "groundtruth.jsonl",
        "manifest.json",
    ):
        assert (drive_dir / name).stat().st_size > 0, name
    gt = load_groundtruth(drive_dir)
    assert [g["frame"] for g in gt] == list(range(N))
    assert gt[0]["motion_from_prev"] is None and gt[1]["motion_from_prev"] is not None
    img = read_png(drive_dir / "frames" / "000003.png")
    assert img.shape == (200, 200, 3) and img.dtype == np.uint8
    assert read_png(drive_dir / "ids" / "000003.png").dtype == np.uint16
    # outside the mirror's image circle is black, the road ring is not
    assert img[0, 0].max() == 0
    assert img[100, 190].max() > 0 or img[190, 100].max() > 0
    assert not list(drive_dir.rglob(".*.png")), "temp files left behind"


def test_body_mask_is_the_ego_cars_pixels(drive_dir):
    """``body_mask.png``: frame 0's ego-car pixels (id 0, written as 1); in later frames
    the body differs only at its edge (the camera's vibration moves it by a pixel); a
    complete render made without one gets it on the next call."""
    cam, _ = load_camera(drive_dir / "camera.yaml")
    body = load_body_mask(drive_dir / "body_mask.png", cam)
    np.testing.assert_array_equal(body, read_png(drive_dir / "ids" / "000000.png") == 1)
    edge = cv2.dilate(body.astype(np.uint8), np.ones((5, 5), np.uint8)) > cv2.erode(
        body.astype(np.uint8), np.ones((5, 5), np.uint8)
    )
    for k in range(1, N):
        off = body != (read_png(drive_dir / "ids" / f"{k:06d}.png") == 1)
        assert off.sum() < 0.02 * body.sum() and not (off & ~edge).any(), k
    assert body[100, 100] and not body[0, 0]  # the roof under the mirror, not the rim
    (drive_dir / "body_mask.png").unlink()
    render_drive(tiny(), drive_dir, progress=False)
    np.testing.assert_array_equal(load_body_mask(drive_dir / "body_mask.png", cam), body)


def test_vehicles_land_on_their_id_pixels(drive_dir):
    """Known 3-D points (vehicle box corners) projected with the camera model bound the
    vehicle's pixels in the rendered id image, within 1 px."""
    cam, _ = load_camera(drive_dir / "camera.yaml")
    checked = 0
    for g in load_groundtruth(drive_dir):
        ids = read_png(drive_dir / "ids" / f"{g['frame']:06d}.png").astype(int) - 1
        T_cw = np.linalg.inv(np.asarray(g["T_world_cam_actual"]))
        for v in g["vehicles"]:
            if v["visible_px"] < 20:
                continue
            P = np.asarray(v["box_world_m"]) @ T_cw[:3, :3].T + T_cw[:3, 3]
            w = cam.project(P)
            if not np.all(np.isfinite(w)):
                continue
            vv, uu = np.nonzero(ids == v["id"])
            assert uu.min() >= w[:, 0].min() - 1 and uu.max() <= w[:, 0].max() + 1
            assert vv.min() >= w[:, 1].min() - 1 and vv.max() <= w[:, 1].max() + 1
            assert v["visible_px"] == len(uu)
            checked += 1
    assert checked > 0, "no vehicle in view: pick another seed"


def test_ground_truth_homography_aligns_the_road(drive_dir):
    from scenarios.road_residual import road_residuals

    cam, mount = load_camera(drive_dir / "camera.yaml")
    assert mount.rear_axle_x_m == pytest.approx(-2.5)  # highway-env's no-slip point (L/2)
    gt = load_groundtruth(drive_dir)
    Hs = {k: np.asarray(gt[k]["motion_from_prev"]["H"]) for k in range(1, N)}
    r = road_residuals(drive_dir, cam, mount, gt, Hs)
    assert r["frames"] >= 3
    assert r["road_median_abs_gt"] < 0.5 * r["uncompensated_median_abs"]
    assert r["road_rms_gt"] < r["uncompensated_rms"]


def test_rerun_resumes_and_reproduces(drive_dir, tmp_path):
    import shutil

    copy = tmp_path / "d"
    shutil.copytree(drive_dir, copy)
    before = read_png(copy / "frames" / "000004.png")
    (copy / "gt" / "000004.json").unlink()  # frame 4 was interrupted
    (copy / "manifest.json").unlink()
    res = render_drive(tiny(), copy, progress=False)
    assert res.rendered == 1
    # every pixel is reproduced exactly, the car-body disc included
    assert np.array_equal(read_png(copy / "frames" / "000004.png"), before)
    assert json.loads((copy / "manifest.json").read_text())["complete"]


def test_interrupted_and_resumed_render_is_byte_identical(drive_dir, tmp_path, monkeypatch):
    """A render stopped after 3 of its 6 frames and resumed writes the very files of an
    uninterrupted one: frames (car-body disc included), ids and range."""
    real = drive_mod.DriveRenderer._render

    def stop_after_three(self, k):
        if k == 3:
            raise KeyboardInterrupt
        return real(self, k)

    monkeypatch.setattr(drive_mod.DriveRenderer, "_render", stop_after_three)
    with pytest.raises(KeyboardInterrupt):
        render_drive(tiny(), tmp_path, progress=False)
    assert len(list((tmp_path / "gt").glob("*.json"))) == 3
    monkeypatch.setattr(drive_mod.DriveRenderer, "_render", real)
    assert render_drive(tiny(), tmp_path, progress=False).rendered == N - 3
    for folder in ("frames", "ids", "range", "gt"):
        names = sorted(p.name for p in (drive_dir / folder).iterdir())
        assert names == sorted(p.name for p in (tmp_path / folder).iterdir()), folder
        differ = [
            n
            for n in names
            if (drive_dir / folder / n).read_bytes() != (tmp_path / folder / n).read_bytes()
        ]
        assert not differ, f"{folder}: {differ} differ from the uninterrupted render"


def test_the_first_frames_of_a_drive_do_not_depend_on_how_many_are_rendered(tmp_path):
    """A drive rendered with ``max_frames`` (``--frames``) is the whole drive's first
    frames, file for file: the scenery lies along the whole path, and the last frame's
    motion blur and CAN messages are the whole drive's."""
    blurred = {"noise_std": 0, "exposure_s": 0.03, "jpeg_quality": None, "gain_drift": 0}
    blurred["vignetting"] = 0
    scenario = tiny(sensor=blurred, can={"speed_noise_mps": 0.1})
    full, short = tmp_path / "full", tmp_path / "short"
    render_drive(scenario, full, progress=False)
    assert render_drive(scenario, short, max_frames=2, progress=False).n_frames == 2
    for folder in ("frames", "ids", "range", "gt"):
        names = sorted(p.name for p in (short / folder).iterdir())
        assert len(names) == 2, folder
        differ = [
            n
            for n in names
            if (full / folder / n).read_bytes() != (short / folder / n).read_bytes()
        ]
        assert not differ, f"{folder}: {differ} differ from the whole drive's"
    t_end = float((short / "timestamps.csv").read_text().splitlines()[-1].split(",")[1])
    whole = [ln for ln in (full / "can.csv").read_text().splitlines()[1:]]
    assert (short / "can.csv").read_text().splitlines()[1:] == [
        ln for ln in whole if float(ln.split(",")[0]) <= t_end + 1e-4
    ]


def test_the_camera_file_records_the_sensor_vignetting(drive_dir, tmp_path):
    """The sensor's vignetting is the drive camera's photometric calibration: its camera
    file says it, and the frames are the unvignetted ones times `vignetting_gain`."""
    sensor = dict(tiny().sensor.model_dump(), vignetting=0.3)
    render_drive(tiny(sensor=sensor), tmp_path, progress=False)
    cam, _ = load_camera(tmp_path / "camera.yaml")
    assert cam.vignetting == 0.3 and load_camera(drive_dir / "camera.yaml")[0].vignetting == 0
    img = read_png(tmp_path / "frames" / "000001.png").astype(np.float32)
    plain = read_png(drive_dir / "frames" / "000001.png").astype(np.float32)
    valid = cam.valid_mask()
    expected = plain * cam.vignetting_gain()[..., None]
    assert np.abs(img - expected)[valid].max() <= 1.0  # 8-bit rounding
    assert np.abs(img - plain)[valid].max() > 10  # (the road ring is vignetted)


def test_interrupted_render_is_not_complete_and_resumes(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = drive_mod.DriveRenderer._render

    def flaky(self, k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(self, k)

    monkeypatch.setattr(drive_mod.DriveRenderer, "_render", flaky)
    sc = tiny(duration_s=4 / 15)
    with pytest.raises(KeyboardInterrupt):
        render_drive(sc, tmp_path, progress=False)
    assert not (tmp_path / "manifest.json").exists()
    with pytest.raises(DriveError, match="not a complete drive"):
        load_groundtruth(tmp_path)
    assert len(list((tmp_path / "gt").glob("*.json"))) == 2
    monkeypatch.setattr(drive_mod.DriveRenderer, "_render", real)
    res = render_drive(sc, tmp_path, progress=False)
    assert res.rendered == 2 and len(load_groundtruth(tmp_path)) == 4


def test_other_scenario_in_same_folder_is_refused(drive_dir):
    with pytest.raises(DriveError, match="different scenario"):
        render_drive(tiny(seed=4), drive_dir, progress=False)


def test_resume_with_another_face_size_is_refused(drive_dir, tmp_path):
    import shutil

    copy = tmp_path / "d"
    shutil.copytree(drive_dir, copy)
    (copy / "gt" / "000004.json").unlink()
    (copy / "manifest.json").unlink()
    face = json.loads((copy / "render.json").read_text())["face_px"]
    with pytest.raises(DriveError, match="face_px"):
        render_drive(tiny(), copy, progress=False, face_px=2 * face)
    assert not (copy / "gt" / "000004.json").exists()  # nothing rendered into the mix


@pytest.mark.parametrize("preset", ["omni-near", "omni-far", "rectilinear-rear-left"])
def test_default_face_is_finer_than_the_camera(preset):
    from estimator.camera.files import resolve_camera
    from estimator.synthetic import pixel_angle_rad
    from sim import frame_renderer as fr

    cam, _ = resolve_camera(preset)
    finest = np.percentile(pixel_angle_rad(cam)[cam.valid_mask()], 1)
    # the cube renderer: a power of two, FACE_OVERSAMPLING x finer, not 2x more
    face = fr.default_face_px(cam)
    texel_rad = np.arctan(2.0 / (face - 3))  # at the face centre, its coarsest
    assert texel_rad * fr.FACE_OVERSAMPLING <= finest * 1.0001
    assert np.arctan(2.0 / (face / 2 - 3)) * fr.FACE_OVERSAMPLING > finest
    # the objects' faces of the plane renderer: a multiple of 8, OBJECT_OVERSAMPLING x finer
    face = fr.object_face_px(cam)
    assert face % 8 == 0
    assert np.arctan(2.0 / (face - 3)) * fr.OBJECT_OVERSAMPLING <= finest * 1.0001
    assert np.arctan(2.0 / (face - 8 - 3)) * fr.OBJECT_OVERSAMPLING > finest


def test_every_frame_is_blurred_by_the_motion_also_the_last(tmp_path):
    """Motion blur on every frame: the last one (no next frame) takes the motion from the
    previous one; before, it was left sharp (a pair of a blurred and a sharp frame that
    no camera gives)."""
    n = 3
    sensor = {"noise_std": 0, "exposure_s": 0.03, "jpeg_quality": None, "gain_drift": 0}
    sensor["vignetting"] = 0
    frames = {}
    for blur in (True, False):
        scenario = tiny(duration_s=n / 15, sensor={**sensor, "motion_blur": blur})
        render_drive(scenario, tmp_path / str(blur), progress=False)
        frames[blur] = [
            read_png(tmp_path / str(blur) / "frames" / f"{k:06d}.png").astype(float)
            for k in range(n)
        ]
    change = [np.abs(b - s).mean() for b, s in zip(frames[True], frames[False], strict=True)]
    assert min(change) > 0.3, change  # [DN] every frame blurred
    assert change[-1] > 0.5 * change[-2], change  # the last as much as the one before


def test_shadows_darken_only_the_road_near_the_vehicles(tmp_path):
    """A scenario with shadows: the same ids and ranges; only plane pixels change, all
    darker, and only within a few metres of a vehicle."""
    dense = {"vehicles_count": 15, "lanes_count": 3, "vehicles_density": 3}  # a car within 8 m
    drive_dir = tmp_path / "lit"
    render_drive(tiny(seed=0, env_config=dense), drive_dir, max_frames=2, progress=False)
    shaded_dir = tmp_path / "s"
    render_drive(
        tiny(seed=0, env_config=dense, shadows=True), shaded_dir, max_frames=2, progress=False
    )
    assert "shadows: true" in (shaded_dir / "scenario.yaml").read_text()
    k = "000001.png"
    for sub in ("ids", "range"):
        assert (shaded_dir / sub / k).read_bytes() == (drive_dir / sub / k).read_bytes()
    lit = read_png(drive_dir / "frames" / k).astype(int)
    shaded = read_png(shaded_dir / "frames" / k).astype(int)
    changed = np.any(shaded != lit, axis=2)
    assert changed.sum() > 20
    assert np.all(shaded[changed] <= lit[changed])
    vehicles = (read_png(drive_dir / "ids" / k).astype(int) - 1 >= 0).astype(np.uint8)
    inside = cv2.erode(vehicles, np.ones((3, 3), np.uint8)) > 0  # edges blend the road
    assert not np.any(changed & inside)
    # every changed pixel within 15 m (small pixel footprints) sees the road near a
    # vehicle: the shadow reaches 1.3 m, the sky hidden OCCLUSION_REACH_M along the car's
    # axes (at a corner sqrt(2) times that), and a pixel's footprint blends a little more
    gt = load_groundtruth(drive_dir)[1]
    T = np.asarray(gt["T_world_cam_actual"])
    d = load_camera(drive_dir / "camera.yaml")[0].pixel_rays()[changed] @ T[:3, :3].T
    xy = T[:2, 3] + (-T[2, 3] / d[:, 2])[:, None] * d[:, :2]
    xy = xy[np.hypot(*(xy - T[:2, 3]).T) < 15.0]
    assert len(xy) > 20
    dist = np.full(len(xy), np.inf)
    for v in gt["vehicles"]:
        c, s = np.cos(v["yaw_rad"]), np.sin(v["yaw_rad"])
        rel = xy - (v["x_m"], v["y_m"])
        along = np.abs(c * rel[:, 0] + s * rel[:, 1]) - v["length_m"] / 2
        across = np.abs(-s * rel[:, 0] + c * rel[:, 1]) - v["width_m"] / 2
        dist = np.minimum(dist, np.hypot(np.maximum(along, 0), np.maximum(across, 0)))
    assert np.all(dist < OCCLUSION_REACH_M * np.sqrt(2) + 0.3), np.sort(dist)[-5:]


def test_shadows_need_the_plane_renderer(tmp_path):
    with pytest.raises(ValueError, match="shadows"):
        render_drive(tiny(shadows=True), tmp_path / "c", renderer="cube", progress=False)
