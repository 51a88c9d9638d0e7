"""Pixel warp w_a -> w_b (eq. 6-10 + H) and its Jacobian (eq. 16) vs central differences."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.egomotion.homography import dh_dx, homography, make_state
from estimator.egomotion.motion_model import (
    RoadPoints,
    constraint_rows,
    map_rays,
    warp_jacobian,
    warp_points,
)

DT = 1.0 / 15.0
PRESETS = ["omni-near", "omni-far", "rectilinear-rear-left"]


def _road_points(preset: str, n: int = 300, seed: int = 0):
    camera, mount = load_camera(preset)
    rng = np.random.default_rng(seed)
    w = np.column_stack(
        [rng.uniform(0, camera.width - 1, 20 * n), rng.uniform(0, camera.height - 1, 20 * n)]
    )
    rays = camera.unproject(w)
    k = rays @ mount.K0
    keep = camera.valid_rays(rays) & (k > 0) & (1.0 / np.maximum(k, 1e-9) < 30.0)
    return camera, mount, RoadPoints.from_pixels(camera, w[keep][:n])


def _state(mount, speed: float = 25.0) -> np.ndarray:
    R = mount.R_car_cam
    return make_state(
        R.T @ [speed, 0.3, 0.05], R.T @ [0.02, -0.03, 0.15], R.T @ [0.004, -0.006, 0.001]
    )


@pytest.mark.parametrize("preset", PRESETS)
def test_zero_motion_is_identity(preset: str) -> None:
    camera, mount, pts = _road_points(preset)
    w_b = warp_points(camera, pts, np.zeros(9), mount.K0, DT)
    assert np.allclose(w_b, pts.w_a, atol=1e-6)


@pytest.mark.parametrize("preset", PRESETS)
def test_warp_jacobian_matches_central_differences(preset: str) -> None:
    camera, mount, pts = _road_points(preset)
    x = _state(mount)
    w_b, J = warp_jacobian(camera, pts.rays_a, x, mount.K0, DT)
    assert J.shape == (len(pts), 2, 9)
    assert np.allclose(w_b, warp_points(camera, pts, x, mount.K0, DT))
    steps = np.r_[np.full(3, 1e-4), np.full(3, 1e-6), np.full(3, 1e-7)]
    J_fd = np.empty_like(J)
    for j in range(9):
        e = np.zeros(9)
        e[j] = steps[j]
        J_fd[:, :, j] = (
            warp_points(camera, pts, x + e, mount.K0, DT)
            - warp_points(camera, pts, x - e, mount.K0, DT)
        ) / (2 * steps[j])
    ok = np.all(np.isfinite(J), axis=(1, 2))
    assert ok.mean() > 0.95
    # per state component, relative to the column's scale over the points
    scale = np.max(np.abs(J[ok]), axis=(0, 1))
    rel = np.max(np.abs(J[ok] - J_fd[ok]), axis=(0, 1)) / scale
    assert np.all(rel < 1e-5), rel


@pytest.mark.parametrize("preset", PRESETS)
def test_constraint_rows_match_central_differences(preset: str) -> None:
    """C_i = g_i^T dw_b/dx (eq. 16) vs central differences of g_i^T w_b(x), g fixed."""
    camera, mount, pts = _road_points(preset, seed=1)
    x = _state(mount, 20.0)
    rng = np.random.default_rng(2)
    g = rng.normal(0, 20, (len(pts), 2))
    P_b = map_rays(pts.rays_a, homography(x, mount.K0, DT))
    C = constraint_rows(camera, pts.rays_a, P_b, g, dh_dx(x, mount.K0, DT))
    assert C.shape == (len(pts), 9)
    steps = np.r_[np.full(3, 1e-4), np.full(3, 1e-6), np.full(3, 1e-7)]

    def c(y):
        return np.sum(g * warp_points(camera, pts, y, mount.K0, DT), axis=1)

    C_fd = np.empty_like(C)
    for j in range(9):
        e = np.zeros(9)
        e[j] = steps[j]
        C_fd[:, j] = (c(x + e) - c(x - e)) / (2 * steps[j])
    ok = np.all(np.isfinite(C), axis=1)
    rel = np.max(np.abs(C[ok] - C_fd[ok]), axis=0) / np.max(np.abs(C[ok]), axis=0)
    assert np.all(rel < 1e-5), rel


def test_road_points_shape() -> None:
    camera, _ = load_camera("omni-near")
    pts = RoadPoints.from_pixels(camera, [[100.0, 320.0], [500.0, 320.0]])
    assert pts.w_a.shape == (2, 2) and pts.rays_a.shape == (2, 3)
    assert np.allclose(np.linalg.norm(pts.rays_a, axis=1), 1.0)
    with pytest.raises(ValueError, match="shape"):
        camera.unproject(np.zeros((3, 3)))
