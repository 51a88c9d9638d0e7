"""The omni observation for any highway-env env: an observation type and a wrapper.

- **observation type**: :class:`OmniObservation`, named in a config as ``{"type":
  "omnibench.OmniObservation", "camera": "omni-near", "width": 128, "height": 128,
  "vehicle_ids": True}`` (keys: :class:`sim.observation_config.OmniObservationConfig`).
  Importing this module runs :func:`register_observation_type`, which teaches
  highway-env's observation factory that name (the one patch of highway-env; its
  docstring says why no hook exists).
- **wrapper**: :class:`OmniObservationWrapper` ``(env, camera=..., width=..., ...)``
  replaces the observation of any highway-env env, wrapped or not; no factory involved.

Observation: ``Box(0, 255, (H, W, 3), uint8)`` RGB, or with ``vehicle_ids=True`` a
``Dict`` with ``"image"`` and ``"vehicle_ids"`` ``Box(-1, 2**24 - 2, (H, W), int32)``:
the id of the vehicle seen by each pixel, -1 for none. Ids are stable within an
episode: the controlled vehicles are 0, 1, ... (the ego is 0, its body fills the masked
disc at the centre of an omni image), the other vehicles follow in order of first
appearance. :meth:`OmniObservation.vehicles_by_id` maps them back to highway-env
vehicles. Pixels without an image (outside the mirror's circle) are black and -1. The
images come from :class:`sim.env_renderer.OmniEnvRenderer`, one per env and camera
set-up; ``env.close()`` releases its GL context.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import gymnasium
import highway_env  # noqa: F401  (registers the highway-env ids, imports all its modules)
import numpy as np
from gymnasium import spaces
from highway_env.envs.common import observation as hw_observation
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.observation import ObservationType

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from sim.env_renderer import close_renderers, renderer_for
from sim.observation_config import OBSERVATION_TYPES, OmniObservationConfig

__all__ = [
    "MAX_VEHICLE_ID",
    "OmniObservation",
    "OmniObservationWrapper",
    "SKIP_RENDER_ATTR",
    "register_observation_type",
]

#: Largest vehicle id an id image can carry (24-bit colour, id + 1).
MAX_VEHICLE_ID = (1 << 24) - 2
#: An env attribute: while True, :meth:`OmniObservation.observe` renders nothing and
#: returns a blank observation (set by ``sim.gym_env.OmniHighwayEnv`` over the reset
#: inside highway-env's constructor, whose observation is discarded).
SKIP_RENDER_ATTR = "_omnibench_constructing"


def _observation_space(config: OmniObservationConfig, shape: tuple[int, int]) -> spaces.Space:
    """The space of the observation for ``config`` and image ``shape`` (H, W) [px]."""
    h, w = shape
    image = spaces.Box(0, 255, (h, w, 3), np.uint8)
    if not config.vehicle_ids:
        return image
    ids = spaces.Box(-1, MAX_VEHICLE_ID, (h, w), np.int32)
    return spaces.Dict({"image": image, "vehicle_ids": ids})


class OmniObservation(ObservationType):
    """highway-env observation type: the omni (or any camera) image of the observer.

    Config keys: see :class:`OmniObservationConfig`. Built by highway-env's
    ``observation_factory`` for ``type: "omnibench.OmniObservation"``, or directly.
    """

    def __init__(self, env: AbstractEnv, **config: Any) -> None:
        super().__init__(env)
        self.config = OmniObservationConfig.from_dict(config)
        self.renderer = renderer_for(env, self.config)

    def space(self) -> spaces.Space:
        return _observation_space(self.config, self.renderer.shape)

    def observe(self) -> np.ndarray | dict[str, np.ndarray]:
        """(H, W, 3) uint8, or {"image": (H, W, 3) uint8, "vehicle_ids": (H, W) int32}."""
        if getattr(self.env, SKIP_RENDER_ATTR, False):
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


# --------------------------------------------------------------------------- factory patch

_PATCH_MARK = "_omnibench"  # attribute set on the wrappers installed below


def register_observation_type() -> None:
    """Let any highway-env config name ``"omnibench.OmniObservation"`` (idempotent).

    Why a patch: highway-env 1.12.1 builds observations in
    ``observation_factory(env, config)``, a closed ``if/elif`` over its own type names
    (no registry; no class or import path accepted as ``type``), and its callers bind
    that function by name at import: ``AbstractEnv.define_spaces`` (abstract.py, every
    env), ``MultiAgentObservation`` and ``TupleObservation`` (observation.py, nested
    configs), ``ParkingEnv.define_spaces`` (parking_env.py). An env class of our own
    needs none of it (``sim.gym_env.OmniHighwayEnv`` overrides ``define_spaces``), but
    the highway-env ids (``merge-v0``, ...) have no other way in. ``AbstractEnv.close``
    has no hook either for what an observation type holds.

    What it does, once: binds, in each highway-env module holding the original
    factory, a wrapper that builds :class:`OmniObservation` for our names and calls the
    original for every other name (the original stays ``wrapper.__wrapped__``); wraps
    ``AbstractEnv.close`` to release the omni renderers' GL contexts before the
    original close. Runs at import of this module.
    """
    original = hw_observation.observation_factory
    if not getattr(original, _PATCH_MARK, False):
        factory = _wrap(original, _omni_or_original(original))
        for name, module in list(sys.modules.items()):
            if name.startswith("highway_env") and (
                getattr(module, "observation_factory", None) is original
            ):
                module.observation_factory = factory
    if not getattr(AbstractEnv.close, _PATCH_MARK, False):
        AbstractEnv.close = _wrap(AbstractEnv.close, _closing_renderers(AbstractEnv.close))


def _omni_or_original(original: Callable) -> Callable:
    def observation_factory(env: AbstractEnv, config: dict) -> ObservationType:
        """highway-env's observation_factory plus ``omnibench.OmniObservation``."""
        if config.get("type") in OBSERVATION_TYPES:
            return OmniObservation(env, **config)
        return original(env, config)

    return observation_factory


def _closing_renderers(original: Callable) -> Callable:
    def close(self: AbstractEnv) -> None:
        """highway-env's close, after releasing the env's omni renderers."""
        try:
            close_renderers(self)
        finally:
            original(self)

    return close


def _wrap(original: Callable, wrapper: Callable) -> Callable:
    wrapper.__wrapped__ = original
    setattr(wrapper, _PATCH_MARK, True)
    return wrapper


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
