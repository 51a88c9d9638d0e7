"""The world side of omnibench: highway-env traffic rendered into omni-camera images.

Importing ``sim`` registers the gymnasium id ``omnibench/OmniHighway-v0`` (gymnasium
1.x has no plugin entry points: an id exists once the module registering it was
imported). The registration names its entry point as a string, so ``import sim``
stays light: pyrender, highway-env and the renderer load with the first
``gymnasium.make``. ``gymnasium.make("sim:omnibench/OmniHighway-v0")`` imports this
package first and so works in a fresh interpreter. See :mod:`sim.gym_env`.
"""

from __future__ import annotations

GYM_ENV_IDS = {"omnibench/OmniHighway-v0": "sim.gym_env:OmniHighwayEnv"}


def _register_gym_envs() -> None:
    try:
        import gymnasium
    except ImportError:  # the estimator side may run without the world side installed
        return
    for env_id, entry_point in GYM_ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point)


_register_gym_envs()
