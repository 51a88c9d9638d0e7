"""The gymnasium env ``omnibench/OmniHighway-v0``: highway-v0 seen by an omni camera.

Three ways to omni observations, one renderer behind them
(:class:`sim.env_renderer.OmniEnvRenderer`):

- **registered env**: ``omnibench/OmniHighway-v0`` (registered by ``import sim``,
  loaded lazily from here): :class:`OmniHighwayEnv`, highway-v0 whose default
  observation is the omni one, 128 x 128 omni-near; a partial ``config["observation"]``
  (no ``type``) updates those defaults.
- **observation type by name** in any highway-env env: ``config={"observation":
  {"type": "omnibench.OmniObservation", "camera": "omni-near", ...}}``
  (:mod:`sim.omni_observation`). Loading: ``import sim.gym_env`` (or
  ``sim.omni_observation``), or the ``"sim.gym_env:merge-v0"`` form of
  ``gymnasium.make``, which imports it first (use it in spawned vector-env workers).
- **wrapper**: :class:`sim.omni_observation.OmniObservationWrapper` on any
  highway-env env.

The observation, its ids and seeds: :mod:`sim.omni_observation` and
:mod:`sim.env_renderer`. ``reset(seed=s)`` twice gives identical observations;
``env.close()`` releases the GL contexts. The names of those modules that users
import are re-exported here.
"""

from __future__ import annotations

from highway_env.envs.common.action import action_factory
from highway_env.envs.highway_env import HighwayEnv

from sim.env_renderer import OmniEnvRenderer, close_renderers
from sim.observation_config import OBSERVATION_TYPE, OBSERVATION_TYPES, OmniObservationConfig
from sim.omni_observation import (
    SKIP_RENDER_ATTR,
    OmniObservation,
    OmniObservationWrapper,
    register_observation_type,
)
from sim.tiles import TiledWorld

__all__ = [
    "ENV_ID",
    "OBSERVATION_TYPE",
    "OmniEnvRenderer",
    "OmniHighwayEnv",
    "OmniObservation",
    "OmniObservationConfig",
    "OmniObservationWrapper",
    "TiledWorld",
    "close_renderers",
    "register_observation_type",
]

ENV_ID = "omnibench/OmniHighway-v0"


class OmniHighwayEnv(HighwayEnv):
    """highway-v0 whose observation is the omni camera image (``omnibench/OmniHighway-v0``).

    Default observation: ``{"type": "omnibench.OmniObservation", "camera":
    "omni-near", "width": 128, "height": 128, "vehicle_ids": False}``. A
    ``config["observation"]`` without ``type`` (or with ours) updates it key by key;
    one with another type replaces it. The omni type is built by :meth:`define_spaces`,
    without highway-env's observation factory.
    """

    DEFAULT_OBSERVATION = {
        "type": OBSERVATION_TYPE,
        "camera": "omni-near",
        "width": 128,  # [px]
        "height": 128,  # [px]
        "vehicle_ids": False,
    }

    def __init__(self, config: dict | None = None, render_mode: str | None = None) -> None:
        self.__dict__[SKIP_RENDER_ATTR] = True  # the reset in __init__ renders nothing
        try:
            super().__init__(config=config, render_mode=render_mode)
        finally:
            self.__dict__[SKIP_RENDER_ATTR] = False

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

    def define_spaces(self) -> None:
        """``AbstractEnv.define_spaces`` with the omni type built here (other types: as there).

        Overriding this method is highway-env's hook for an env's own observation;
        ``observation_factory``, which it calls, knows only highway-env's names.
        """
        obs_config = self.config["observation"]
        if obs_config.get("type") not in OBSERVATION_TYPES:
            super().define_spaces()
            return
        self.observation_type = OmniObservation(self, **obs_config)
        self.action_type = action_factory(self, self.config["action"])
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    def close(self) -> None:
        try:
            close_renderers(self)
        finally:
            super().close()
