"""What stands on the road, drawn in one flat pass that gives colour, vehicle id and range.

Every triangle of the objects (vehicles, guard-rails, posts, trees, buildings) gets its
own 24-bit code, its face colour, drawn FLAT (`pyrender.RenderFlags.FLAT`: GL writes the
colour unlit and unchanged, the depth as usual). Two tables indexed by code give each
triangle's lit colour and its vehicle id (-1 for static objects), so one rasterisation
gives all three images. Code 0 is nothing (the sky, or the road plane drawn elsewhere).

Lighting is baked per triangle (flat shading, as the meshes have no smooth normals):
the diffuse part of pyrender's shader for the same vertex-coloured material under the
scene's sun and ambient light, in linear values, then pyrender's display gamma. Its
specular lobe (roughness 0.8) is left out.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh
from numba import njit, prange

from sim.gl import pyrender
from sim.ground import DISPLAY_GAMMA
from sim.highway import VehicleState
from sim.scene import vehicle_triangles

SUN_TOWARDS = np.array([0.45, 0.55, -0.7])  # [-] sunlight's direction (world), 45 deg up
SUN_INTENSITY = 3.0  # [-] pyrender DirectionalLight intensity
AMBIENT = 0.35  # [-] pyrender ambient light
METALLIC = 0.2  # [-] pyrender's material for vertex-coloured meshes
# pyrender's diffuse term: intensity * (1 - F0) * (1 - metallic) / pi, F0 = 0.04
SUN_DIFFUSE = SUN_INTENSITY * (1.0 - 0.04) * (1.0 - METALLIC) / np.pi


def lit_colors(rgb: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(T, 3) uint8 display colour of triangles with albedo rgb (T, 3) uint8 (used as
    linear values, as pyrender does with vertex colours) and unit normals (T, 3)."""
    sun = -SUN_TOWARDS / np.linalg.norm(SUN_TOWARDS)
    irradiance = AMBIENT + SUN_DIFFUSE * np.clip(normals @ sun, 0.0, None)
    linear = np.asarray(rgb, np.float64) / 255.0 * irradiance[:, None]
    return np.clip(np.rint(255.0 * np.clip(linear, 0, 1) ** (1.0 / DISPLAY_GAMMA)), 0, 255).astype(
        np.uint8
    )


def code_colors(first: int, count: int) -> np.ndarray:
    """(count, 4) uint8 RGBA face colours of codes first .. first + count - 1."""
    code = np.arange(first, first + count, dtype=np.int64)
    if count and code[-1] >= 1 << 24:
        raise ValueError(f"more than {(1 << 24) - 1} triangles to code")
    return np.stack(
        [code & 255, (code >> 8) & 255, code >> 16, np.full(count, 255)], axis=1
    ).astype(np.uint8)


def decode(atlas: np.ndarray) -> np.ndarray:
    """(...) int64 codes of an (..., 3) uint8 flat render."""
    a = np.asarray(atlas)
    return (
        a[..., 0].astype(np.int64)
        | (a[..., 1].astype(np.int64) << 8)
        | (a[..., 2].astype(np.int64) << 16)
    )


def _triangle_props(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) uint8 albedo (the mean of its vertices' colours) and (T, 3) unit normal of
    every triangle of a vertex-coloured mesh."""
    vc = np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.float64)
    rgb = np.rint(vc[mesh.faces].mean(axis=1)).astype(np.uint8)
    return rgb, np.asarray(mesh.face_normals)


def _coded_mesh(mesh: trimesh.Trimesh, first: int) -> pyrender.Mesh:
    m = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)
    m.visual = trimesh.visual.ColorVisuals(m, face_colors=code_colors(first, len(mesh.faces)))
    return pyrender.Mesh.from_trimesh(m, smooth=False)


class CodedScene:
    """The pyrender scene of the objects, drawn with codes, and the tables of the codes.

    static_meshes: vertex-coloured meshes that do not move; `set_vehicles` replaces the
    vehicles of the frame. ``rgb[code]`` (C, 3) uint8 and ``ids[code]`` (C,) int32 read
    a flat render (`decode`).
    """

    def __init__(self, static_meshes: list[trimesh.Trimesh]) -> None:
        self.scene = pyrender.Scene(bg_color=[0, 0, 0, 1.0], ambient_light=[1.0, 1.0, 1.0])
        self._static_nodes: list = []
        self._node = None
        self.set_static(static_meshes)

    def set_static(self, static_meshes: list[trimesh.Trimesh]) -> None:
        """Replace the static objects (and drop the vehicles until `set_vehicles`)."""
        for node in self._static_nodes:
            self.scene.remove_node(node)
        self._static_nodes = []
        rgb, normals = [np.zeros((1, 3), np.uint8)], [np.zeros((1, 3))]
        n = 1
        for m in static_meshes:
            if m is None or not len(m.faces):
                continue
            self._static_nodes.append(self.scene.add(_coded_mesh(m, n)))
            c, nrm = _triangle_props(m)
            rgb.append(c)
            normals.append(nrm)
            n += len(m.faces)
        self.n_static = n  # codes below are static (code 0: nothing)
        self._static_rgb = lit_colors(np.concatenate(rgb), np.concatenate(normals))
        self._static_rgb[0] = 0
        self.set_vehicles(())

    def set_vehicles(self, vehicles: Sequence[VehicleState]) -> None:
        """Put the vehicles (the camera's own car included) in the scene and the tables."""
        if self._node is not None:
            self.scene.remove_node(self._node)
            self._node = None
        corners, albedo, vid = vehicle_triangles(vehicles)
        n = len(corners)
        self.rgb = self._static_rgb
        self.ids = np.full(self.n_static, -1, np.int32)
        if n == 0:
            return
        # one primitive straight from the arrays: each corner carries its triangle's code
        codes = np.repeat(code_colors(self.n_static, n), 3, axis=0)
        prim = pyrender.Primitive(
            positions=corners.reshape(-1, 3).astype(np.float32),
            color_0=codes,
            mode=pyrender.constants.GLTF.TRIANGLES,
        )
        self._node = self.scene.add(pyrender.Mesh([prim]))
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        self.rgb = np.concatenate([self._static_rgb, lit_colors(albedo, normals)])
        self.ids = np.concatenate([self.ids, vid.astype(np.int32)])


@njit(parallel=True, cache=True)
def premultiplied_rgba(atlas: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """(h, w, 4) uint8 colour and coverage of a flat render (h, w, 3) uint8 of codes, by
    the table rgb (C, 3) uint8: (0, 0, 0, 0) where nothing was drawn."""
    h, w = atlas.shape[0], atlas.shape[1]
    out = np.zeros((h, w, 4), np.uint8)
    for r in prange(h):
        for c in range(w):
            code = (
                atlas[r, c, 0] | (np.int64(atlas[r, c, 1]) << 8) | (np.int64(atlas[r, c, 2]) << 16)
            )
            if code > 0:
                out[r, c, 0] = rgb[code, 0]
                out[r, c, 1] = rgb[code, 1]
                out[r, c, 2] = rgb[code, 2]
                out[r, c, 3] = 255
    return out
