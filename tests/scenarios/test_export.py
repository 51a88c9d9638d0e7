"""Ground truth exported for other tools: COCO, flow, depth, TUM."""

from __future__ import annotations

import json
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
