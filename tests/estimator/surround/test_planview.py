"""Plan view (flat-plane transform): lookups agree with the camera model and mount."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.surround.planview import PlanView, pixel_road_xy


def _road_of_pixels(camera, mount, w: np.ndarray) -> np.ndarray:
    """(N, 2) road point (ego road frame) of pixels w (N, 2), independently of PlanView."""
    P = camera.unproject(w)
    P = P / (P @ mount.K0)[:, None]  # on the road: K0^T P = 1
    p_car = P @ mount.R_car_cam.T + np.asarray(mount.position_m)
    return p_car[:, :2] - np.asarray(mount.position_m[:2])


def test_road_pixel_round_trip():
    cam, mount = load_camera("omni-near")
    pv = PlanView.build(cam, mount, 20.0, 0.2)
    rows, cols = np.array([0, 50, 199]), np.array([3, 120, 60])
    xy = pv.to_road(rows, cols)
    assert np.allclose(pv.to_pixel(xy), np.stack([cols, rows], axis=1))
    # row 0 is the farthest point ahead, column 0 the farthest to the left
    assert xy[0, 0] > 19.0 and xy[0, 1] > 19.0


@pytest.mark.parametrize("preset", ["omni-near", "omni-far", "rectilinear-rear-left"])
def test_cells_map_to_pixels_that_see_them(preset):
    cam, mount = load_camera(preset)
    pv = PlanView.build(cam, mount, 25.0, 0.25)
    r, c = np.nonzero(pv.seen)
    assert len(r) > 100
    pick = np.linspace(0, len(r) - 1, 200).astype(int)
    r, c = r[pick], c[pick]
    w = np.stack([pv.map_x[r, c], pv.map_y[r, c]], axis=1).astype(float)
    back = _road_of_pixels(cam, mount, w)
    assert np.abs(back - pv.to_road(r, c)).max() < 0.01  # [m]


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_pixel_road_xy_matches_inverse_perspective(preset):
    cam, mount = load_camera(preset)
    xy = pixel_road_xy(cam, mount)
    assert xy.shape == (cam.height, cam.width, 2)
    v, u = np.nonzero(np.isfinite(xy[..., 0]))
    pick = np.linspace(0, len(v) - 1, 300).astype(int)
    w = np.stack([u[pick], v[pick]], axis=1).astype(float)
    assert np.abs(xy[v[pick], u[pick]] - _road_of_pixels(cam, mount, w)).max() < 1e-3
    # no road point above the horizon or outside the field of view
    rays = cam.pixel_rays()
    above = (rays @ mount.K0.astype(np.float32)) <= 0
    assert np.isnan(xy[above]).all()
    assert np.isnan(xy[~cam.valid_mask()]).all()


def test_bad_plan_view():
    cam, mount = load_camera("omni-near")
    with pytest.raises(ValueError):
        PlanView.build(cam, mount, 0.0, 0.1)
