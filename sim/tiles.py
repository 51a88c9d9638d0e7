"""The static world of the gym observations, in square tiles fixed to the world grid.

The textured road and markings (from the env's lane geometry, :class:`RoadGeometry`),
the roadside and the ground, as :mod:`sim.scene` builds them, cut into tiles of
``tile_m`` [m]: each tile is seeded by (world seed, tile index), so a place always
looks the same during an episode. The window around an observer is the set of tiles
within ``view_range_m`` [m], merged into 4 meshes (pyrender's cost is per node) and
rebuilt only when the observer's window changes; tiles are cached.
:class:`TiledWorld` is the entry; :class:`sim.env_renderer.OmniEnvRenderer` uses it.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from sim import scene as scene_mod
from sim.highway import RoadGeometry
from sim.textures import asphalt_texture, grass_texture

__all__ = ["TiledWorld", "build_tile", "road_signature"]


@dataclass
class _Tile:
    """Static geometry of one world tile, None where the tile has none.

    road: (v (N, 3) [m], f (M, 3), n (N, 3)), untextured (the window textures it);
    markings, roadside: (v, f, n, c (N, 4) uint8 RGBA).
    """

    road: tuple[np.ndarray, ...] | None
    markings: tuple[np.ndarray, ...] | None
    roadside: tuple[np.ndarray, ...] | None


def _urban(lane: Any) -> bool:
    """sim.scene.build_static_scene's "auto" style: urban at low speed limits."""
    limit = lane.speed_limit_mps
    return limit is not None and limit <= scene_mod.URBAN_SPEED_MPS


def _road_strips(lanes: list[Any]) -> tuple[np.ndarray, ...]:
    """The road surface of sim.scene._road_mesh without its texture: (v, f, n)."""
    vs, fs, ns, base = [], [], [], 0
    overlap, shoulder = scene_mod.LANE_OVERLAP_M, scene_mod.SHOULDER_M
    for lane in lanes:
        nl = scene_mod._left_normals(lane)
        grow_l = overlap + (shoulder if lane.line_types[0] >= scene_mod.CONTINUOUS else 0.0)
        grow_r = overlap + (shoulder if lane.line_types[1] >= scene_mod.CONTINUOUS else 0.0)
        left, right = lane.left_xy + grow_l * nl, lane.right_xy - grow_r * nl
        t = np.stack([nl[:, 1], -nl[:, 0]], axis=1)
        for pts in (left, right):
            pts[0] -= overlap * t[0]
            pts[-1] += overlap * t[-1]
        v, f, n = scene_mod._strip(left, right, 0.0)
        vs.append(v)
        fs.append(f + base)
        ns.append(n)
        base += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(ns)


def _mesh_arrays(mesh: trimesh.Trimesh | None) -> tuple[np.ndarray, ...] | None:
    """A vertex-coloured mesh as (v (N, 3), f (M, 3), n (N, 3), c (N, 4) uint8); None if empty."""
    if mesh is None or len(mesh.faces) == 0:
        return None
    colors = np.asarray(mesh.visual.vertex_colors, dtype=np.uint8)
    return (
        np.asarray(mesh.vertices, float),
        np.asarray(mesh.faces, np.int64),
        np.asarray(mesh.vertex_normals, float),
        colors,
    )


def build_tile(
    road: RoadGeometry, area: tuple[float, float, float, float], rng: np.random.Generator
) -> _Tile:
    """Everything static in ``area`` (x0, x1, y0, y1) [m, world] but the ground, as
    sim.scene builds it.

    Uses sim.scene's private builders: ``build_static_scene`` draws its textures
    (~0.12 s) on every call, too slow per tile; the textures are drawn once per
    world instead (:class:`TiledWorld`).

    The road is clipped with sim.scene's margin (pieces overlap their neighbours'
    exactly: same triangles' colours, no cracks); the roadside is built over the area
    grown by one road sample so that guard-rails run on across tile borders.
    """
    clipped = road.clipped(area, margin_m=2.0)
    lanes = [scene_mod._resample_lane(ln, scene_mod.ROAD_STEP_M) for ln in clipped.lanes]
    lanes = [ln for ln in lanes if len(ln.s_m) >= 2]
    geo = RoadGeometry(lanes=tuple(lanes), obstacles_xyyaw_lw=clipped.obstacles_xyyaw_lw)
    g = scene_mod.ROAD_STEP_M
    grown = (area[0] - g, area[1] + g, area[2] - g, area[3] + g)
    return _Tile(
        road=_road_strips(lanes) if lanes else None,
        markings=_mesh_arrays(scene_mod._markings_mesh(lanes)) if lanes else None,
        roadside=_mesh_arrays(scene_mod._roadside_mesh(geo, grown, rng, _urban)),
    )


def _concat(parts: Iterable[tuple[np.ndarray, ...] | None]) -> tuple[np.ndarray, ...] | None:
    """Concatenate (v, f, ...) tuples into one, shifting the faces; None if all are None."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return None
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    out = [np.concatenate([p[0] for p in parts])]
    out.append(np.concatenate([p[1] + o for p, o in zip(parts, offsets, strict=True)]))
    out.extend(np.concatenate([p[k] for p in parts]) for k in range(2, len(parts[0])))
    return tuple(out)


def _colored_mesh(arrays: tuple[np.ndarray, ...], name: str) -> trimesh.Trimesh:
    """(v, f, n, c) as a trimesh named ``name`` (metadata), unprocessed."""
    v, f, n, c = arrays
    m = trimesh.Trimesh(vertices=v, faces=f, vertex_normals=n, vertex_colors=c, process=False)
    m.metadata["name"] = name
    return m


def _seed_word(i: int) -> int:
    """Signed integer -> non-negative word for np.random.SeedSequence (zig-zag)."""
    return 2 * i if i >= 0 else -2 * i - 1


def road_signature(road: RoadGeometry) -> str:
    """A digest of the road's geometry (to reuse tiles across episodes on the same road)."""
    h = hashlib.blake2b(digest_size=16)
    for ln in road.lanes:
        h.update(repr((ln.index, ln.line_types, ln.speed_limit_mps, ln.kind)).encode())
        for a in (ln.center_xy, ln.left_xy, ln.right_xy, ln.width_m):
            h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(road.obstacles_xyyaw_lw, dtype=np.float64).tobytes())
    return h.hexdigest()


