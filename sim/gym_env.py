"""Gymnasium face of omnibench: omni-camera observations for any highway-env env.

Three ways in, one renderer behind them (:class:`OmniEnvRenderer`):

- **observation type by name**: ``config={"observation": {"type":
  "omnibench.OmniObservation", "camera": "omni-near", "width": 128, "height": 128,
  "vehicle_ids": True}}`` in any highway-env env. highway-env 1.12.1's
  ``observation_factory`` is a closed ``if/elif`` chain over its own names (no
  registry, no import by dotted path), so importing this module installs
  :func:`register_observation_type`: a factory that builds
  :class:`OmniObservation` for our names and hands every other name to the original
  (idempotent; it replaces the name in every highway-env module that imported it).
  The same call makes ``AbstractEnv.close`` also release the omni renderers' GL
  contexts. Loading: ``import sim.gym_env``, or the ``"sim.gym_env:merge-v0"`` form
  of ``gymnasium.make`` (which imports it first; use it in spawned vector-env
  workers).
- **wrapper**: :class:`OmniObservationWrapper` ``(env, camera=..., width=...,
  ...)`` replaces the observation of ANY highway-env env (wrapped or not); no
  factory involved.
- **registered env**: ``omnibench/OmniHighway-v0`` (registered by ``import sim``,
  loaded lazily from here): highway-v0 (:class:`OmniHighwayEnv`) whose default
  observation is the omni one, 128 x 128 omni-near; a partial
  ``config["observation"]`` (no ``type``) updates those defaults.

Observation: ``Box(0, 255, (H, W, 3), uint8)`` RGB, or with ``vehicle_ids=True`` a
``Dict`` with ``"image"`` and ``"vehicle_ids"`` ``Box(-1, 2**24 - 2, (H, W),
int32)``: the id of the vehicle seen by each pixel, -1 for none. Ids are stable
within an episode: the controlled vehicles are 0, 1, ... (the ego is 0, its body
fills the masked disc at the centre of an omni image), the other vehicles follow in
order of first appearance, as in :mod:`sim.highway`. :meth:`OmniObservation.vehicles_by_id`
maps them back to highway-env vehicles. Pixels without an image (outside the
mirror's circle) are black and -1.

Rendering per observation:

- the static world (textured road and markings from the env's lane geometry,
  roadside, ground) lives in square tiles of ``tile_m`` fixed to the world grid, each
  seeded by (world seed, tile index), so a place always looks the same during an
  episode; the window is the set of tiles within ``view_range_m`` of the observer,
  merged into 4 meshes (pyrender's cost is per node) and rebuilt only when the
  observer's window changes; tiles are cached. The road geometry is sampled once
  per episode (``sim.highway.road_geometry``: world = (x_hw, -y_hw), yaw = -heading).
- the vehicles (``env.road.vehicles`` within ``view_range_m``) are re-posed every
  step as one merged mesh (``sim.scene.vehicles_mesh``);
- the camera sits on the observer (``observer_vehicle``, default the ego) by the
  camera's mount (``sim.camera_motion.camera_pose``), optionally vibrating;
- ``sim.renderer.OmniRenderer`` renders the cube map and ray-maps it;
- sensor effects (``sim.sensor``) are off by default; ``sensor: {...}`` takes the
  keys of ``sim.scenario.SensorConfig``. Motion blur uses the motion since the
  previous observation (the next one is not known online).

Seeds. The seed of an episode is (seed passed to the last ``reset(seed=...)``,
episodes since then). The roadside of the tiles derives from it, or from
``world_seed`` when given (then the tiles are reused across episodes on the same
road); the asphalt and grass textures from ``world_seed`` (0 when not given: the
same in every episode, ~0.1 s saved per reset). Vehicle heights, vibration phases,
sensor noise and gain derive from the episode seed; nothing draws from the env's
``np_random``, so the traffic is exactly that of the plain env. ``reset(seed=s)``
twice gives identical observations.

Render state (GL context, scenes, tiles) is kept per env and per camera set-up,
shared by every observation object with that set-up (highway-env rebuilds its
observation objects at every reset), created at the first observation and released
by ``env.close()``.
"""

