"""Road segmentation by appearance (`estimator.egomotion.road_appearance`) on drawn scenes."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.camera.files import load_camera
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import default_config
from estimator.egomotion.levels import build_levels
from estimator.egomotion.road_appearance import (
    AppearanceConfig,
    offroad_by_appearance,
    seed_indices,
)

H, W = 120, 160


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """(image (H, W, 3) uint8 RGB, seed (S,) flat indices, regions (H, W) bool by name):
    sky, grass, a light guard-rail band on the far road's edge, asphalt (noisy dark gray)
    below it with an enclosed white dash and a dark crack, the seed at the bottom."""
    img = np.zeros((H, W, 3), np.uint8)
    rows = np.arange(H)[:, None] * np.ones((1, W), int)
    cols = np.ones((H, 1), int) * np.arange(W)[None, :]
    regions = {
        "sky": rows < 30,
        "grass": (rows >= 30) & (rows < 40),
        "rail": (rows >= 40) & (rows < 48),
        "road": rows >= 48,
    }
    img[regions["sky"]] = (150, 190, 230)
    img[regions["grass"]] = (60, 120, 50)
    img[regions["rail"]] = (200, 200, 195)
    asphalt = np.clip(rng.normal(60, 8, (H, W)), 0, 255).astype(np.uint8)
    img[regions["road"]] = np.repeat(asphalt[..., None], 3, axis=2)[regions["road"]]
    regions["dash"] = (rows >= 70) & (rows < 76) & (cols >= 60) & (cols < 90)
    img[regions["dash"]] = (235, 235, 235)
    regions["crack"] = (rows >= 90) & (rows < 92) & (cols >= 20) & (cols < 120)
    img[regions["crack"]] = (25, 25, 25)
    seed = np.flatnonzero(((rows >= 105) & (cols >= 40) & (cols < 120)).ravel())
    return img, seed, regions


def test_rail_grass_and_sky_are_off_road_markings_and_cracks_on_it() -> None:
    img, seed, regions = _scene(np.random.default_rng(0))
    off = offroad_by_appearance(img, seed)
    assert off.shape == (H, W) and off.dtype == np.uint8
    for name in ("sky", "grass", "rail"):
        assert off[regions[name]].mean() == 1.0, name
    # the dash and the crack are holes in the road: filled
    for name in ("road", "dash", "crack"):
        assert off[regions[name]].mean() == 0.0, name


def test_a_marking_at_the_road_edge_is_off_road() -> None:
    """A light line joining the rail is not enclosed by the road: it stays off the road
    (the segmentation keeps what it cannot tell from a kerb out)."""
    img, seed, regions = _scene(np.random.default_rng(1))
    img[48:52] = (235, 235, 235)  # an edge line right below the rail
    off = offroad_by_appearance(img, seed)
    assert off[48:52].mean() == 1.0
    assert off[regions["dash"]].mean() == 0.0


def test_gray_frames_are_judged_by_lightness() -> None:
    img, seed, regions = _scene(np.random.default_rng(2))
    gray = img.mean(axis=2).astype(np.uint8)
    off = offroad_by_appearance(gray, seed)
    assert off[regions["rail"]].mean() == 1.0
    assert off[regions["road"]].mean() == 0.0
    assert off[regions["grass"]].mean() == 1.0  # beyond the rail: not connected
    # without the rail, grass as dark as the asphalt joins the road in gray, not in colour
    img[regions["rail"]] = (60, 120, 50)
    assert offroad_by_appearance(img, seed)[regions["grass"]].mean() == 1.0
    gray = img.mean(axis=2).astype(np.uint8)
    assert offroad_by_appearance(gray, seed)[regions["grass"]].mean() == 0.0


def test_tolerance_decides() -> None:
    img, seed, regions = _scene(np.random.default_rng(3))
    tight = offroad_by_appearance(img, seed, AppearanceConfig(lightness_tol=5.0, close_px=0))
    loose = offroad_by_appearance(img, seed)
    assert tight[regions["road"]].mean() > loose[regions["road"]].mean()


def test_no_seed_no_map() -> None:
    img, _, _ = _scene(np.random.default_rng(4))
    assert offroad_by_appearance(img, np.zeros(0, np.intp)) is None


def test_seed_is_the_nearest_road() -> None:
    K0 = np.array([0.0, 0.5, 0.0])  # camera 2 m above the road, y down
    rays = np.array([[0.0, 1.0, z] for z in (1.0, 2.0, 5.0, 10.0, 20.0)])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    idx = seed_indices(rays, K0, share=0.4)
    assert list(idx) == [0, 1]


@pytest.mark.parametrize("enabled", [True, False])
def test_estimator_excludes_what_does_not_look_like_road(enabled: bool) -> None:
    """The rectilinear camera's frames get an appearance map at the mask level, and no
    point of the next pair is selected in it."""
    camera, mount = load_camera("rectilinear-rear-left")
    cfg = default_config("pinhole", road_appearance=enabled)
    est = DirectEstimator(camera, mount, cfg)
    rng = np.random.default_rng(5)
    img = np.clip(rng.normal(60, 8, (camera.height, camera.width)), 0, 255).astype(np.uint8)
    img = np.repeat(img[..., None], 3, axis=2)
    level = build_levels(camera, mount, cfg)[est._mask_lvl]
    rows = level.roi_idx // level.shape[1]
    band = (rows.min() * 2, (rows.min() + 10) * 2)  # the far road, full resolution
    img[band[0] : band[1]] = (210, 210, 205)  # a light structure across the far road
    est.step(img, 0.0, 20.0)
    look = est._prev.offroad_look
    if not enabled:
        assert look is None
        return
    assert look is not None and look.shape == level.shape
    far = np.zeros(level.shape, bool)
    far[band[0] // 2 : band[1] // 2] = True
    roi = np.zeros(level.shape[0] * level.shape[1], bool)
    roi[level.roi_idx] = True
    roi = roi.reshape(level.shape)
    assert look[far & roi].mean() == 1.0
    assert look[~far & roi].mean() < 0.05