class TiledWorld:
    """The static world as tiles of ``tile_m`` on the world grid, merged per window.

    :meth:`reset` starts a world (road + seed words); :meth:`window_meshes` gives the
    merged meshes around a point, or None when the window has not changed.
    """

    def __init__(self, tile_m: float, view_range_m: float, cache_tiles: int = 512) -> None:
        self.tile_m = float(tile_m)  # [m]
        self.view_range_m = float(view_range_m)  # [m]
        self.cache_tiles = cache_tiles  # tiles kept, least recently used dropped first
        self._key: tuple | None = None
        self._road: RoadGeometry | None = None
        self._words: tuple[int, ...] = ()
        self._tiles: OrderedDict[tuple[int, int], _Tile] = OrderedDict()
        self._textures: tuple[tuple[int, ...], np.ndarray, np.ndarray] | None = None
        self._window: tuple[int, int, int, int] | None = None
        self.builds = 0  # windows merged since construction (for tests and stats)

    def reset(
        self,
        road: RoadGeometry,
        seed_words: tuple[int, ...],
        texture_words: tuple[int, ...] = (0,),
    ) -> None:
        """Start a world: the road, the seed of its tiles, the seed of its textures.

        Tiles are kept when road and seed are those of the last world, the textures
        when their seed is.
        """
        key = (road_signature(road), tuple(seed_words))
        if key != self._key:
            self._key, self._road, self._words = key, road, tuple(seed_words)
            self._tiles.clear()
        if self._textures is None or self._textures[0] != tuple(texture_words):
            rng = np.random.default_rng([*texture_words, 0x7E])
            self._textures = (
                tuple(texture_words),
                asphalt_texture(rng, scene_mod.ASPHALT_PX),
                grass_texture(rng, scene_mod.GRASS_PX),
            )
        self._window = None  # a new episode re-adds its meshes

    def invalidate(self) -> None:
        """Forget the last window: the next :meth:`window_meshes` returns meshes."""
        self._window = None

    def window_of(self, x: float, y: float) -> tuple[int, int, int, int]:
        """Tile indices (ix0, ix1, iy0, iy1), inclusive, within view range of (x, y) [m]."""
        r, t = self.view_range_m, self.tile_m
        return (
            math.floor((x - r) / t),
            math.floor((x + r) / t),
            math.floor((y - r) / t),
            math.floor((y + r) / t),
        )

    def _tile(self, ix: int, iy: int) -> _Tile:
        tile = self._tiles.get((ix, iy))
        if tile is None:
            t = self.tile_m
            area = (ix * t, (ix + 1) * t, iy * t, (iy + 1) * t)
            rng = np.random.default_rng([*self._words, 0x711E, _seed_word(ix), _seed_word(iy)])
            tile = self._tiles[(ix, iy)] = build_tile(self._road, area, rng)
            while len(self._tiles) > self.cache_tiles:
                self._tiles.popitem(last=False)
        else:
            self._tiles.move_to_end((ix, iy))
        return tile

    def window_area(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) [m] of the window returned last by `window_meshes`."""
        if self._window is None:
            raise RuntimeError("no window yet: call window_meshes() first")
        ix0, ix1, iy0, iy1 = self._window
        t = self.tile_m
        return (ix0 * t, (ix1 + 1) * t, iy0 * t, (iy1 + 1) * t)

    def window_meshes(self, x: float, y: float) -> list[trimesh.Trimesh] | None:
        """Merged meshes (road, markings, ground, roadside) of the window around (x, y)
        [m, world]; None if the window is the one returned last."""
        if self._road is None:
            raise RuntimeError("TiledWorld.reset() first")
        win = self.window_of(x, y)
        if win == self._window:
            return None
        ix0, ix1, iy0, iy1 = win
        tiles = [self._tile(ix, iy) for ix in range(ix0, ix1 + 1) for iy in range(iy0, iy1 + 1)]
        _, asphalt, grass = self._textures
        t = self.tile_m
        meshes = []
        road = _concat(tl.road for tl in tiles)
        if road is not None:
            meshes.append(scene_mod._textured(*road, asphalt, scene_mod.ASPHALT_TILE_M, "road"))
        markings = _concat(tl.markings for tl in tiles)
        if markings is not None:
            meshes.append(_colored_mesh(markings, "markings"))
        area = (ix0 * t, (ix1 + 1) * t, iy0 * t, (iy1 + 1) * t)
        meshes.append(
            scene_mod._textured(
                *scene_mod.ground_grid(area), grass, scene_mod.GRASS_TILE_M, "ground"
            )
        )
        roadside = _concat(tl.roadside for tl in tiles)
        if roadside is not None:
            meshes.append(_colored_mesh(roadside, "roadside"))
        self._window = win
        self.builds += 1
        return meshes
