"""Import pyrender with the OSMesa platform, in one place, with its fixes.

- PYOPENGL_PLATFORM must be set before anything imports OpenGL: OSMesa by default; a value
  already set is kept (``egl`` for a GPU: untested, docs/INSTALL.md).
- pyrender 0.1.45 still uses ``np.infty`` (removed in NumPy 2) in ``Mesh.bounds``;
  the alias below keeps those code paths working.
- pyrender caches compiled shader programs under a key that starts with
  ``OpenGL.contextdata.getContext()``. With OSMesa that call returns a *new*
  pointer object every time, so the cache never hits: every primitive's program
  was compiled again on every render (the per-mesh-node cost of OSMesa rendering,
  docs/INSTALL.md) and the cache grew without bound. `_get_program` keys the cache
  by the context's address instead. Measured here: 5 cube faces of a 5-mesh scene,
  190 -> ~40 ms.
- Anisotropic texture filtering (below).
- Depth offsets for coplanar surfaces (`set_depth_offset`, below).
"""

from __future__ import annotations

import ctypes
import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import numpy as np  # noqa: E402

if not hasattr(np, "infty"):
    setattr(np, "infty", np.inf)  # noqa: B010  pyrender 0.1.45 uses np.infty (gone in NumPy 2)

import OpenGL.contextdata  # noqa: E402
import pyrender  # noqa: E402
from pyrender.shader_program import ShaderProgram, ShaderProgramCache  # noqa: E402


def _context_key() -> int | object:
    ctx = OpenGL.contextdata.getContext()
    try:
        return ctypes.cast(ctx, ctypes.c_void_p).value or 0
    except (TypeError, ctypes.ArgumentError):
        return ctx


def _get_program(self, vertex_shader, fragment_shader, geometry_shader=None, defines=None):
    """pyrender's ShaderProgramCache.get_program with a stable context key."""
    defines = defines or {}
    files = [f for f in (vertex_shader, fragment_shader, geometry_shader) if f is not None]
    names = [os.path.split(f)[1] for f in files]
    key = (_context_key(), *sorted([(s, 1) for s in names] + [(d, defines[d]) for d in defines]))
    if key not in self._program_cache:
        paths = [os.path.join(self.shader_dir, f) for f in files]
        if len(paths) == 2:
            paths.append(None)
        vs, fs, gs = paths
        self._program_cache[key] = ShaderProgram(
            vertex_shader=vs, fragment_shader=fs, geometry_shader=gs, defines=defines
        )
    return self._program_cache[key]


ShaderProgramCache.get_program = _get_program

__all__ = ["pyrender"]


# Anisotropic texture filtering. The road is seen at grazing angles (a few
# degrees below the horizon); isotropic trilinear mipmapping then blurs the
# asphalt to a smear whose blur changes from frame to frame with the viewing
# angle, which breaks the brightness constancy the estimator relies on.
# llvmpipe implements GL_EXT_texture_filter_anisotropic (up to 16x). Its cost
# on Mesa 22.3's llvmpipe can jump to seconds per frame for some tilted views
# (seen with a rolled camera over a large textured ground plane):
# OMNIBENCH_ANISOTROPY=1 turns it off (trilinear only), e.g. to compare speed.
_GL_TEXTURE_MAX_ANISOTROPY = 0x84FE
_GL_MAX_TEXTURE_MAX_ANISOTROPY = 0x84FF
MAX_ANISOTROPY = float(os.environ.get("OMNIBENCH_ANISOTROPY", "16"))

_original_add_to_context = pyrender.texture.Texture._add_to_context


def _add_to_context_anisotropic(self) -> None:
    from OpenGL import GL

    _original_add_to_context(self)
    if self.source is None or MAX_ANISOTROPY <= 1.0:
        return
    try:
        limit = float(GL.glGetFloatv(_GL_MAX_TEXTURE_MAX_ANISOTROPY))
        GL.glBindTexture(self.tex_type, self._texid)
        GL.glTexParameterf(self.tex_type, _GL_TEXTURE_MAX_ANISOTROPY, min(MAX_ANISOTROPY, limit))
        GL.glBindTexture(self.tex_type, 0)
    except GL.GLError:  # extension missing: keep trilinear filtering
        pass


pyrender.texture.Texture._add_to_context = _add_to_context_anisotropic


# Coplanar surfaces. The road, its markings and the grass beside it lie in one plane,
# z = 0: the road plane the estimator assumes. Raising or lowering a surface by a few
# centimetres to settle which one is seen puts it off that plane: grass 3 cm low is
# 1.5 % farther than the plane says (seen from 1.95 m), a speed bias of that size on
# every road point it holds. Instead, the depth test settles it: a primitive with a depth
# offset is drawn with glPolygonOffset(offset, offset) (positive: behind; in units of the
# depth buffer's resolution and of the surface's depth slope per pixel). That changes the
# depth test, not where a surface is drawn; the depth it writes is off by up to a pixel's
# worth of slope (metres for grass near the horizon), so ranges come from a scene drawn
# without offsets (`sim.drive.DriveRenderer.produce`).
DEPTH_OFFSET_ATTR = "omnibench_depth_offset"

