"""Vehicles' shadows on the road: the sun hidden where a ray to the sun meets the car (an
independent ray cast on the car's triangles), the sky hidden under and around it, the
plane shaded by what is left of the light, and no shadow of the camera's own car."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from sim.coded_scene import AMBIENT, SUN_TOWARDS
from sim.ground import DISPLAY_GAMMA, LightMap
from sim.highway import VehicleState
from sim.scene import vehicle_triangles
from sim.shadows import LIGHT_WEIGHTS, SUN_DIRECT, cast_shadows, light
from tests.sim.test_ground import _setup


def _car(x: float, y: float, yaw: float, ego: bool = False, vid: int = 1) -> VehicleState:
    return VehicleState(vid, x, y, yaw, 10.0, 4.6, 1.9, 1.5, 0.0, ego, False)


def _sample(grid: np.ndarray, cell: float, half: float, xy: np.ndarray) -> np.ndarray:
    """Nearest-cell value of a grid centred on the origin at points xy (N, 2) [m]."""
    i = np.floor((xy + half) / cell).astype(int)
    return grid[i[:, 1], i[:, 0]]


def _ray_hits(origins: np.ndarray, d: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(N,) bool: whether the rays from origins (N, 3) along d (3,) meet any triangle
    (T, 3, 3) (Moller-Trumbore)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(d, e2)
    det = np.einsum("tk,tk->t", e1, p)
    ok = np.abs(det) > 1e-12
    e1, e2, p, det, v0 = e1[ok], e2[ok], p[ok], det[ok], tri[ok, 0]
    hits = np.zeros(len(origins), bool)
    for a in range(0, len(origins), 2000):
        s = origins[a : a + 2000, None, :] - v0[None]  # (n, T, 3)
        u = np.einsum("ntk,tk->nt", s, p) / det
        q = np.cross(s, e1[None])
        v = (q @ d) / det
        t = np.einsum("ntk,tk->nt", q, e2) / det
        hits[a : a + 2000] = np.any((u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), axis=1)
    return hits


@pytest.mark.parametrize("yaw", [0.0, 0.7, 2.4])
def test_the_sun_is_hidden_where_a_ray_to_the_sun_meets_the_car(yaw):
    car = _car(4.0, -3.0, yaw)
    lm = cast_shadows([car], np.zeros(2))
    step = 0.05
    g = np.arange(-4.0, 4.0, step)
    gx, gy = np.meshgrid(g + car.x_m, g + car.y_m)
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + 0.5 * step
    to_sun = -SUN_TOWARDS / np.linalg.norm(SUN_TOWARDS)
    origins = np.column_stack([xy, np.full(len(xy), 1e-3)])
    truth = _ray_hits(origins, to_sun, vehicle_triangles([car])[0]).reshape(gx.shape)
    hidden = _sample(lm.sun, lm.sun_cell_m, lm.half_m, xy).reshape(gx.shape) > 127
    # compare away from the shadow's outline (3 cells)
    pad = np.pad(truth, 3, mode="edge")
    n = 2 * 3 + 1
    stack = [pad[i : i + gx.shape[0], j : j + gx.shape[1]] for i in range(n) for j in range(n)]
    check = np.all(np.stack(stack) == truth, axis=0)
    assert truth[check].sum() > 200  # the shadow reaches beyond the footprint
    assert (~truth[check]).sum() > 1000
    np.testing.assert_array_equal(hidden[check], truth[check])


def test_the_kernel_skips_only_blocks_where_both_grids_are_zero():
    lm = cast_shadows([_car(3.0, 2.0, 0.5), _car(-12.0, 7.0, 2.0, vid=2)], np.zeros(2))
    b = lm.near.shape[0]
    for grid in (lm.sun, lm.sky):
        n = grid.shape[0] // b
        blocks = grid.reshape(b, n, b, n).max(axis=(1, 3)) > 0
        assert blocks.any() and not np.any(blocks & (lm.near == 0))
        # bilinear reads reach a neighbour cell: the blocks around a nonzero one are read
        ring = cv2.dilate(blocks.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert not np.any(ring & (lm.near == 0))
    assert lm.near.sum() <= 2 * 300  # [blocks] at most ~17 m x 17 m around each car


def _sky_hidden_by_ray_cast(point: np.ndarray, tri: np.ndarray, n: int) -> float:
    """Share of n cosine-weighted random directions from point (3,) whose ray meets a
    triangle (T, 3, 3) (Moller-Trumbore)."""
    rng = np.random.default_rng(3)
    r, phi = np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    d = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - r * r)])  # (n, 3)
    e1, e2, s = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], point - tri[:, 0]  # (T, 3)
    p = np.cross(d[:, None, :], e2[None])  # (n, T, 3)
    det = np.einsum("ntk,tk->nt", p, e1)
    ok = np.abs(det) > 1e-12
    det = np.where(ok, det, 1.0)
    u = np.einsum("ntk,tk->nt", p, s) / det
    q = np.cross(s, e1)  # (T, 3)
    v = (d @ q.T) / det
    t = (q * e2).sum(axis=1) / det
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    return float(hit.any(axis=1).mean())


@pytest.mark.parametrize("yaw", [0.0, 0.7])
def test_the_sky_hidden_is_that_of_a_ray_cast_on_the_car(yaw):
    """Around the car, the share of the sky hidden equals that of random cosine-weighted
    rays cast on its triangles (4000 rays: one standard deviation <= 0.008); under the car
    nearly all of it (a little passes under the body), far from it none."""
    car = _car(3.0, -2.0, yaw)
    lm = cast_shadows([car], np.zeros(2))

    def sky(xy: np.ndarray) -> float:  # bilinear, cell centres at -half + (i + 0.5) cell
        u = (xy[::-1] + lm.half_m) / lm.sky_cell_m - 0.5
        return float(map_coordinates(lm.sky, u[:, None], order=1)[0])

    c, s = np.cos(yaw), np.sin(yaw)
    fwd, left, centre = np.array([c, s]), np.array([-s, c]), np.array([car.x_m, car.y_m])
    tri = vehicle_triangles([car])[0]
    hl, hw = car.length_m / 2, car.width_m / 2
    for d in (0.3, 1.0, 2.0):
        for xy in (
            centre + (hw + d) * left,
            centre - (hl + d) * fwd,
            centre + (hl + d) * fwd - (hw + d) * left,
        ):
            want = _sky_hidden_by_ray_cast(np.array([*xy, 1e-3]), tri, 4000)
            assert want > 0.005
            assert sky(xy) == pytest.approx(want, abs=0.03)
    under = _sky_hidden_by_ray_cast(np.array([*centre, 1e-3]), tri, 4000)
    assert sky(centre) == pytest.approx(under, abs=0.01) and under > 0.95  # the body's gap
    assert sky(centre + (hw + 6.0) * left) == 0.0


def test_the_sky_hidden_by_two_cars_leaves_the_product_of_what_each_leaves():
    a, b = _car(0.0, 0.0, 0.0), _car(0.0, 3.4, 0.2, vid=2)
    both, one, two = (cast_shadows(v, np.zeros(2)).sky for v in ([a, b], [a], [b]))
    np.testing.assert_allclose(1 - both, (1 - one) * (1 - two), atol=1e-6)
    assert both.max() <= 1.0 and np.any((one > 0.05) & (two > 0.05))


def test_the_camera_car_casts_no_shadow():
    lm = cast_shadows([_car(0.0, 0.0, 0.3, ego=True)], np.zeros(2))
    assert lm.sun_cell_m == 0.0 and lm.sky_cell_m == 0.0
    both = cast_shadows([_car(0.0, 0.0, 0.3, ego=True), _car(8.0, 0.0, 0.0, vid=2)], np.zeros(2))
    assert _sample(both.sun, both.sun_cell_m, both.half_m, np.array([[0.0, 1.3]]))[0] == 0
    assert _sample(both.sun, both.sun_cell_m, both.half_m, np.array([[8.0, 1.3]]))[0] == 255


def test_light_is_the_ambient_part_in_full_shadow_and_one_in_the_open():
    assert light(np.float32(0.0), np.float32(0.0)) == pytest.approx(1.0)
    assert light(np.float32(1.0), np.float32(0.0)) == pytest.approx(
        AMBIENT / (AMBIENT + SUN_DIRECT)
    )
    assert light(np.float32(1.0), np.float32(1.0)) == pytest.approx(0.0, abs=1e-7)
    np.testing.assert_allclose(LIGHT_WEIGHTS, [1 - light(1.0, 0.0), 1 - light(0.0, 1.0)])
    lm = cast_shadows([_car(0.0, 0.0, 0.0)], np.zeros(2))
    np.testing.assert_array_equal(lm.weights, LIGHT_WEIGHTS)
    assert not np.any(LightMap.lit().weights)


@pytest.mark.parametrize("sun_hidden, sky_hidden", [(1.0, 0.0), (1.0, 0.5), (0.0, 1.0)])
def test_the_plane_is_shaded_by_the_light_left(sun_hidden, sky_hidden):
    """A flat albedo under grids that hide the same part of the light everywhere: every
    pixel's linear radiance is the open road's times `light`."""
    albedo = 0.2
    cam, ground, T = _setup(np.full((16, 16, 3), albedo, np.float32))
    n = 400
    lm = LightMap(
        np.full((n, n), np.uint8(round(255 * sun_hidden))),
        0.5,
        np.full((n, n), np.float32(sky_hidden)),
        0.5,
        100.0,
        np.ones((200, 200), np.uint8),
        1.0,
        LIGHT_WEIGHTS,
    )
    H, W = cam.height, cam.width
    image = np.zeros((H, W, 3), np.float32)
    range_m = np.full((H, W), np.inf, np.float32)
    hit = ground.render_into(T, image, range_m, lm)
    rays = cam.pixel_rays() @ T[:3, :3].T
    sure = hit & (rays[..., 2] < -0.1)
    assert sure.sum() > 1000
    want = 255.0 * (albedo * light(sun_hidden, sky_hidden)) ** (1 / DISPLAY_GAMMA)
    np.testing.assert_allclose(image[sure], want, atol=1e-3)
