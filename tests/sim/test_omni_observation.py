"""sim/omni_observation.py: the observation type named in highway-env configs, the
factory patch that lets them name it, the wrapper (real renders)."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from highway_env.envs import parking_env
from highway_env.envs.common import abstract, observation
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.observation import (
    KinematicObservation,
    MultiAgentObservation,
    OccupancyGridObservation,
)

from sim.observation_config import OBSERVATION_TYPE
from sim.omni_observation import (
    OmniObservation,
    OmniObservationWrapper,
    register_observation_type,
)

# highway-env's own notice on merge-v0/roundabout-v0 ("out of date"): not ours
pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")


# --------------------------------------------------------------------------- factory patch


def test_the_factory_patch_wraps_the_original_once():
    factory = observation.observation_factory
    original = factory.__wrapped__
    assert not hasattr(original, "__wrapped__")  # one wrapper, around highway-env's own
    assert original.__module__ == "highway_env.envs.common.observation"
    # every highway-env module that calls the factory by name holds the wrapper
    assert abstract.observation_factory is factory and parking_env.observation_factory is factory
    close = AbstractEnv.close
    assert not hasattr(close.__wrapped__, "__wrapped__")
    register_observation_type()  # again: nothing changes
    assert observation.observation_factory is factory and AbstractEnv.close is close


def test_the_original_factory_still_serves_highway_envs_own_types():
    e = gymnasium.make("merge-v0")
    base = e.unwrapped
    factory = abstract.observation_factory
    try:
        assert isinstance(base.observation_type, KinematicObservation)  # merge-v0's default
        assert type(factory(base, {"type": "Kinematics"})) is KinematicObservation
        grid = factory(base, {"type": "OccupancyGrid"})
        assert type(grid) is OccupancyGridObservation
        with pytest.raises(ValueError, match="Unknown observation type"):
            factory(base, {"type": "NoSuchObservation"})
        # highway-env's nested types reach ours through the same wrapper
        multi = factory(
            base,
            {
                "type": "MultiAgentObservation",
                "observation_config": {"type": OBSERVATION_TYPE, "width": 32, "height": 32},
            },
        )
        assert type(multi) is MultiAgentObservation
        assert all(isinstance(t, OmniObservation) for t in multi.agents_observation_types)
    finally:
        e.close()


# --------------------------------------------------------------------------- renders


def test_wrapper_on_merge_env():
    e = OmniObservationWrapper(
        gymnasium.make("merge-v0"),
        camera="omni-far",
        width=64,
        height=64,
        vehicle_ids=True,
        keep_original=True,
    )
    try:
        assert set(e.observation_space.spaces) == {"image", "vehicle_ids", "original"}
        obs, _ = e.reset(seed=2)
        for _ in range(2):
            assert e.observation_space.contains(obs)
            assert obs["image"].shape == (64, 64, 3) and obs["original"].shape == (5, 5)
            seen = set(np.unique(obs["vehicle_ids"]).tolist()) - {-1}
            assert 0 in seen and seen <= set(e.vehicles_by_id())
            obs, *_ = e.step(1)
        r = e.omni.renderer
    finally:
        e.close()
    assert not r.is_open


def test_observation_type_by_name_in_another_env_config_with_sensor_effects():
    """Any highway-env config can name the type; other types still work; the sensor
    effects and vibration run."""
    cfg = {
        "type": OBSERVATION_TYPE,
        "camera": {"preset": "omni-near", "width": 64, "height": 64},
        "sensor": {"noise_std": 2.0, "motion_blur": True, "gain_drift": 0.03, "jpeg_quality": 90},
        # small: llvmpipe's anisotropic filtering is pathologically slow (seconds per
        # face) for cameras tilted by ~0.2-15 deg (measured on Mesa 22.3)
        "vibration": {"amplitude_deg": 0.05, "frequency_hz": 2.0},
    }
    e = gymnasium.make("roundabout-v0", config={"observation": cfg})
    try:
        assert isinstance(e.unwrapped.observation_type, OmniObservation)
        obs, _ = e.reset(seed=0)
        obs2, *_ = e.step(1)
        assert e.observation_space.contains(obs2) and obs2.shape == (64, 64, 3)
        assert not np.array_equal(obs, obs2)
    finally:
        e.close()
    k = gymnasium.make("roundabout-v0", config={"observation": {"type": "Kinematics"}})
    assert k.reset(seed=0)[0].shape == (5, 5)
    k.close()


def test_motion_blur_blurs_the_frames_after_the_first():
    """With the sensor's motion blur (a long exposure here), the frame after a step differs
    from the same frame without it; the first frame (no motion before it) hardly does (the
    depth pass that the blur needs moves a few pixels)."""
    frames = {}
    for blur in (True, False):
        sensor = {"noise_std": 0, "motion_blur": blur, "exposure_s": 0.05, "gain_drift": 0}
        sensor.update(jpeg_quality=None, vignetting=0)
        cfg = {"type": OBSERVATION_TYPE, "sensor": sensor, "vibration": None}
        cfg["camera"] = {"preset": "omni-near", "width": 64, "height": 64}
        e = gymnasium.make("highway-v0", config={"observation": cfg})
        try:
            first, _ = e.reset(seed=0)
            second, *_ = e.step(1)
        finally:
            e.close()
        frames[blur] = first.astype(float), second.astype(float)
    change = [np.abs(b - s).mean() for b, s in zip(frames[True], frames[False], strict=True)]
    assert change[0] < 0.1 and change[1] > 0.3, change  # [DN] (measured 0.02 and 1.34)


def test_shadows_darken_only_the_road():
    """``shadows: true``: the same frame with the road darker near the vehicles, nothing
    brighter."""
    frames = {}
    for shadows in (False, True):
        cfg = {"type": OBSERVATION_TYPE, "shadows": shadows, "vibration": None}
        cfg["camera"] = {"preset": "omni-near", "width": 96, "height": 96}
        env_config = {"observation": cfg, "vehicles_density": 3}
        e = gymnasium.make("highway-v0", config=env_config)
        try:
            frames[shadows] = e.reset(seed=0)[0].astype(int)
        finally:
            e.close()
    changed = np.any(frames[True] != frames[False], axis=2)
    assert 0 < changed.sum() < 0.1 * changed.size
    assert np.all(frames[True][changed] <= frames[False][changed])