_original_bind_and_draw = pyrender.renderer.Renderer._bind_and_draw_primitive


def _bind_and_draw_with_offset(self, primitive, pose, program, flags) -> None:
    from OpenGL import GL

    offset = getattr(primitive, DEPTH_OFFSET_ATTR, 0.0)
    if not offset:
        return _original_bind_and_draw(self, primitive, pose, program, flags)
    GL.glEnable(GL.GL_POLYGON_OFFSET_FILL)
    GL.glPolygonOffset(offset, offset)
    try:
        return _original_bind_and_draw(self, primitive, pose, program, flags)
    finally:
        GL.glDisable(GL.GL_POLYGON_OFFSET_FILL)


pyrender.renderer.Renderer._bind_and_draw_primitive = _bind_and_draw_with_offset


def set_depth_offset(mesh: pyrender.Mesh, offset: float) -> pyrender.Mesh:
    """Draw ``mesh`` with a depth offset (> 0: behind coplanar surfaces, < 0: in front)."""
    for prim in mesh.primitives:
        setattr(prim, DEPTH_OFFSET_ATTR, float(offset))
    return mesh


# Reading a face. pyrender's OffscreenRenderer.render reads the colour with glReadPixels
# (a copy of the colour buffer) and the depth with glReadPixels, then turns every depth
# value into a linear distance with numpy: about 14 ms of a frame's four object faces.
# With OSMesa the colour buffer is pyrender's own array, and OSMesaGetDepthBuffer gives
# the depth buffer itself: `draw` returns both as they are, and only the pixels that a
# camera looks up are turned into distances (`linear_depth_m`).
DEPTH_CODE_MAX = (1 << 24) - 1  # the depth buffer's 24-bit code of its far plane (nothing drawn)


def draw(
    offscreen: pyrender.OffscreenRenderer, scene: pyrender.Scene, flags: int
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``scene`` with ``flags`` into the renderer's viewport.

    Returns colour (h, w, 3) uint8 and depth-buffer codes (h, w) uint32 (window depth
    times DEPTH_CODE_MAX in the low 24 bits), both top row first; with OSMesa they are
    views of the GL buffers, valid until the next draw.
    """
    platform = offscreen._platform
    if platform.supports_framebuffers():  # EGL: pyrender reads; its distances re-coded
        color, z_m = offscreen.render(scene, flags=flags)
        cam = scene.main_camera_node.camera
        return color, depth_codes(z_m, cam.znear, cam.zfar)
    from OpenGL.osmesa import OSMesaGetDepthBuffer

    platform.make_current()
    r = offscreen._renderer
    r.viewport_width, r.viewport_height = offscreen.viewport_width, offscreen.viewport_height
    r.render(scene, flags)  # draws into OSMesa's colour buffer (pyrender's array), flushed
    w, h, nbytes, ptr = OSMesaGetDepthBuffer(platform._context)
    if nbytes != 4 or (w, h) != (r.viewport_width, r.viewport_height):
        raise RuntimeError(f"OSMesa depth buffer {w}x{h} with {nbytes} bytes a value")
    codes = np.ctypeslib.as_array(ctypes.cast(ptr, ctypes.POINTER(ctypes.c_uint32)), (h, w))
    rgba = np.asarray(platform._buffer)
    return rgba[::-1, :, :3], codes[::-1]


def linear_depth_m(codes: np.ndarray, z_near: float, z_far: float) -> np.ndarray:
    """float32 z-depth [m] of depth-buffer codes (any shape), inf where nothing was drawn:
    glReadPixels' float depth and then pyrender's linearisation, bit for bit."""
    d = ((codes & DEPTH_CODE_MAX) / float(DEPTH_CODE_MAX)).astype(np.float32)
    ndc = 2.0 * d - 1.0
    with np.errstate(divide="ignore"):
        z = (2.0 * z_near * z_far) / (z_far + z_near - ndc * (z_far - z_near))
    z[d == 1.0] = np.inf
    return z


def depth_codes(z_m: np.ndarray, z_near: float, z_far: float) -> np.ndarray:
    """(h, w) uint32 depth-buffer codes of z-depths [m] (0: nothing drawn), the inverse of
    `linear_depth_m` up to the codes' rounding."""
    z = np.asarray(z_m, np.float64)
    with np.errstate(divide="ignore"):
        ndc = (z_far + z_near - 2.0 * z_near * z_far / z) / (z_far - z_near)
    d = np.where(z > 0, np.clip(0.5 * ndc + 0.5, 0.0, 1.0), 1.0)
    return np.rint(d * DEPTH_CODE_MAX).astype(np.uint32)
