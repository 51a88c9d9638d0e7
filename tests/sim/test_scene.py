"""sim/scene.py and sim/textures.py: geometry, colours, ids, and a tiny OSMesa render."""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")  # before anything imports OpenGL

import numpy as np
import pytest
import trimesh

from sim.highway import HighwayBridge, VehicleState
from sim.scene import (
    ASPHALT_TILE_M,
    DASH_OFF_M,
    DASH_ON_M,
    MARK_WIDTH_M,
    build_static_scene,
    decode_id_image,
    id_color,
    id_occluder_mesh,
    vehicle_corners_world,
    vehicles_mesh,
)
from sim.textures import asphalt_texture, grass_texture

FPS = 15.0


@pytest.fixture(scope="module")
def highway():
    """A 4-lane highway-v0 drive (seed 0), its first frame, and a 160 m scene around the ego."""
    b = HighwayBridge("highway-v0", {"vehicles_count": 20}, 0, FPS)
    frame = next(b.frames(1))
    e = frame.ego
    area = (e.x_m - 80.0, e.x_m + 80.0, e.y_m - 40.0, e.y_m + 40.0)
    meshes = build_static_scene(b.road, area, np.random.default_rng(7))
    return b, frame, area, {m.metadata["name"]: m for m in meshes}, meshes


@pytest.fixture(scope="module")
def roundabout():
    b = HighwayBridge("roundabout-v0", {}, 0, FPS)
    area = (-90.0, 90.0, -90.0, 90.0)
    meshes = build_static_scene(b.road, area, np.random.default_rng(3))
    return b, area, {m.metadata["name"]: m for m in meshes}


@pytest.mark.parametrize("fixture", ["highway", "roundabout"])
def test_road_markings_and_grass_lie_in_the_road_plane(fixture, request):
    """The estimator's road plane is z = 0: the road, its markings and the grass are all
    in it (their overlap is settled by depth offsets when drawn, `sim.scene.DEPTH_OFFSET`)."""
    from sim.scene import DEPTH_OFFSET

    by_name = request.getfixturevalue(fixture)[-2 if fixture == "highway" else -1]
    for name in ("road", "markings", "ground"):
        assert np.all(by_name[name].vertices[:, 2] == 0.0), name
    # paint before asphalt before grass, all pushed back: nothing is drawn over what
    # stands on the road
    assert 0 < DEPTH_OFFSET["markings"] < DEPTH_OFFSET["road"] < DEPTH_OFFSET["ground"]


def _inside_triangles(pts: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """(M,) bool: which 2-D points lie in the xy projection of some triangle."""
    tri = mesh.vertices[mesh.faces][:, :, :2]  # (F, 3, 2)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]

    def cross(o, p, q):  # z of (p - o) x (q - o), broadcast (M, F)
        return (p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1]) - (p[..., 1] - o[..., 1]) * (
            q[..., 0] - o[..., 0]
        )

    x = pts[:, None, :]
    d1, d2, d3 = cross(x, a[None], b[None]), cross(x, b[None], c[None]), cross(x, c[None], a[None])
    neg = (d1 < 0) | (d2 < 0) | (d3 < 0)
    pos = (d1 > 0) | (d2 > 0) | (d3 > 0)
    return np.any(~(neg & pos), axis=1)


def _state(vid: int, x: float, y: float, yaw: float, ego: bool = False) -> VehicleState:
    return VehicleState(
        id=vid,
        x_m=x,
        y_m=y,
        yaw_rad=yaw,
        speed_mps=10.0,
        length_m=5.0,
        width_m=2.0,
        height_m=1.5,
        yaw_rate_rps=0.0,
        is_ego=ego,
    )


# --------------------------------------------------------------------------- static scene


def test_few_meshes_each_textured_or_vertex_coloured(highway, roundabout):
    for meshes in (highway[3], roundabout[2]):
        assert 1 <= len(meshes) <= 5
        for name, m in meshes.items():
            if name in ("road", "ground"):
                assert isinstance(m.visual, trimesh.visual.TextureVisuals)
                assert m.visual.material.image is not None
                assert m.visual.uv.shape == (len(m.vertices), 2)
            else:
                assert m.visual.kind == "vertex"
                assert m.visual.vertex_colors.dtype == np.uint8
    assert set(highway[3]) == {"road", "markings", "ground", "roadside"}