from __future__ import annotations

import hashlib
import math
import os
import secrets
import weakref
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import gymnasium
import highway_env  # noqa: F401  (registers the highway-env ids)
import numpy as np
import trimesh
from gymnasium import spaces
from highway_env.envs.common import observation as hw_observation
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.observation import ObservationType
from highway_env.envs.highway_env import HighwayEnv
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from estimator.camera.files import resolve_camera
from estimator.camera.models import CameraModel, vignetting_gain
from estimator.camera.mount import CameraMount
from sim import scene as scene_mod
from sim.camera_motion import CameraPose, T_world_car, Vibration, camera_pose
from sim.drive import (
    WorldScenes,
    default_face_px,
    imaged_mask,
    scene_flow_px,
    static_pyrender_mesh,
)
from sim.gl import pyrender  # OSMesa platform and pyrender fixes (sim/gl.py)
from sim.highway import (
    EGO_HEIGHT_M,
    HEIGHT_RANGE_M,
    RoadGeometry,
    VehicleState,
    road_geometry,
    world_from_hw_xy,
    world_yaw_from_hw_heading,
)
from sim.renderer import OmniRenderer
from sim.scenario import SensorConfig, VibrationConfig
from sim.scene import decode_id_image, id_occluder_mesh, vehicles_mesh
from sim.sensor import SensorModel, apply_sensor, exposure_times
from sim.textures import asphalt_texture, grass_texture

# highway-env's "human" render mode opens a pygame window. Without a display SDL falls
# back to its "offscreen" video driver, which sets up its own GL (EGL) and leaves the
# OSMesa context of our renderer broken (GLError at the next call). With no display
# there is no window to show anyway: SDL's "dummy" driver (highway-env then skips
# its viewer).
if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

__all__ = [
    "ENV_ID",
    "OBSERVATION_TYPE",
    "OmniEnvRenderer",
    "OmniHighwayEnv",
    "OmniObservation",
    "OmniObservationConfig",
    "OmniObservationWrapper",
    "close_renderers",
    "register_observation_type",
]

ENV_ID = "omnibench/OmniHighway-v0"
#: The name a highway-env config gives as ``observation.type``; the bare class name
#: is accepted too.
OBSERVATION_TYPE = "omnibench.OmniObservation"
OBSERVATION_TYPES = (OBSERVATION_TYPE, "OmniObservation")
#: Largest vehicle id an id image can carry (24-bit colour, id + 1).
MAX_VEHICLE_ID = (1 << 24) - 2

_STORE_ATTR = "_omnibench_renderers"  # env attribute: {set-up key: OmniEnvRenderer}
_CONSTRUCTING_ATTR = "_omnibench_constructing"  # set by OmniHighwayEnv.__init__


# --------------------------------------------------------------------------- config


