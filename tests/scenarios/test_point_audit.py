"""The audit of the estimator's points against the range images of a drive."""

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.egomotion.ego_estimator import INLIER, OUTLIER, PointPull
from estimator.fileio import read_png, write_png
from scenarios.point_audit import (
    PullMap,
    camera_unit_rays,
    gt_road_mask,
    gt_vehicle_mask,
    height_map,
    points_above_road,
)
from sim.camera_motion import T_world_car, camera_pose


@pytest.fixture(scope="module")
def raised_drive(tmp_path_factory):
    """A one-pair 'drive': the road everywhere, except a box of pixels that sees a
    surface at 0.9 of the road's range (0.1 h = 0.195 m above it)."""
    camera, mount = load_camera("omni-near")
    pose = camera_pose(T_world_car(0.0, 0.0, 0.0), mount, None, 0.0)
    rays = camera.pixel_rays().astype(np.float64)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    down = rays @ pose.T_world_actual[:3, :3].T  # world directions
    h = pose.T_world_actual[2, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        rng = np.where(down[..., 2] < -1e-3, h / -down[..., 2], 0.0)
    rng = np.nan_to_num(rng)
    box = (slice(300, 340), slice(80, 120))  # rows, cols: left of the car, on the road
    rng[box] *= 0.9
    rng = np.clip(rng, 0, 600)
    drive = tmp_path_factory.mktemp("drive")
    (drive / "range").mkdir()
    write_png(drive / "range" / "000000.png", np.rint(rng * 100).astype(np.uint16))
    gt = [{"T_world_cam_actual": pose.T_world_actual.tolist()}]
    return drive, camera, gt, pose, box


def test_height_map_puts_the_box_above_the_road(raised_drive):
    drive, camera, gt, pose, box = raised_drive
    rays = camera.pixel_rays().astype(np.float64)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    z = height_map(drive, 0, np.nan_to_num(rays), pose.T_world_actual)
    h = pose.T_world_actual[2, 3]
    assert np.median(z[box]) == pytest.approx(0.1 * h, abs=0.01)  # range quantised to 1 cm
    assert np.abs(z[310:330, 200:220]).max() < 0.02  # road elsewhere


def test_shares_of_points_and_information_above_the_road(raised_drive):
    drive, camera, gt, _, _ = raised_drive
    # 4 inliers in the box (info 1 each), 6 on the road (info 0.5 each), 5 outliers in
    # the box (not counted)
    inside = [(100.0, 320.0), (90.0, 310.0), (110.0, 330.0), (95.0, 325.0)]
    road = [(200.0, 320.0), (210.0, 300.0), (520.0, 320.0), (320.0, 100.0), (320, 540), (230, 330)]
    out = [(100.0, 315.0)] * 5
    pts = np.array(inside + road + out, float)
    labels = np.array([INLIER] * 10 + [OUTLIER] * 5, np.int8)
    info = np.array([1.0] * 4 + [0.5] * 6 + [9.0] * 5)
    rec = SimpleNamespace(frame=1, points_px=pts, point_labels=labels, point_speed_info=info)
    first = SimpleNamespace(frame=0, points_px=np.zeros((0, 2)), point_labels=np.zeros(0))
    a = points_above_road(drive, camera, gt, [first, rec])
    assert a["frames"] == 1 and a["inliers"] == 10
    assert a["inlier_share"] == pytest.approx(0.4)
    assert a["speed_info_share"] == pytest.approx(4.0 / 7.0)
    # an estimator without per-point information (the baselines): the share is NaN
    rec.point_speed_info = np.zeros(0)
    assert math.isnan(points_above_road(drive, camera, gt, [rec])["speed_info_share"])


def test_missing_range_image_names_the_file(tmp_path: Path, raised_drive):
    _, camera, gt, _, _ = raised_drive
    rec = SimpleNamespace(
        frame=1, points_px=np.array([[100.0, 320.0]]), point_labels=np.array([INLIER])
    )
    with pytest.raises(FileNotFoundError, match="000000.png"):
        points_above_road(tmp_path, camera, gt, [rec])


def test_gt_road_mask_leaves_out_the_raised_box(raised_drive):
    drive, camera, gt, _, box = raised_drive
    road = gt_road_mask(drive, 0, camera_unit_rays(camera), gt[0])
    assert road.shape == (camera.height, camera.width)
    assert not road[box].any()
    assert road[310:330, 200:220].all()
    assert not road[0, 0]  # outside the mirror: no range, not road


def test_run_refuses_an_unknown_road_mask(tmp_path: Path):
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    with pytest.raises(ValueError, match="road_mask must be 'gt' or None, got 'seg'"):
        run_scenario(load_scenario("highway-omni-near"), tmp_path, road_mask="seg")


def test_gt_vehicle_mask_is_every_vehicle_but_the_ego_car(tmp_path: Path):
    """Id images hold id + 1 (0: no vehicle, 1: the ego car, which the camera sees)."""
    ids = np.zeros((4, 5), np.uint16)
    ids[0, :2] = 1  # the ego car's body
    ids[2, 1:4] = 3  # vehicle 2
    ids[3, 4] = 8  # vehicle 7
    (tmp_path / "ids").mkdir()
    write_png(tmp_path / "ids" / "000004.png", ids)
    mask = gt_vehicle_mask(tmp_path, 4)
    assert mask.dtype == bool and mask.sum() == 4
    assert mask[2, 1:4].all() and mask[3, 4] and not mask[0].any()
    with pytest.raises(FileNotFoundError, match="000005.png"):
        gt_vehicle_mask(tmp_path, 5)


def test_run_refuses_an_unknown_vehicle_mask(tmp_path: Path):
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    with pytest.raises(ValueError, match="vehicle_mask must be 'gt' or None, got 'ids'"):
        run_scenario(load_scenario("highway-omni-near"), tmp_path, vehicle_mask="ids")
    assert not (tmp_path / "drive").exists()  # refused before anything renders


def _road_pixel(camera, mount, forward_m: float, left_m: float) -> np.ndarray:
    """(2,) pixel of the road point at (forward_m, left_m) in the car frame (nominal pose)."""
    p_car = np.array([forward_m, left_m, 0.0]) - mount.position_m
    return camera.project((mount.R_car_cam.T @ p_car)[None])[0]


def test_pull_map_sums_the_pulls_per_pixel_and_range(tmp_path: Path):
    """Two pairs: a near point pulling the speed up and a far one pulling the yaw rate down.
    The means per pair, their split by road range, and the picture follow."""
    camera, mount = load_camera("omni-near")
    R = mount.R_car_cam
    near = _road_pixel(camera, mount, 4.0, 3.0)  # ~5 m from the camera
    far = _road_pixel(camera, mount, 0.0, 25.0)  # ~25 m
    dx_near = np.zeros(9)
    dx_near[:3] = 0.2 * R[0]  # +0.2 m/s forward
    dx_far = np.zeros(9)
    dx_far[3:6] = np.radians(-0.5) * R[2]  # -0.5 deg/s yaw
    pm = PullMap(camera, mount)
    pm.add(PointPull(np.array([near, far]), np.stack([dx_near, dx_far])))
    pm.add(PointPull(np.array([near]), dx_near[None]))
    pm.add(None)  # a pair without a fit is not counted
    s = pm.summary(20.0)
    assert s["pairs"] == 2
    assert s["speed_pull_mps"] == pytest.approx(0.2)  # 0.4 m/s over two pairs
    assert s["speed_pull_pct"] == pytest.approx(1.0)
    assert s["yaw_rate_pull_dps"] == pytest.approx(-0.25)
    bands = s["by_range"]
    assert list(bands) == ["0-10 m", "10-20 m", "20-40 m", "40+ m"]
    assert bands["0-10 m"]["points_share"] == pytest.approx(2 / 3)
    assert bands["0-10 m"]["speed_pull_mps"] == pytest.approx(0.2)
    assert bands["20-40 m"]["yaw_rate_pull_dps"] == pytest.approx(-0.25)
    assert bands["10-20 m"]["points_share"] == 0.0
    png = tmp_path / "pull.png"
    pm.write_png(png, np.full((camera.height, camera.width, 3), 128, np.uint8))
    img = read_png(png)
    assert img.shape[:2] == (camera.height, 2 * camera.width)
    u, v = np.rint(far).astype(int)
    right = img[:, camera.width :]  # the yaw panel: red (down) at the far point
    assert right[v, u, 0] > right[v, u, 1] + 100
    left = img[:, : camera.width]  # the speed panel: green (up) at the near point
    u, v = np.rint(near).astype(int)
    assert left[v, u, 1] > left[v, u, 0] + 100


def test_pull_map_without_pairs_is_nan():
    camera, mount = load_camera("omni-near")
    s = PullMap(camera, mount).summary(20.0)
    assert (
        s["pairs"] == 0 and math.isnan(s["speed_pull_mps"]) and math.isnan(s["yaw_rate_pull_dps"])
    )
    assert math.isnan(s["by_range"]["0-10 m"]["points_share"])