def test_road_uvs_are_world_metres_over_the_tile(highway):
    road = highway[3]["road"]
    np.testing.assert_allclose(road.visual.uv, road.vertices[:, :2] / ASPHALT_TILE_M)
    assert np.all(road.vertices[:, 2] == 0.0)


@pytest.mark.parametrize("which", ["highway", "roundabout"])
def test_road_covers_every_lane_centre_in_the_area(which, highway, roundabout):
    if which == "highway":
        b, _, area, meshes, _ = highway
    else:
        b, area, meshes = roundabout
    pts = []
    for ln in b.road.lanes:
        s = np.arange(ln.s_m[0], ln.s_m[-1], 0.5)
        c = np.column_stack([np.interp(s, ln.s_m, ln.center_xy[:, i]) for i in range(2)])
        pts.append(c)
    pts = np.concatenate(pts)
    xmin, xmax, ymin, ymax = area
    pts = pts[(pts[:, 0] > xmin) & (pts[:, 0] < xmax) & (pts[:, 1] > ymin) & (pts[:, 1] < ymax)]
    assert len(pts) > 100
    assert _inside_triangles(pts, meshes["road"]).all()


def test_striped_line_is_dashed_3_on_9_off(highway):
    _, _, area, meshes, _ = highway
    mk = meshes["markings"]
    assert np.all(mk.vertices[:, 2] == 0.0)  # in the road plane (drawn in front by depth offset)
    assert np.all(mk.visual.vertex_colors[:, :3] > 200)  # white paint
    # lanes 0/1 boundary: highway-env lane 1 (y_hw = 4) draws it striped, world y = -2
    v = mk.vertices[np.abs(mk.vertices[:, 1] + 2.0) < 0.1]
    assert np.ptp(v[:, 1]) == pytest.approx(MARK_WIDTH_M, abs=1e-6)
    xs = np.arange(area[0] + 1, area[1] - 1, 0.1)
    painted = _inside_triangles(np.column_stack([xs, np.full_like(xs, -2.0)]), mk)
    assert painted.mean() == pytest.approx(DASH_ON_M / (DASH_ON_M + DASH_OFF_M), abs=0.03)
    # lane 0's left edge (continuous, world y = +2) is painted all along, inside the lane
    cont = _inside_triangles(np.column_stack([xs, np.full_like(xs, 2.0 - MARK_WIDTH_M / 2)]), mk)
    assert cont.all()


def test_roadside_has_rails_on_the_highway_and_buildings_in_town(highway):
    side = highway[3]["roadside"]
    z = side.vertices[:, 2]
    # guard-rails at 0.45-0.78 m just outside both shoulders of the 4-lane road
    rail = np.isclose(z, 0.78) & (np.abs(side.vertices[:, 1] - 2.0 - 1.05 - 0.6) < 0.1)
    assert rail.sum() > 10
    b = HighwayBridge("intersection-v0", {}, 0, FPS)
    town = build_static_scene(b.road, (-60, 60, -60, 60), np.random.default_rng(0))
    side = {m.metadata["name"]: m for m in town}["roadside"]
    assert side.vertices[:, 2].max() > 6.0  # buildings
    assert not b.road.contains_xy(side.vertices[side.vertices[:, 2] > 5.0][:, :2]).any()


def test_normals_agree_with_the_winding(highway, roundabout):
    """Face winding (what pyrender culls/lights with smooth=False) matches the normals."""
    meshes = list(highway[3].values()) + list(roundabout[2].values())
    meshes.append(vehicles_mesh(highway[1].vehicles, "color"))
    for m in meshes:
        fn = m.face_normals
        vn = m.vertex_normals[m.faces].mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", fn, vn) > 0), m.metadata["name"]
    for name in ("road", "markings", "ground"):
        assert np.all(highway[3][name].face_normals[:, 2] > 0.99)


def test_static_scene_is_seeded(highway):
    b, _, area, meshes, _ = highway
    again = build_static_scene(b.road, area, np.random.default_rng(7))
    other = build_static_scene(b.road, area, np.random.default_rng(8))
    side = meshes["roadside"]
    assert np.array_equal(again[3].vertices, side.vertices)
    assert not np.array_equal(other[3].vertices, side.vertices)


