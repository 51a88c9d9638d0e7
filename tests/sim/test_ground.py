"""The road plane drawn per pixel: exact range, exact shading of a flat albedo, a texture
fixed to the world, the sky where the plane is not."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from estimator.camera.files import resolve_camera
from estimator.geometry import make_T
from sim.ground import (
    DISPLAY_GAMMA,
    CoverageMap,
    GroundLook,
    GroundRenderer,
    MipAtlas,
    MipTexture,
)

SKY = np.array([158.0, 189.0, 230.0])


def _setup(texture: np.ndarray, tile_m: float = 4.0, preset: str = "omni-near"):
    cam, mount = resolve_camera({"preset": preset, "width": 160, "height": 160})
    big = np.array([[-1e3, -1e3], [1e3, -1e3], [1e3, 1e3], [-1e3, 1e3]])  # road everywhere
    coverage = CoverageMap([big], [], (-200.0, 200.0, -200.0, 200.0))
    tex = MipTexture(texture, tile_m)
    look = GroundLook(tex, tex, np.zeros(3), k_road=1.0, k_grass=1.0, k_marking=1.0)
    T = make_T(mount.R_car_cam, mount.position_m)
    return cam, GroundRenderer(cam, T, look, coverage, SKY), T


def test_flat_albedo_is_shaded_exactly_and_the_range_is_the_rays():
    albedo = 0.2
    cam, ground, T = _setup(np.full((16, 16, 3), albedo, np.float32))
    img = ground.render(T)
    rays = cam.pixel_rays() @ T[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -T[2, 3] / rays[..., 2]
    sure = img.hit & (rays[..., 2] < -0.1)  # the whole footprint on the plane
    assert sure.sum() > 1000
    np.testing.assert_allclose(img.rgb[sure], 255.0 * albedo ** (1 / DISPLAY_GAMMA), atol=1e-3)
    np.testing.assert_allclose(img.range_m[sure], t[sure], rtol=1e-5)
    above = cam.valid_mask() & (rays[..., 2] > 0.05)  # well above the horizon
    assert above.sum() > 100
    np.testing.assert_allclose(
        img.rgb[above], np.broadcast_to(SKY, img.rgb[above].shape), atol=1e-3
    )
    assert np.all(np.isinf(img.range_m[above]))


def test_the_texture_is_fixed_to_the_world():
    """Moving the camera by one texture period along x draws the same image."""
    rng = np.random.default_rng(0)
    cam, ground, T = _setup(rng.uniform(0.05, 0.6, (64, 64, 3)).astype(np.float32), 4.0)
    a = ground.render(T).rgb
    T2 = T.copy()
    T2[0, 3] += 4.0
    b = ground.render(T2).rgb
    assert np.abs(a - b).max() < 0.05  # [DN]
    T3 = T.copy()
    T3[0, 3] += 1.3  # not a period: another image
    hit = ground.render(T).hit
    assert np.abs(a - ground.render(T3).rgb)[hit].mean() > 1.0


@pytest.mark.parametrize("blur", [0.01, 0.03, 0.1])
def test_a_mip_level_is_twice_the_blur(blur):
    atlas = MipAtlas([np.zeros((64, 64, 1), np.float32)] * 1, 0.01, periodic=False)
    tex = MipTexture(np.zeros((64, 64, 3), np.uint8), 0.64)  # 1-cm texels, 7 levels
    lo, frac = tex.levels(np.array([blur]))
    assert lo[0] + frac[0] == pytest.approx(np.log2(2 * blur / 0.01))
    assert atlas.n_levels == 1


def test_only_a_periodic_atlas_has_an_inverse_period():
    """A periodic atlas keeps 1 / period per level; a raster (no period) keeps 0, with no
    division by zero."""
    levels = [np.zeros((64, 64, 1), np.float32), np.zeros((32, 32, 1), np.float32)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        raster = MipAtlas(levels, 0.01, periodic=False)
        tile = MipAtlas(levels, 0.01, periodic=True)
    assert np.all(raster.period == 0.0) and np.all(raster.inv_period == 0.0)
    assert tile.inv_period == pytest.approx([1 / 64, 1 / 32])


def test_a_moved_window_of_the_same_world_takes_over_the_built_tiles():
    """Coverage of another window of one world: tiles taken over from the earlier map are
    the same cells a fresh map builds (and are not built again)."""
    road = [np.array([[-300.0, -6.0], [300.0, -6.0], [300.0, 6.0], [-300.0, 6.0]])]
    marks = [np.array([[-300.0, -0.1], [300.0, -0.1], [300.0, 0.1], [-300.0, 0.1]])]
    first = CoverageMap(road, marks, (-150.0, 150.0, -60.0, 60.0))
    first.follow(20.0, 1.0)
    built = dict(first._tiles)
    moved = CoverageMap(road, marks, (-100.0, 200.0, -60.0, 60.0), tiles_from=first)
    fresh = CoverageMap(road, marks, (-100.0, 200.0, -60.0, 60.0))
    moved.follow(30.0, 1.0)
    fresh.follow(30.0, 1.0)
    assert np.array_equal(moved.fine.atlas, fresh.fine.atlas)
    assert moved.fine.atlas[..., 1].any()  # the marking is in the window
    assert len(built) == 49 and len(moved._tiles) == 49 + 7  # one tile column built anew


def test_a_marking_edge_moves_smoothly_with_the_world():
    """A painted edge across the road 12-16 m ahead, where each footprint is several
    probes long: as the camera moves forward in 1-cm steps the edge's light in the image
    grows in proportion (the coverage's mean over each probe's cell), not in steps from
    probe to probe."""
    cam, mount = resolve_camera({"preset": "omni-near", "width": 320, "height": 320})
    big = np.array([[-1e3, -1e3], [1e3, -1e3], [1e3, 1e3], [-1e3, 1e3]])
    paint = np.array([[14.0, -3.0], [1e3, -3.0], [1e3, 3.0], [14.0, 3.0]])  # x >= 14 m
    flat = MipTexture(np.full((8, 8, 3), 0.1, np.float32), 4.0)
    look = GroundLook(flat, flat, np.ones(3), k_road=1.0, k_grass=1.0, k_marking=1.0)
    T = make_T(mount.R_car_cam, mount.position_m)
    ground = GroundRenderer(cam, T, look, CoverageMap([big], [paint], (-60, 60, -60, 60)), SKY)
    rays = cam.pixel_rays() @ T[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        x = T[0, 3] - T[2, 3] / rays[..., 2] * rays[..., 0]  # road x of each pixel [m]
        y = T[1, 3] - T[2, 3] / rays[..., 2] * rays[..., 1]
    near_edge = (rays[..., 2] < 0) & (np.abs(x - 14.0) < 1.5) & (np.abs(y) < 1.0)
    assert near_edge.sum() > 20
    light = []
    steps = np.arange(0.0, 0.2, 0.01)  # [m]
    for d in steps:
        Td = T.copy()
        Td[0, 3] += d
        rgb = ground.render(Td).rgb[..., 1]
        light.append(np.sum((rgb[near_edge] / 255.0) ** DISPLAY_GAMMA))
    light = np.asarray(light)
    fit = np.polyval(np.polyfit(steps, light, 2), steps)
    per_step = np.abs(np.diff(fit)).mean()
    assert per_step > 0.01  # the edge moved through the pixels
    assert np.abs(light - fit).max() < 0.1 * per_step  # smooth: no jumps between probes
