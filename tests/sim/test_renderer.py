"""The cube-map renderer agrees with the camera model to within a pixel."""

import numpy as np
import pytest
import trimesh

from estimator.camera.files import resolve_camera
from estimator.geometry import make_T
from sim.gl import pyrender
from sim.renderer import CubeMapLookup, OmniRenderer, face_rotation


def _box_mesh(center, size, value):
    m = trimesh.creation.box(extents=size)
    m.apply_translation(center)
    rgb = [value & 255, (value >> 8) & 255, value >> 16, 255]
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=np.tile(rgb, (len(m.vertices), 1)))
    return m


def _ray_hits_box(origin, dirs, lo, hi):
    """Slab test: (N,) bool, rays from origin along dirs hit the axis-aligned box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - origin) / dirs
        t2 = (hi - origin) / dirs
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return (tmax >= tmin) & (tmax > 0)


def test_face_rotations_are_proper_and_look_along_their_axis():
    for name, look in (("+x", [1, 0, 0]), ("-y", [0, -1, 0]), ("+z", [0, 0, 1])):
        R = face_rotation(name)
        assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1)
        assert np.allclose(-R[:, 2], look)


@pytest.mark.parametrize("preset", ["omni-near", "omni-far", "rectilinear-rear-left"])
def test_lookup_maps_every_valid_pixel_inside_a_face(preset):
    cam, _ = resolve_camera(
        {"preset": preset, "width": 160, "height": 160 if "omni" in preset else 120}
    )
    lk = CubeMapLookup.build(cam, 64)
    v = cam.valid_mask()
    assert np.all(lk.map_x[v] >= 0.5) and np.all(lk.map_x[v] <= 63 - 0.5)
    assert np.all(lk.cos_to_axis[v] >= 1 / np.sqrt(3) - 1e-6)


@pytest.mark.parametrize("windowed", [False, True])
@pytest.mark.parametrize("preset", ["omni-far", "rectilinear-rear-left"])
def test_rendered_box_silhouette_matches_camera_model(preset, windowed):
    """Id render vs analytic ray casting of the model's rays: mismatches only on edges,
    also when only the windows of the faces that valid pixels see are rendered."""
    size = (160, 160) if "omni" in preset else (160, 120)
    cam, mount = resolve_camera({"preset": preset, "width": size[0], "height": size[1]})
    # camera 1.95 m above the origin with the nominal mount, box on the road nearby
    T_world_cam = make_T(mount.R_car_cam, mount.position_m)
    lo = np.array([-9.0, 3.0, 0.0]) if "omni" in preset else np.array([-9.0, 2.5, 0.0])
    hi = lo + [4.0, 1.8, 1.5]
    scene = pyrender.Scene(bg_color=[0, 0, 0, 1], ambient_light=[1, 1, 1])
    scene.add(pyrender.Mesh.from_trimesh(_box_mesh((lo + hi) / 2, hi - lo, 7), smooth=False))
    pixels = cam.valid_mask() if windowed else None
    r = OmniRenderer(cam, face_px=256, pixels=pixels, windowed=windowed)
    try:
        atlas, depth = r.render_atlas(scene, T_world_cam, flat=True, depth=True)
        rgb = r.remap_nearest(atlas)
        rng = r.range_image(depth)
        if windowed and "omni" in preset:  # the windows are smaller than the faces
            assert r.lookup.window_px[1] < 0.6 * r.lookup.face_px
    finally:
        r.close()
    ids = rgb[..., 0].astype(int) + (rgb[..., 1].astype(int) << 8)
    rendered = ids == 7
    rays_cam = cam.pixel_rays().reshape(-1, 3)
    dirs_w = rays_cam @ T_world_cam[:3, :3].T
    expected = _ray_hits_box(T_world_cam[:3, 3], dirs_w, lo, hi).reshape(rendered.shape)
    valid = cam.valid_mask()
    assert expected[valid].sum() > 50, "box must be in view"
    mismatch = (rendered != expected) & valid
    # every mismatch is within 1 px of the true silhouette edge
    import cv2

    edge = cv2.dilate(expected.astype(np.uint8), np.ones((3, 3))) != cv2.erode(
        expected.astype(np.uint8), np.ones((3, 3))
    )
    assert not np.any(mismatch & ~edge), f"{int((mismatch & ~edge).sum())} px off the edge"
    assert mismatch.sum() < 0.25 * edge[valid].sum()
    # range: the box's nearest face distance along the ray is right
    hit = rendered & expected & valid
    P = rays_cam.reshape(*rendered.shape, 3)[hit] * rng[hit][:, None]
    Pw = P @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    inside = np.all((Pw > lo - 0.05) & (Pw < hi + 0.05), axis=1)
    assert inside.mean() > 0.98


def _flat_quad(x0, x1, y0, y1, rgb, name):
    v = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    m = trimesh.Trimesh(vertices=v, faces=[[0, 1, 2], [0, 2, 3]], process=False)
    m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=np.tile([*rgb, 255], (4, 1)))
    m.metadata["name"] = name
    return m


def test_coplanar_road_markings_and_grass_are_each_seen_where_they_lie():
    """Grass, road and a marking all in z = 0 (the estimator's road plane): the depth
    offsets (`sim.scene.DEPTH_OFFSET`) decide what is seen, without z-fighting, out to
    about 100 m (rays 1 degree below the horizon), and a car standing on the marking
    25 m away is seen whole (no surface of the road plane drawn over it)."""
    import cv2

    from sim.frame_renderer import static_pyrender_mesh

    cam, mount = resolve_camera({"preset": "omni-near", "width": 240, "height": 240})
    T_world_cam = make_T(mount.R_car_cam, mount.position_m)
    grass = _flat_quad(-300, 300, -300, 300, (0, 255, 0), "ground")
    road = _flat_quad(-300, 300, -4, 4, (0, 0, 255), "road")
    mark = _flat_quad(-300, 300, 1.9, 2.1, (255, 0, 0), "markings")
    scene = pyrender.Scene(bg_color=[0, 0, 0, 1], ambient_light=[1, 1, 1])
    for m in (grass, mark, road):  # drawn in an order the offsets must overrule
        scene.add(static_pyrender_mesh(m))
    lo, hi = np.array([-27.0, 1.1, 0.0]), np.array([-23.0, 2.9, 1.5])  # a car on the marking
    scene.add(pyrender.Mesh.from_trimesh(_box_mesh((lo + hi) / 2, hi - lo, 7), smooth=False))
    r = OmniRenderer(cam, face_px=512)
    try:
        atlas, _ = r.render_atlas(scene, T_world_cam, flat=True)
        rgb = r.remap_nearest(atlas)
    finally:
        r.close()
    rays = cam.pixel_rays()
    dirs_w = rays.reshape(-1, 3) @ T_world_cam[:3, :3].T
    car = _ray_hits_box(T_world_cam[:3, 3], dirs_w, lo, hi).reshape(rays.shape[:2])
    car &= cam.valid_mask()
    inner = cv2.erode(car.astype(np.uint8), np.ones((3, 3))) > 0  # 1 px from its outline
    assert inner.sum() > 15 and np.all(rgb[inner] == (7, 0, 0))
    near_car = cv2.dilate(car.astype(np.uint8), np.ones((3, 3))) > 0
    hit = cam.valid_mask() & (rays[..., 2] > 0.02) & ~near_car  # the road plane, to ~100 m
    # the world point of each pixel's ray on z = 0 (camera at the mount, nominal axes)
    d = rays[hit] @ T_world_cam[:3, :3].T
    p = T_world_cam[:3, 3] - d * (T_world_cam[2, 3] / d[:, 2:3])
    y = p[:, 1]
    seen = rgb[hit]
    clear = lambda lo, hi: (np.abs(y) > lo) & (np.abs(y) < hi)  # noqa: E731  one surface, 0.1 m from edges
    on_mark, on_road = (y > 2.0 - 0.05) & (y < 2.0 + 0.05), clear(0, 3.9) & ~((y > 1.8) & (y < 2.2))
    assert on_mark.sum() > 20 and np.all(seen[on_mark] == (255, 0, 0))
    assert on_road.sum() > 1000 and np.all(seen[on_road] == (0, 0, 255))
    on_grass = clear(4.1, 1e9)
    assert on_grass.sum() > 1000 and np.all(seen[on_grass] == (0, 255, 0))


def test_faces_finer_than_the_camera_are_low_passed_to_its_pixel():
    """The anti-aliasing prefilter: half a camera pixel (at the face centre) in face
    pixels when the faces are finer than the camera, none when they are coarser; each
    face is blurred alone (nothing mixed across a face border), the car-body faces not."""
    import cv2

    from sim.renderer import finest_pixel_angle_rad, prefilter_sigma_px

    cam, _ = resolve_camera("omni-near")
    finest = finest_pixel_angle_rad(cam)
    fine, coarse = 1.0 / (finest / 2.0), 1.0 / (finest * 2.0)  # focal: texels 2x finer / coarser
    assert prefilter_sigma_px(cam, fine) == pytest.approx(1.0, rel=0.01)
    assert prefilter_sigma_px(cam, coarse) == 0.0
    small, _ = resolve_camera({"preset": "omni-near", "width": 120, "height": 120})
    r = OmniRenderer(small, face_px=256)
    try:
        assert r.prefilter_sigma_px > 0
        F, n = r.lookup.face_px, len(r.lookup.faces)
        atlas = np.random.default_rng(0).integers(0, 256, (n * F, F, 3), dtype=np.uint8)
        before = atlas.copy()
        r.remap_color(atlas)  # low-passes the atlas in place
        for i, name in enumerate(r.lookup.faces):
            face, orig = atlas[i * F : (i + 1) * F], before[i * F : (i + 1) * F]
            if name in r.lookup.body_only:
                assert np.array_equal(face, orig)
            else:
                assert np.array_equal(face, cv2.GaussianBlur(orig, (0, 0), r.prefilter_sigma_px))
    finally:
        r.close()
