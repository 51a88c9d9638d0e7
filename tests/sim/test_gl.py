"""Reading a rendered face straight from OSMesa's buffers (`sim.gl.draw`)."""

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from sim.gl import DEPTH_CODE_MAX, depth_codes, draw, linear_depth_m, pyrender


def test_draw_gives_pyrenders_colour_and_depth_bit_for_bit():
    """Colour equal to pyrender's glReadPixels copy; depth codes that `linear_depth_m`
    turns into pyrender's linear depth exactly (0 there: nothing drawn, inf here)."""
    scene = pyrender.Scene(bg_color=[0.2, 0.4, 0.6, 1.0], ambient_light=[1.0, 1.0, 1.0])
    for center, rgb in (((0.0, 0.0, -4.0), (200, 30, 10)), ((1.2, 0.5, -9.0), (10, 220, 40))):
        box = trimesh.creation.box(extents=(1.5, 1.0, 2.0))
        box.apply_translation(center)
        box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=(*rgb, 255))
        scene.add(pyrender.Mesh.from_trimesh(box, smooth=False))
    cam = pyrender.IntrinsicsCamera(fx=60.0, fy=60.0, cx=48.0, cy=40.0, znear=0.05, zfar=400.0)
    scene.add(cam, pose=np.eye(4))
    r = pyrender.OffscreenRenderer(96, 80)
    try:
        flags = pyrender.RenderFlags.FLAT
        color_ref, z_ref = r.render(scene, flags=flags)
        color, codes = draw(r, scene, flags)
        color, codes = color.copy(), codes.copy()
    finally:
        r.delete()
    assert color.shape == (80, 96, 3) and codes.shape == (80, 96)
    np.testing.assert_array_equal(color, color_ref)
    z = linear_depth_m(codes, cam.znear, cam.zfar)
    drawn = z_ref > 0
    assert 0.05 < drawn.mean() < 0.5
    np.testing.assert_array_equal(z[drawn], z_ref[drawn])
    assert np.all(np.isinf(z[~drawn])) and np.all(codes[~drawn] & DEPTH_CODE_MAX == DEPTH_CODE_MAX)
    assert 2.9 < z[drawn].min() < 3.1  # the near box's front face, 3 m away


@settings(max_examples=100, deadline=None)
@given(st.floats(0.06, 390.0))
def test_depth_codes_round_trip(z_m):
    """`depth_codes` inverts `linear_depth_m` to the 24-bit codes' resolution (relative
    z step z (far - near) / (far near) / 2^24 at depth z, here below 1e-3 to 390 m)."""
    z = linear_depth_m(depth_codes(np.array([[z_m]]), 0.05, 400.0), 0.05, 400.0)[0, 0]
    assert abs(z - z_m) <= 1e-3 * z_m