class OmniObservationConfig(BaseModel):
    """The ``observation`` config of :class:`OmniObservation` (unknown keys are errors).

    camera: preset name (``omni-near``, ``omni-far``, ``rectilinear-rear-left``), a
        camera file, or a ``resolve_camera`` mapping ``{preset: ..., ...}``.
    width, height: image size [px] (override the camera's; intrinsics rescale).
    vehicle_ids: also return the per-pixel vehicle-id image (Dict observation).
    face_px: cube-face size [px] (default: ``sim.drive.default_face_px``).
    view_range_m: how far around the observer the world is built [m].
    tile_m: side of a world tile [m].
    world_seed: fixed seed of the static world (default: from the episode seed).
    sensor: ``SensorConfig`` keys; every effect is off unless given.
    vibration: ``VibrationConfig`` keys (amplitude_deg, frequency_hz); None = none.
        A tilted camera can be very slow on llvmpipe: its anisotropic texture
        filtering (sim/gl.py) took 5-30 s per frame at some poses with tilts of
        0.3-15 deg (Mesa 22.3), against ~0.1 s level.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str = OBSERVATION_TYPE
    camera: str | dict[str, Any] = "omni-near"
    width: int | None = Field(None, ge=8, le=4096)
    height: int | None = Field(None, ge=8, le=4096)
    vehicle_ids: bool = False
    face_px: int | None = Field(None, ge=16, le=4096)
    view_range_m: float = Field(120.0, gt=5.0, le=2000.0)
    tile_m: float = Field(60.0, ge=10.0, le=1000.0)
    world_seed: int | None = Field(None, ge=0)
    sensor: SensorConfig = SensorConfig.exact()
    vibration: VibrationConfig | None = None

    @field_validator("type")
    @classmethod
    def _type(cls, v: str) -> str:
        if v not in OBSERVATION_TYPES:
            raise ValueError(f"must be one of {OBSERVATION_TYPES}, got {v!r}")
        return v

    @field_validator("sensor", mode="before")
    @classmethod
    def _sensor(cls, v: Any) -> Any:
        if v is None:
            return SensorConfig.exact()
        if isinstance(v, dict):  # effects not named stay off
            return {**SensorConfig.exact().model_dump(), **v}
        return v

    @classmethod
    def from_dict(
        cls, config: dict[str, Any], where: str = "omni observation"
    ) -> OmniObservationConfig:
        try:
            return cls.model_validate(dict(config))
        except ValidationError as e:
            errs = "; ".join(
                f"{'.'.join(str(p) for p in err['loc']) or '(root)'}: {err['msg']}"
                f" (got {err.get('input')!r})"
                for err in e.errors()
            )
            raise ValueError(f"{where} config: {errs}") from None

    def camera_spec(self) -> str | dict[str, Any]:
        if self.width is None and self.height is None:
            return self.camera
        spec = {"preset": self.camera} if isinstance(self.camera, str) else dict(self.camera)
        if self.width is not None:
            spec["width"] = int(self.width)
        if self.height is not None:
            spec["height"] = int(self.height)
        return spec

    def renderer_key(self) -> str:
        """What a shared :class:`OmniEnvRenderer` depends on (not type/vehicle_ids)."""
        return self.model_dump_json(exclude={"type", "vehicle_ids"})

    def to_observation_dict(self) -> dict[str, Any]:
        d = self.model_dump(exclude_defaults=True)
        d["type"] = OBSERVATION_TYPE
        return d


# --------------------------------------------------------------------------- world tiles


@dataclass
class _Tile:
    """Static geometry of one world tile: (v, f, n) road strips, (v, f, n, c) others."""

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
    """Everything static in ``area`` except the ground, as sim.scene builds it.

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
    parts = [p for p in parts if p is not None]
    if not parts:
        return None
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    out = [np.concatenate([p[0] for p in parts])]
    out.append(np.concatenate([p[1] + o for p, o in zip(parts, offsets, strict=True)]))
    out.extend(np.concatenate([p[k] for p in parts]) for k in range(2, len(parts[0])))
    return tuple(out)


def _colored_mesh(arrays: tuple[np.ndarray, ...], name: str) -> trimesh.Trimesh:
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
        self.tile_m = float(tile_m)
        self.view_range_m = float(view_range_m)
        self.cache_tiles = cache_tiles
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


# --------------------------------------------------------------------------- renderer


@dataclass
class _Observer:
    """Per-observer sensor state within an episode."""

    vibration: Vibration | None
    gain_rng: np.random.Generator
    gain_x: float | None = None
    prev_pose: CameraPose | None = None
    prev_xy: dict[int, np.ndarray] = field(default_factory=dict)
    prev_time: float | None = None


@dataclass
class _Episode:
    road_obj: object  # env.road of the episode (identity marks the episode)
    geometry: RoadGeometry
    seed_words: tuple[int, ...]
    ids: dict[int, tuple[object, int]] = field(default_factory=dict)
    next_id: int = 0
    heights: dict[int, float] = field(default_factory=dict)
    observers: dict[int, _Observer] = field(default_factory=dict)