def test_static_scene_bad_inputs(highway):
    b = highway[0]
    with pytest.raises(ValueError, match="area_xy"):
        build_static_scene(b.road, (10, 0, 0, 10), np.random.default_rng(0))
    with pytest.raises(TypeError, match="Generator"):
        build_static_scene(b.road, (0, 10, 0, 10), 42)
    with pytest.raises(ValueError, match="style"):
        build_static_scene(b.road, (0, 10, 0, 10), np.random.default_rng(0), style="moon")


# --------------------------------------------------------------------------- vehicles


def test_id_mode_colours_decode_to_vehicle_ids(highway):
    frame = highway[1]
    vs = frame.vehicles
    m = vehicles_mesh(vs, "id")
    nv = m.metadata["vertices_per_vehicle"]
    assert len(m.vertices) == nv * len(vs)
    rgb = m.visual.vertex_colors[:, :3].reshape(1, -1, 3)
    ids = decode_id_image(np.ascontiguousarray(rgb))[0]
    np.testing.assert_array_equal(ids, np.repeat([v.id for v in vs], nv))
    assert ids[0] == 0  # the ego is in the mesh too


def test_id_encoding_round_trip_and_background():
    rng = np.random.default_rng(0)
    ids = np.concatenate([[0, 254, 255, 256, 65535, 2**24 - 2], rng.integers(0, 2**24 - 1, 200)])
    img = id_color(ids).reshape(1, -1, 3)
    np.testing.assert_array_equal(decode_id_image(img)[0], ids)
    assert decode_id_image(np.zeros((2, 3, 3), np.uint8)).tolist() == [[-1] * 3] * 2
    np.testing.assert_array_equal(id_color(0), [1, 0, 0])
    np.testing.assert_array_equal(id_color(256), [1, 1, 0])
    with pytest.raises(ValueError):
        id_color(-1)
    with pytest.raises(ValueError, match="uint8"):
        decode_id_image(np.zeros((2, 2, 3)))


def test_colour_mode_varies_body_colours_and_has_dark_glass(highway):
    vs = highway[1].vehicles
    m = vehicles_mesh(vs, "color")
    nv = m.metadata["vertices_per_vehicle"]
    cols = m.visual.vertex_colors[:, :3].reshape(len(vs), nv, 3)
    body = cols[:, 0]  # first vertex: the lower body
    assert len({tuple(c) for c in body}) >= 4
    dark = cols.sum(axis=2) < 150
    assert np.all(dark.mean(axis=1) > 0.1)  # glass and tyres
    assert np.array_equal(
        cols, vehicles_mesh(vs, "color").visual.vertex_colors[:, :3].reshape(cols.shape)
    )


def test_vehicles_mesh_is_posed_inside_each_box():
    vs = [_state(0, 0.0, 0.0, 0.0, ego=True), _state(7, 20.0, -4.0, 0.7), _state(9, -15, 3, -2.0)]
    m = vehicles_mesh(vs, "color")
    nv = m.metadata["vertices_per_vehicle"]
    for k, v in enumerate(vs):
        p = m.vertices[k * nv : (k + 1) * nv]
        c, s = np.cos(v.yaw_rad), np.sin(v.yaw_rad)
        d = p[:, :2] - (v.x_m, v.y_m)
        lon, lat = d @ (c, s), d @ (-s, c)
        assert np.abs(lon).max() == pytest.approx(v.length_m / 2, abs=0.03)
        assert np.abs(lat).max() == pytest.approx(v.width_m / 2, abs=0.01)
        assert p[:, 2].min() == pytest.approx(0.0, abs=1e-9)
        assert p[:, 2].max() == pytest.approx(v.height_m)
    assert vehicles_mesh([], "id") is None
    with pytest.raises(ValueError, match="mode"):
        vehicles_mesh(vs, "seg")


def test_corners_match_length_width_yaw():
    v = _state(3, 10.0, -2.0, 0.6)
    c = vehicle_corners_world(v)
    assert c.shape == (8, 3)
    fl, fr, rr, rl = c[:4]
    assert np.linalg.norm(fl - rl) == pytest.approx(5.0)
    assert np.linalg.norm(fl - fr) == pytest.approx(2.0)
    fwd = (fl - rl)[:2] / 5.0
    np.testing.assert_allclose(fwd, [np.cos(0.6), np.sin(0.6)])
    left = (fl - fr)[:2] / 2.0
    np.testing.assert_allclose(left, [-np.sin(0.6), np.cos(0.6)])
    np.testing.assert_allclose(c[:, :2].mean(axis=0), [10.0, -2.0])
    np.testing.assert_allclose(c[:4, 2], 0.0)
    np.testing.assert_allclose(c[4:, 2], 1.5)
    np.testing.assert_allclose(c[4:, :2], c[:4, :2])


