"""Ground truth exported for other tools: COCO, flow, depth, TUM."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.fileio import read_png
from scenarios.export import ExportError, export_drive, flow_between
from sim.drive import load_groundtruth

FRAMES = 6


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    """A short render of the library's highway drive (a car ahead and guard rails)."""
    from scenarios.config import load_scenario
    from sim.drive import render_drive

    out = tmp_path_factory.mktemp("drive")
    render_drive(load_scenario("highway-omni-near"), out, progress=False, max_frames=FRAMES)
    return out


# pycocotools' own decode warns under numpy 2 (its __array__ has no copy keyword)
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_coco_loads_in_pycocotools_and_boxes_are_the_id_pixels_extent(drive, tmp_path):
    from pycocotools.coco import COCO

    (path,) = export_drive(drive, "coco", tmp_path, progress=False)
    coco = COCO(str(path))
    assert sorted(coco.getImgIds()) == list(range(FRAMES))
    assert coco.getCatIds() == [1]
    n = 0
    for k in range(FRAMES):
        ids = read_png(drive / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        anns = coco.loadAnns(coco.getAnnIds(imgIds=[k]))
        assert sorted(a["track_id"] for a in anns) == sorted(np.unique(ids[ids > 0]).tolist())
        for a in anns:
            m = ids == a["track_id"]
            rows, cols = np.nonzero(m)
            x, y = cols.min(), rows.min()
            assert a["bbox"] == [x, y, cols.max() - x + 1, rows.max() - y + 1]
            assert np.array_equal(coco.annToMask(a).astype(bool), m)
            assert a["area"] == m.sum()
            n += 1
    assert n >= FRAMES  # the car ahead in every frame


def _road_homography(gt_a: dict, gt_b: dict) -> np.ndarray:
    """(3, 3) H with P_b ~ H P_a for points of the road plane z = 0 (camera axes), from the
    two poses: R_ba + t_ba K_a^T, K_a^T P = 1 on the road (eq. 3)."""
    Ta = np.asarray(gt_a["T_world_cam_actual"], float)
    Tb = np.asarray(gt_b["T_world_cam_actual"], float)
    R_ba = Tb[:3, :3].T @ Ta[:3, :3]
    t_ba = Tb[:3, :3].T @ (Ta[:3, 3] - Tb[:3, 3])
    K_a = -(Ta[:3, :3].T @ np.array([0.0, 0.0, 1.0])) / Ta[2, 3]
    return R_ba + np.outer(t_ba, K_a)


def test_flow_on_the_road_is_the_road_homographys_and_vehicles_keep_their_ids(drive, tmp_path):
    files = export_drive(drive, "flow", tmp_path, progress=False)
    assert len(files) == FRAMES - 1
    cam, _ = load_camera(drive / "camera.yaml")
    gt = load_groundtruth(drive)
    k = 3
    flow = np.load(files[k])
    assert flow.shape == (cam.height, cam.width, 2) and flow.dtype == np.float64
    ids = read_png(drive / "ids" / f"{k:06d}.png").astype(np.int64) - 1
    rng = read_png(drive / "range" / f"{k:06d}.png").astype(float) * 0.01
    # road pixels: surfaces within 5 cm of the plane; the homography from the poses
    rays = cam.pixel_rays().reshape(-1, 3).astype(float)
    Ta = np.asarray(gt[k]["T_world_cam_actual"], float)
    z = Ta[2, 3] + (rays @ Ta[:3, :3].T)[:, 2] * rng.reshape(-1)
    road = (ids.reshape(-1) < 0) & (rng.reshape(-1) > 0) & (np.abs(z) < 0.05)
    road &= np.isfinite(flow.reshape(-1, 2)[:, 0])
    assert road.sum() > 10_000
    w_b = cam.project(rays[road] @ _road_homography(gt[k], gt[k + 1]).T)
    pred = w_b - cam.pixel_grid().reshape(-1, 2)[road]
    assert np.max(np.abs(pred - flow.reshape(-1, 2)[road])) < 1e-6  # [px]
    assert np.median(np.hypot(*pred.T)) > 1.0  # the road moves: not a trivial zero
    # vehicles: moved by their own rigid motion, their pixels land on the same vehicle
    ids_b = read_png(drive / "ids" / f"{k + 1:06d}.png").astype(np.int64) - 1
    vv, uu = np.nonzero((ids > 0) & np.isfinite(flow[..., 0]))
    assert len(vv) > 100
    u1 = np.round(uu + flow[vv, uu, 0]).astype(int)
    v1 = np.round(vv + flow[vv, uu, 1]).astype(int)
    inside = (u1 >= 0) & (u1 < cam.width) & (v1 >= 0) & (v1 < cam.height)
    assert np.mean(ids_b[v1[inside], u1[inside]] == ids[vv, uu][inside]) > 0.9
    # the ego car's body moves with the camera: no flow
    ego = (ids == 0) & np.isfinite(flow[..., 0])
    if ego.any():
        assert np.max(np.abs(flow[ego])) < 1e-6


def test_flow_of_a_vehicle_that_leaves_is_unknown():
    cam, _ = load_camera("omni-near")
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking down
    T[2, 3] = 1.95
    a = {"T_world_cam_actual": T.tolist(), "vehicles": [{"id": 4, "x_m": 8.0, "y_m": 0.0,
                                                           "yaw_rad": 0.0}]}  # fmt: skip
    b = {"T_world_cam_actual": T.tolist(), "vehicles": []}
    ids = np.full((cam.height, cam.width), -1)
    ids[10:12, 300:302] = 4
    rng = np.full(ids.shape, 5.0)
    flow = flow_between(cam, a, b, ids, rng)
    assert np.isnan(flow[10:12, 300:302]).all()


def test_depth_tum_and_bad_requests(drive, tmp_path):
    files = export_drive(drive, "depth", tmp_path, progress=False)
    assert len(files) == FRAMES + 1
    d0 = read_png(tmp_path / "depth" / "000000.png")
    assert d0.dtype == np.uint16 and np.array_equal(d0, read_png(drive / "range" / "000000.png"))
    assert json.loads((tmp_path / "depth" / "scale.json").read_text())["unit_m"] == 0.01
    (tum,) = export_drive(drive, "tum", tmp_path, progress=False)
    rows = [r.split() for r in tum.read_text().splitlines() if not r.startswith("#")]
    assert len(rows) == FRAMES and all(len(r) == 8 for r in rows)
    with pytest.raises(ExportError, match="unknown format 'kitti'"):
        export_drive(drive, "kitti", tmp_path)
    with pytest.raises(ExportError, match="not a complete rendered drive"):
        export_drive(tmp_path, "tum", tmp_path / "x")


def _kitti2dbox_hota(gt_folder: Path, trackers_folder: Path, out: Path) -> dict:
    """Stock TrackEval (Evaluator, Kitti2DBox, HOTA, class car) on KITTI tracking files;
    the one tracker's per-sequence HOTA results."""
    import trackeval

    evaluator = trackeval.Evaluator(
        {"USE_PARALLEL": False, "PRINT_RESULTS": False, "PRINT_CONFIG": False,
         "TIME_PROGRESS": False, "OUTPUT_SUMMARY": False, "OUTPUT_DETAILED": False,
         "PLOT_CURVES": False, "LOG_ON_ERROR": str(out / "trackeval_error.log")}
    )  # fmt: skip
    dataset = trackeval.datasets.Kitti2DBox(
        {"GT_FOLDER": str(gt_folder), "TRACKERS_FOLDER": str(trackers_folder),
         "OUTPUT_FOLDER": str(out), "CLASSES_TO_EVAL": ["car"], "PRINT_CONFIG": False}
    )  # fmt: skip
    res, _ = evaluator.evaluate([dataset], [trackeval.metrics.HOTA()])
    (tracker,) = res["Kitti2DBox"]
    return {s: r["car"]["HOTA"] for s, r in res["Kitti2DBox"][tracker].items()}


def test_kitti_tracking_rows_are_the_coco_boxes_and_the_true_poses(drive, tmp_path):
    """Each label row: the COCO export's box (right - left = w), the vehicle's size, and
    its footprint centre and heading in the KITTI camera axes; TrackEval's Kitti2DBox reads
    the files (the labels as a tracker: HOTA 1)."""
    import shutil

    from scenarios.runner import vehicle_footprint

    files = export_drive(drive, "kitti-tracking", tmp_path, progress=False)
    label = tmp_path / "kitti" / "label_02" / "highway-omni-near.txt"
    assert label in files
    (coco_path,) = export_drive(drive, "coco", tmp_path, progress=False)
    coco = json.loads(coco_path.read_text())
    boxes = {(a["image_id"], a["track_id"]): a["bbox"] for a in coco["annotations"]}
    gt = load_groundtruth(drive)
    rows = [r.split() for r in label.read_text().splitlines()]
    assert len(rows) == len(boxes) >= FRAMES
    for r in rows:
        k, vid = int(r[0]), int(r[1])
        assert r[2:5] == ["Car", "0", "0"]
        left, top, right, bottom = map(float, r[6:10])
        assert [left, top, right - left, bottom - top] == boxes[(k, vid)]
        v = next(v for v in gt[k]["vehicles"] if v["id"] == vid)
        h, w, length, x, y, z, ry = map(float, r[10:17])
        assert (h, w, length) == pytest.approx(
            (v["height_m"], v["width_m"], v["length_m"]), abs=1e-6
        )
        c = vehicle_footprint(gt[k], v).mean(axis=0)
        assert (x, y, z) == pytest.approx((-c[1], 0.0, c[0]), abs=1e-6)
        # KITTI's heading (cos ry, -sin ry) in (x, z) is the vehicle's in the road frame
        yaw = v["yaw_rad"] - gt[k]["ego"]["yaw_rad"]
        assert (math.cos(ry), -math.sin(ry)) == pytest.approx(
            (-math.sin(yaw), math.cos(yaw)), abs=1e-5
        )
        assert float(r[5]) == pytest.approx(
            math.remainder(ry - math.atan2(x, z), 2 * math.pi), abs=1e-5
        )
    tracker = tmp_path / "trackers" / "labels" / "data"
    tracker.mkdir(parents=True)
    shutil.copy(label, tracker / label.name)
    hota = _kitti2dbox_hota(tmp_path / "kitti", tmp_path / "trackers", tmp_path / "te")
    assert float(np.mean(hota["highway-omni-near"]["HOTA"])) == pytest.approx(1.0, abs=1e-12)


def test_mot_export_needs_boxes_and_the_mot_format(drive, tmp_path):
    tracks = tmp_path / "points.csv"
    tracks.write_text("frame,track_id,x_m,y_m\n1,3,8.0,0.0\n")
    with pytest.raises(ExportError, match=r"points.csv: no track with a box"):
        export_drive(drive, "mot", tmp_path / "o", progress=False, tracks=tracks)
    with pytest.raises(ExportError, match="exported with --format mot, not 'coco'"):
        export_drive(drive, "coco", tmp_path / "o", progress=False, tracks=tracks)
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,track_id,x_m,y_m\n1,3,8.0\n")
    with pytest.raises(ExportError, match=r"bad.csv, line 2: y_m=None is not a number"):
        export_drive(drive, "mot", tmp_path / "o", progress=False, tracks=bad)
    assert not (tmp_path / "o").exists()
    files = export_drive(drive, "mot", tmp_path / "g", progress=False)
    assert [p.relative_to(tmp_path / "g").as_posix() for p in files] == [
        "mot/highway-omni-near/gt/gt.txt",
        "mot/highway-omni-near/seqinfo.ini",
        "mot/seqmaps/omnibench-all.txt",
    ]