class OmniEnvRenderer:
    """Renders what a camera on a highway-env vehicle sees, step after step.

    One per env and camera set-up (:func:`renderer_for`); the GL context opens at
    the first :meth:`render` and closes with :meth:`close`.
    """

    def __init__(self, config: OmniObservationConfig) -> None:
        self.config = config
        self.camera: CameraModel
        self.mount: CameraMount
        self.camera, self.mount = resolve_camera(config.camera_spec())
        self.shape = (self.camera.height, self.camera.width)
        self.face_px = config.face_px or default_face_px(self.camera)
        self.mask = imaged_mask(self.camera)
        self.sensor = SensorModel(**config.sensor.model_dump())
        self.vignette = (
            vignetting_gain(self.shape, self.sensor.vignetting)
            if self.sensor.vignetting > 0
            else None
        )
        self.world = TiledWorld(config.tile_m, config.view_range_m)
        self._renderer: OmniRenderer | None = None
        self._scenes: WorldScenes | None = None
        self._static_nodes: list[tuple[pyrender.Scene, pyrender.Node]] = []
        self._veh_nodes: dict[str, pyrender.Node] = {}
        self._veh_key: tuple | None = None
        self._rays: np.ndarray | None = None
        self._episode: _Episode | None = None
        self._episode_count = 0
        self._seed_rng: object = None
        self._seed_base: int | None = None
        self._seed_episode = 0
        self._cache: tuple[tuple, np.ndarray, np.ndarray | None] | None = None

    # -- life cycle ----------------------------------------------------------

    def close(self) -> None:
        """Release the GL context (idempotent; a later :meth:`render` opens a new one)."""
        if self._renderer is not None:
            self._renderer.close()
        self._renderer = None
        self._scenes = None
        self._static_nodes = []
        self._veh_nodes = {}
        self._veh_key = None
        self._cache = None
        self.world.invalidate()

    @property
    def is_open(self) -> bool:
        """Whether a GL context is held."""
        return self._renderer is not None

    def _open(self, base: AbstractEnv) -> OmniRenderer:
        if self._renderer is None:
            # the cached car-body faces show the first observer's car: only one observer
            single = len(getattr(base, "controlled_vehicles", ()) or ()) <= 1
            self._renderer = OmniRenderer(self.camera, self.face_px, cache_body_faces=single)
            self._scenes = WorldScenes([], [])
        return self._renderer

    # -- episodes --------------------------------------------------------------

    def _sync_episode(self, base: AbstractEnv) -> _Episode:
        ep = self._episode
        if ep is not None and base.road is ep.road_obj:
            return ep
        if base.road is None:
            raise RuntimeError("the env has no road yet: call reset() first")
        rng_obj = getattr(base, "_np_random", None)
        if self._seed_base is None or rng_obj is not self._seed_rng:
            seed = getattr(base, "_np_random_seed", None)  # set by reset(seed=...)
            if not isinstance(seed, int | np.integer) or seed < 0:
                seed = secrets.randbits(63)  # unseeded env: unseeded world
            self._seed_base, self._seed_episode, self._seed_rng = int(seed), 0, rng_obj
        else:
            self._seed_episode += 1
        words = (self._seed_base, self._seed_episode)
        ep = _Episode(road_obj=base.road, geometry=road_geometry(base), seed_words=words)
        for v in base.controlled_vehicles:
            self._vehicle_id(ep, v)
        fixed = self.config.world_seed
        world_words = (1, fixed) if fixed is not None else words
        self.world.reset(ep.geometry, world_words, (2, fixed if fixed is not None else 0))
        self._drop_nodes()  # the scenes (and their cached faces) are kept
        self._episode = ep
        self._episode_count += 1
        self._cache = None
        return ep

    def _drop_nodes(self) -> None:
        if self._scenes is not None:
            for scene, node in self._static_nodes:
                scene.remove_node(node)
            for mode, node in self._veh_nodes.items():
                (self._scenes.color if mode == "color" else self._scenes.ids).remove_node(node)
        self._static_nodes, self._veh_nodes, self._veh_key = [], {}, None

    def _vehicle_id(self, ep: _Episode, v: object) -> int:
        entry = ep.ids.get(id(v))
        if entry is None or entry[0] is not v:
            entry = (v, ep.next_id)  # keeps v alive: id(v) is never reused
            ep.ids[id(v)] = entry
            ep.next_id += 1
        return entry[1]

    def _height(self, ep: _Episode, vid: int, controlled: bool) -> float:
        h = ep.heights.get(vid)
        if h is None:
            if controlled:
                h = EGO_HEIGHT_M  # the mount puts the viewpoint above this roof
            else:
                u = float(np.random.default_rng([*ep.seed_words, vid, 0x0B]).uniform())
                h = HEIGHT_RANGE_M[0] + (HEIGHT_RANGE_M[1] - HEIGHT_RANGE_M[0]) * u
            ep.heights[vid] = h
        return h

    def vehicles_by_id(self, base: AbstractEnv) -> dict[int, object]:
        """Our vehicle id -> highway-env vehicle, for the vehicles on the road now."""
        ep = self._sync_episode(base)
        return {self._vehicle_id(ep, v): v for v in base.road.vehicles}

    # -- rendering -------------------------------------------------------------

    def _states(
        self, base: AbstractEnv, ep: _Episode, observer: object
    ) -> tuple[VehicleState, list[VehicleState]]:
        """World states of the observer and the vehicles near it (ids assigned to all)."""
        controlled = {id(v) for v in base.controlled_vehicles}
        ox, oy = world_from_hw_xy(np.asarray(observer.position, float))
        reach = self.config.view_range_m + 10.0
        ego_state, near = None, []
        for v in base.road.vehicles:
            vid = self._vehicle_id(ep, v)  # every vehicle, in list order: stable ids
            x, y = world_from_hw_xy(np.asarray(v.position, float))
            if v is not observer and max(abs(x - ox), abs(y - oy)) > reach:
                continue
            s = VehicleState(
                id=vid,
                x_m=float(x),
                y_m=float(y),
                yaw_rad=float(world_yaw_from_hw_heading(v.heading)),
                speed_mps=float(v.speed),
                length_m=float(v.LENGTH),
                width_m=float(v.WIDTH),
                height_m=self._height(ep, vid, id(v) in controlled),
                yaw_rate_rps=0.0,
                is_ego=v is observer,
                crashed=bool(getattr(v, "crashed", False)),
            )
            if v is observer:
                ego_state = s
            near.append(s)
        if ego_state is None:  # observer not on the road list (should not happen)
            vid = self._vehicle_id(ep, observer)
            x, y = world_from_hw_xy(np.asarray(observer.position, float))
            ego_state = VehicleState(
                vid,
                float(x),
                float(y),
                float(world_yaw_from_hw_heading(observer.heading)),
                float(observer.speed),
                float(observer.LENGTH),
                float(observer.WIDTH),
                self._height(ep, vid, True),
                0.0,
                True,
            )
            near.append(ego_state)
        return ego_state, near

    def _update_static(self, x: float, y: float) -> None:
        meshes = self.world.window_meshes(x, y)
        if meshes is None:
            return
        for scene, node in self._static_nodes:
            scene.remove_node(node)
        self._static_nodes = []
        sc = self._scenes
        for m in meshes:
            node = sc.color.add(static_pyrender_mesh(m))
            self._static_nodes.append((sc.color, node))
        occluder = id_occluder_mesh(meshes)
        if occluder is not None:
            node = sc.ids.add(pyrender.Mesh.from_trimesh(occluder, smooth=False))
            self._static_nodes.append((sc.ids, node))

    def _update_vehicles(self, key: tuple, states: list[VehicleState], want_ids: bool) -> None:
        if key != self._veh_key:
            for mode, node in self._veh_nodes.items():
                (self._scenes.color if mode == "color" else self._scenes.ids).remove_node(node)
            self._veh_nodes, self._veh_key = {}, key
        modes = ("color", "id") if want_ids else ("color",)
        for mode in modes:
            if mode in self._veh_nodes:
                continue
            mesh = vehicles_mesh(states, mode=mode)
            scene = self._scenes.color if mode == "color" else self._scenes.ids
            self._veh_nodes[mode] = scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=False))

    def _observer_state(self, ep: _Episode, vid: int) -> _Observer:
        obs = ep.observers.get(vid)
        if obs is None:
            vib_cfg = self.config.vibration
            vib = None
            if vib_cfg is not None and vib_cfg.amplitude_deg > 0:
                rng = np.random.default_rng([*ep.seed_words, 0, vid])
                vib = Vibration.seeded(vib_cfg.amplitude_deg, vib_cfg.frequency_hz, rng)
            gain_rng = np.random.default_rng([*ep.seed_words, 3, vid])
            obs = ep.observers[vid] = _Observer(vibration=vib, gain_rng=gain_rng)
        return obs

    def _gain(self, obs: _Observer) -> float:
        std = self.sensor.gain_drift
        if std <= 0:
            return 1.0
        rho = 0.97  # as sim.sensor.gain_sequence
        if obs.gain_x is None:
            obs.gain_x = float(obs.gain_rng.normal(0, std))
        obs.gain_x = rho * obs.gain_x + math.sqrt(1 - rho**2) * float(obs.gain_rng.normal(0, std))
        return 1.0 + obs.gain_x

    def render(
        self, base: AbstractEnv, observer: object | None = None, want_ids: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``(image (H, W, 3) uint8, ids (H, W) int32 or None)`` of the env's current state.

        observer: the highway-env vehicle carrying the camera (default: the ego).
        Fresh arrays every call.
        """
        observer = observer if observer is not None else base.vehicle
        ep = self._sync_episode(base)
        key = (self._episode_count, int(base.steps), float(base.time), id(observer))
        if (
            self._cache is not None
            and self._cache[0] == key
            and (self._cache[2] is not None or not want_ids)
        ):
            _, image, ids = self._cache
            return image.copy(), (ids.copy() if want_ids else None)

        renderer = self._open(base)
        ego, states = self._states(base, ep, observer)
        self._update_static(ego.x_m, ego.y_m)
        blur = self.sensor.motion_blur
        need_ids = want_ids or blur
        self._update_vehicles(key, states, need_ids)
        obs = self._observer_state(ep, ego.id)
        t_s = float(base.time)
        pose = camera_pose(
            T_world_car(ego.x_m, ego.y_m, ego.yaw_rad), self.mount, obs.vibration, t_s
        )
        atlas, _ = renderer.render_atlas(self._scenes.color, pose.T_world_actual)
        image = renderer.remap_color(atlas)
        ids = depth = None
        if need_ids:  # depth from the id scene (no depth offsets: `sim.drive.DriveRenderer`)
            id_atlas, depth = renderer.render_atlas(
                self._scenes.ids, pose.T_world_actual, flat=True, depth=blur
            )
            ids = decode_id_image(renderer.remap_nearest(id_atlas))
            ids[~self.mask] = -1
        blur_px = None
        xy_now = {s.id: np.array([s.x_m, s.y_m, 0.0]) for s in states}
        if blur and obs.prev_pose is not None and t_s > (obs.prev_time or 0.0):
            if self._rays is None:
                self._rays = self.camera.pixel_rays()
            disp = {i: obs.prev_xy[i] - p for i, p in xy_now.items() if i in obs.prev_xy}
            flow_ids = ids
            if ego.id != 0:  # scene_flow_px takes id 0 for the camera's own car: swap
                flow_ids = np.where(ids == ego.id, 0, np.where(ids == 0, ego.id, ids))
                disp = {(0 if i == ego.id else ego.id if i == 0 else i): d for i, d in disp.items()}
            dt = t_s - obs.prev_time
            # the motion from now back to the previous observation, taken as steady over
            # the exposure (centred on now: the motion to come is not known yet)
            full = scene_flow_px(
                self.camera,
                self._rays,
                renderer.range_image(depth),
                flow_ids,
                pose,
                obs.prev_pose,
                disp,
            )
            blur_px = [(-tau / dt) * full for tau in exposure_times(self.sensor.exposure_s)]
        obs.prev_pose, obs.prev_xy, obs.prev_time = pose, xy_now, t_s
        rng = np.random.default_rng([*ep.seed_words, 4, ego.id, int(base.steps)])
        image = apply_sensor(
            image,
            self.sensor,
            rng,
            gain=self._gain(obs),
            vignette=self.vignette,
            blur_px=blur_px,
            mask=self.mask,
        )
        ids_out = ids if want_ids else None
        self._cache = (key, image, ids_out)
        return image.copy(), (ids_out.copy() if ids_out is not None else None)


def renderer_for(base: AbstractEnv, config: OmniObservationConfig) -> OmniEnvRenderer:
    """The env's shared renderer for this camera set-up (created on first use)."""
    store = base.__dict__.get(_STORE_ATTR)
    if store is None:
        store = base.__dict__[_STORE_ATTR] = {}
        # backstop for envs never closed: release the GL contexts with the env
        fin = weakref.finalize(base, _close_store, store)
        fin.atexit = False  # at interpreter exit the process releases everything
    key = config.renderer_key()
    r = store.get(key)
    if r is None:
        r = store[key] = OmniEnvRenderer(config)
    return r


def _close_store(store: dict) -> None:
    for r in list(store.values()):  # kept: an env used again after close() reopens them
        r.close()


def close_renderers(env: gymnasium.Env) -> None:
    """Release every omni renderer (GL context) of ``env`` (idempotent)."""
    base = getattr(env, "unwrapped", env)
    store = base.__dict__.get(_STORE_ATTR)
    if store:
        _close_store(store)


# --------------------------------------------------------------------------- observation


def _spaces(config: OmniObservationConfig, shape: tuple[int, int]) -> spaces.Space:
    h, w = shape
    image = spaces.Box(0, 255, (h, w, 3), np.uint8)
    if not config.vehicle_ids:
        return image
    ids = spaces.Box(-1, MAX_VEHICLE_ID, (h, w), np.int32)
    return spaces.Dict({"image": image, "vehicle_ids": ids})


class OmniObservation(ObservationType):
    """highway-env observation type: the omni (or any camera) image of the observer.

    Config keys: see :class:`OmniObservationConfig`. Built by highway-env's
    ``observation_factory`` for ``type: "omnibench.OmniObservation"`` once
    :func:`register_observation_type` ran (importing this module runs it).
    """

    def __init__(self, env: AbstractEnv, **config: Any) -> None:
        super().__init__(env)
        self.config = OmniObservationConfig.from_dict(config)
        self.renderer = renderer_for(env, self.config)

    def space(self) -> spaces.Space:
        return _spaces(self.config, self.renderer.shape)

    def observe(self) -> np.ndarray | dict[str, np.ndarray]:
        if getattr(self.env, _CONSTRUCTING_ATTR, False):
            # the reset inside AbstractEnv.__init__: its observation is discarded
            return self._blank()
        image, ids = self.renderer.render(
            self.env, self.observer_vehicle, want_ids=self.config.vehicle_ids
        )
        if not self.config.vehicle_ids:
            return image
        return {"image": image, "vehicle_ids": ids}

    def _blank(self) -> np.ndarray | dict[str, np.ndarray]:
        h, w = self.renderer.shape
        image = np.zeros((h, w, 3), np.uint8)
        if not self.config.vehicle_ids:
            return image
        return {"image": image, "vehicle_ids": np.full((h, w), -1, np.int32)}

    def vehicles_by_id(self) -> dict[int, object]:
        """Vehicle id (as in the ``vehicle_ids`` image) -> highway-env vehicle."""
        return self.renderer.vehicles_by_id(self.env)

    @property
    def camera(self) -> CameraModel:
        return self.renderer.camera

    @property
    def mount(self) -> CameraMount:
        return self.renderer.mount


# --------------------------------------------------------------------------- factory hook


def _omni_observation_factory(original):  # noqa: ANN001, ANN202
    def observation_factory(env: AbstractEnv, config: dict) -> ObservationType:
        if config.get("type") in OBSERVATION_TYPES:
            return OmniObservation(env, **config)
        return original(env, config)

    observation_factory.__wrapped__ = original
    observation_factory._omnibench = True
    observation_factory.__doc__ = (
        "highway-env's observation_factory plus omnibench.OmniObservation."
    )
    return observation_factory


def _close_with_omni(original):  # noqa: ANN001, ANN202
    def close(self: AbstractEnv) -> None:
        try:
            close_renderers(self)
        finally:
            original(self)

    close.__wrapped__ = original
    close._omnibench = True
    return close


def register_observation_type() -> None:
    """Let highway-env configs name ``"omnibench.OmniObservation"`` (idempotent).

    Replaces ``observation_factory`` in every loaded highway-env module that holds
    it (``observation``, ``abstract``, ``parking_env``; other types go to the
    original) and wraps ``AbstractEnv.close`` to also release the omni renderers.
    """
    import sys

    current = hw_observation.observation_factory
    if not getattr(current, "_omnibench", False):
        patched = _omni_observation_factory(current)
        for name, mod in list(sys.modules.items()):
            if name.startswith("highway_env") and getattr(mod, "observation_factory", None) is (
                current
            ):
                mod.observation_factory = patched
    if not getattr(AbstractEnv.close, "_omnibench", False):
        AbstractEnv.close = _close_with_omni(AbstractEnv.close)


register_observation_type()


# --------------------------------------------------------------------------- wrapper


class OmniObservationWrapper(gymnasium.ObservationWrapper):
    """Replace the observation of any highway-env env by the omni camera's.

    ``OmniObservationWrapper(gymnasium.make("merge-v0"), camera="omni-far", width=96,
    height=96, vehicle_ids=True)``; other keyword arguments are
    :class:`OmniObservationConfig` keys. keep_original: return a Dict that also holds
    the env's own observation under ``"original"``.
    """

    def __init__(
        self,
        env: gymnasium.Env,
        camera: str | dict[str, Any] = "omni-near",
        width: int | None = None,
        height: int | None = None,
        vehicle_ids: bool = False,
        keep_original: bool = False,
        **options: Any,
    ) -> None:
        super().__init__(env)
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise TypeError(
                f"OmniObservationWrapper needs a highway-env env, got {type(base).__name__}"
            )
        config = OmniObservationConfig.from_dict(
            {
                "camera": camera,
                "width": width,
                "height": height,
                "vehicle_ids": vehicle_ids,
                **options,
            },
            where="OmniObservationWrapper",
        )
        self.omni = OmniObservation(base, **config.model_dump())
        self.keep_original = keep_original
        space = self.omni.space()
        if keep_original:
            parts = dict(space.spaces) if isinstance(space, spaces.Dict) else {"image": space}
            parts["original"] = env.observation_space
            space = spaces.Dict(parts)
        self.observation_space = space

    def observation(self, observation: Any) -> Any:
        obs = self.omni.observe()
        if not self.keep_original:
            return obs
        out = dict(obs) if isinstance(obs, dict) else {"image": obs}
        out["original"] = observation
        return out

    def vehicles_by_id(self) -> dict[int, object]:
        return self.omni.vehicles_by_id()

    def close(self) -> None:
        try:
            close_renderers(self.env)
        finally:
            super().close()


# --------------------------------------------------------------------------- env


class OmniHighwayEnv(HighwayEnv):
    """highway-v0 whose observation is the omni camera image (``omnibench/OmniHighway-v0``).

    Default observation: ``{"type": "omnibench.OmniObservation", "camera":
    "omni-near", "width": 128, "height": 128, "vehicle_ids": False}``. A
    ``config["observation"]`` without ``type`` (or with ours) updates it key by key;
    one with another type replaces it.
    """

    DEFAULT_OBSERVATION = {
        "type": OBSERVATION_TYPE,
        "camera": "omni-near",
        "width": 128,
        "height": 128,
        "vehicle_ids": False,
    }

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.__dict__[_CONSTRUCTING_ATTR] = True  # the reset in __init__ renders nothing
        try:
            super().__init__(config=config, render_mode=render_mode)
        finally:
            self.__dict__[_CONSTRUCTING_ATTR] = False

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config["observation"] = dict(cls.DEFAULT_OBSERVATION)
        return config

    def configure(self, config: dict) -> None:
        obs = (config or {}).get("observation")
        if isinstance(obs, dict) and obs.get("type", OBSERVATION_TYPE) in OBSERVATION_TYPES:
            current = self.config.get("observation") or {}
            if current.get("type") in OBSERVATION_TYPES:
                obs = {**current, **obs}
            config = {**config, "observation": {**obs, "type": obs.get("type", OBSERVATION_TYPE)}}
        super().configure(config)

    def close(self) -> None:
        try:
            close_renderers(self)
        finally:
            super().close()