# --------------------------------------------------------------------------- textures


@pytest.mark.parametrize("make", [asphalt_texture, grass_texture])
def test_textures_are_seeded_and_tileable(make):
    a = make(np.random.default_rng(1), 128)
    assert a.shape == (128, 128, 3) and a.dtype == np.uint8
    assert np.array_equal(a, make(np.random.default_rng(1), 128))
    assert not np.array_equal(a, make(np.random.default_rng(2), 128))
    g = a[..., 1].astype(float)
    inner = np.abs(np.diff(g, axis=1)).mean()
    seam = np.abs(g[:, 0] - g[:, -1]).mean()  # wrapping around: no step at the seam
    assert seam < 1.5 * inner
    seam_v = np.abs(g[0] - g[-1]).mean()
    assert seam_v < 1.5 * np.abs(np.diff(g, axis=0)).mean()


def test_asphalt_has_gradients_at_2_to_20_cm():
    a = asphalt_texture(np.random.default_rng(0)).astype(float)[..., 0]
    texel_m = ASPHALT_TILE_M / a.shape[1]
    for scale_m in (0.02, 0.05, 0.2):
        k = max(1, round(scale_m / texel_m))
        assert np.abs(a - np.roll(a, k, axis=1)).mean() > 6.0  # [DN]
    with pytest.raises(ValueError, match="size_px"):
        asphalt_texture(np.random.default_rng(0), 7)


# --------------------------------------------------------------------------- render


def test_flat_id_render_shows_each_vehicle_id_at_its_centre(highway):
    import pyrender

    _, frame, _, _, meshes = highway
    e = frame.ego
    half = 30.0  # [m] half the view
    size = 128  # [px]
    ids_scene = pyrender.Scene(bg_color=(0, 0, 0, 1), ambient_light=(0, 0, 0))
    ids_scene.add(pyrender.Mesh.from_trimesh(id_occluder_mesh(meshes), smooth=False))
    ids_scene.add(pyrender.Mesh.from_trimesh(vehicles_mesh(frame.vehicles, "id"), smooth=False))
    color_scene = pyrender.Scene(bg_color=(0.6, 0.7, 0.9, 1), ambient_light=(0.8, 0.8, 0.8))
    for m in meshes:
        color_scene.add(pyrender.Mesh.from_trimesh(m, smooth=False))
    color_scene.add(pyrender.Mesh.from_trimesh(vehicles_mesh(frame.vehicles, "color")))
    pose = np.eye(4)
    pose[:3, 3] = (e.x_m, e.y_m, 100.0)  # looking down -z, image up = world +y
    for sc in (ids_scene, color_scene):
        sc.add(pyrender.OrthographicCamera(half, half, znear=1.0, zfar=200.0), pose=pose)
    r = pyrender.OffscreenRenderer(size, size)
    try:
        rgb, _ = r.render(ids_scene, flags=pyrender.RenderFlags.FLAT)
        col, _ = r.render(color_scene)
    finally:
        r.delete()
    ids = decode_id_image(rgb)
    checked = 0
    for v in frame.vehicles:
        u = ((v.x_m - e.x_m) / half + 1) / 2 * size - 0.5
        w = (1 - (v.y_m - e.y_m) / half) / 2 * size - 0.5
        if 2 <= u < size - 2 and 2 <= w < size - 2:
            assert ids[round(w), round(u)] == v.id
            checked += 1
    assert checked >= 2  # the ego and at least one other car
    assert (ids == -1).mean() > 0.8  # road, grass and trees are "no vehicle"
    assert set(np.unique(ids)) <= {-1} | {v.id for v in frame.vehicles}
    # the colour render shows a grey textured road around the ego
    road = col[size // 2 - 12 : size // 2 + 12, :8].reshape(-1, 3).astype(float)
    assert np.all(np.abs(road.mean(axis=0) - road.mean()) < 20)  # greyish
    assert road.std(axis=0).max() > 2.0  # textured, not flat
