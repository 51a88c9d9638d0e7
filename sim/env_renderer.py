"""What a camera on a highway-env vehicle sees, rendered step after step.

:class:`OmniEnvRenderer` renders the env's current state for an observer vehicle:

- the static world from :class:`sim.tiles.TiledWorld` (the road geometry is sampled
  once per episode, ``sim.highway.road_geometry``: world = (x_hw, -y_hw),
  yaw = -heading);
- the vehicles (``env.road.vehicles`` within ``view_range_m``) re-posed every step as
  one merged mesh (``sim.scene.vehicles_mesh``);
- the camera on the observer by the camera's mount (``sim.camera_motion.camera_pose``),
  optionally vibrating;
- ``sim.frame_renderer.PlaneFrameRenderer`` draws the road plane per pixel and what
  stands on it through cube faces, as for a rendered drive (`sim.drive`);
- sensor effects (``sim.sensor``) after it. Motion blur uses the motion since the
  previous observation (the next one is not known online).

Vehicle ids are stable within an episode: the controlled vehicles are 0, 1, ... (the
ego is 0), the other vehicles follow in order of first appearance, as in
:mod:`sim.highway`.

Seeds. The seed of an episode is (seed passed to the last ``reset(seed=...)``,
episodes since then). The roadside of the tiles derives from it, or from
``world_seed`` when given (then the tiles are reused across episodes on the same
road); the asphalt and grass textures from ``world_seed`` (0 when not given: the
same in every episode, ~0.1 s saved per reset). Vehicle heights, vibration phases,
sensor noise and gain derive from the episode seed; nothing draws from the env's
``np_random``, so the traffic is exactly that of the plain env.

Render state (GL context, scenes, tiles) is kept per env and per camera set-up
(:func:`renderer_for`), shared by every observation object with that set-up
(highway-env rebuilds its observation objects at every reset), created at the first
render and released by :func:`close_renderers`.
"""

from __future__ import annotations

import math
import os
import secrets
import weakref
from dataclasses import dataclass, field

import gymnasium
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv

from estimator.camera.files import resolve_camera
from estimator.camera.models import CameraModel, vignetting_gain
from estimator.camera.mount import CameraMount
from sim.camera_motion import CameraPose, T_world_car, Vibration, camera_pose
from sim.drive import scene_flow_px
from sim.frame_renderer import PlaneFrameRenderer, imaged_mask, object_face_px
from sim.highway import (
    EGO_HEIGHT_M,
    HEIGHT_RANGE_M,
    RoadGeometry,
    VehicleState,
    road_geometry,
    world_from_hw_xy,
    world_yaw_from_hw_heading,
)
from sim.observation_config import OmniObservationConfig
from sim.sensor import SensorModel, apply_sensor, exposure_times
from sim.tiles import TiledWorld

# highway-env's "human" render mode opens a pygame window. Without a display SDL falls
# back to its "offscreen" video driver, which sets up its own GL (EGL) and leaves the
# OSMesa context of our renderer broken (GLError at the next call). With no display
# there is no window to show anyway: SDL's "dummy" driver (highway-env then skips
# its viewer).
if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

__all__ = ["OmniEnvRenderer", "close_renderers", "renderer_for"]

_STORE_ATTR = "_omnibench_renderers"  # env attribute: {set-up key: OmniEnvRenderer}


@dataclass
class _Observer:
    """Per-observer sensor state within an episode."""

    vibration: Vibration | None
    gain_rng: np.random.Generator
    gain_x: float | None = None  # [-] gain drift state (gain = 1 + gain_x)
    prev_pose: CameraPose | None = None
    prev_xy: dict[int, np.ndarray] = field(default_factory=dict)  # id -> (3,) [m, world]
    prev_time: float | None = None  # [s] env time of the previous observation


@dataclass
class _Episode:
    road_obj: object  # env.road of the episode (identity marks the episode)
    geometry: RoadGeometry
    seed_words: tuple[int, ...]
    ids: dict[int, tuple[object, int]] = field(default_factory=dict)  # id(v) -> (v, our id)
    next_id: int = 0
    heights: dict[int, float] = field(default_factory=dict)  # our id -> [m]
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
        self.shape = (self.camera.height, self.camera.width)  # (H, W) [px]
        self.face_px = config.face_px or object_face_px(self.camera)  # [px]
        self.mask = imaged_mask(self.camera)  # (H, W) bool: pixels with an image
        self.sensor = SensorModel(**config.sensor.model_dump())
        self.vignette = (
            vignetting_gain(self.shape, self.sensor.vignetting).astype(np.float32)
            if self.sensor.vignetting > 0
            else None
        )
        self.world = TiledWorld(config.tile_m, config.view_range_m)
        self._renderer: PlaneFrameRenderer | None = None
        self._rays: np.ndarray | None = None
        self._episode: _Episode | None = None
        self._episode_count = 0
        self._static_episode: int | None = None  # episode of the static world drawn last
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
        self._cache = None
        self.world.invalidate()

    @property
    def is_open(self) -> bool:
        """Whether a GL context is held."""
        return self._renderer is not None

    def _open(self, base: AbstractEnv) -> PlaneFrameRenderer:
        if self._renderer is None:
            # the car body drawn once shows the first observer's car: only one observer
            single = len(getattr(base, "controlled_vehicles", ()) or ()) <= 1
            T_ref = camera_pose(T_world_car(0.0, 0.0, 0.0), self.mount, None, 0.0)
            self._renderer = PlaneFrameRenderer(
                self.camera,
                T_ref.T_world_nominal,
                self.face_px,
                cache_body=single,
                shadows=self.config.shadows,
            )
            self.world.invalidate()  # the new renderer needs the window's meshes
            self._static_episode = None
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
        self._episode = ep
        self._episode_count += 1
        self._cache = None
        return ep

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
        reach = self.config.view_range_m + 10.0  # [m] vehicles farther in x or y are not drawn
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
        if meshes is not None:
            # another window of the same episode's road keeps the coverage tiles built
            same = self._static_episode == self._episode_count
            self._renderer.set_static(meshes, self.world.window_area(), same_world=same)
            self._static_episode = self._episode_count

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
        obs = self._observer_state(ep, ego.id)
        t_s = float(base.time)
        pose = camera_pose(
            T_world_car(ego.x_m, ego.y_m, ego.yaw_rad), self.mount, obs.vibration, t_s
        )
        seen = renderer.render(states, pose.T_world_actual)
        image, ids = seen.image, seen.ids
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
                seen.range_m,
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
