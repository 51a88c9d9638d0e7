"""sim/gym_env.py: the gymnasium ids, OmniHighwayEnv and its observations (real renders)."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env

import sim
from sim.camera_motion import T_world_car, camera_pose
from sim.gym_env import ENV_ID, OmniHighwayEnv
from sim.highway import (
    HEIGHT_RANGE_M,
    VehicleState,
    world_from_hw_xy,
    world_yaw_from_hw_heading,
)
from sim.observation_config import OBSERVATION_TYPE
from sim.omni_observation import OmniObservation
from sim.scene import vehicle_corners_world

# highway-env's own notice on merge-v0/roundabout-v0 ("out of date"): not ours
pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")

REPO = Path(__file__).resolve().parents[2]
# small and quick: 96 px, 5 decisions/s (3 sim steps each), 15 cars, 80 m of world
OBS = {"width": 96, "height": 96, "vehicle_ids": True, "view_range_m": 80.0}
CONFIG = {"vehicles_count": 15, "lanes_count": 3, "policy_frequency": 5, "observation": OBS}


def _run(code: str) -> str:
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        env={**__import__("os").environ, "PYOPENGL_PLATFORM": "osmesa"},
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout.strip().splitlines()[-1]


def _renderer(env: gymnasium.Env):
    return env.unwrapped.observation_type.renderer


@pytest.fixture(scope="module")
def env():
    e = gymnasium.make(ENV_ID, config=CONFIG)
    yield e
    e.close()


# --------------------------------------------------------------------------- ids


def test_import_sim_registers_the_id_and_stays_light():
    got = json.loads(
        _run(
            "import json, sys, gymnasium, sim\n"
            "heavy = ['pyrender', 'OpenGL', 'highway_env', 'trimesh', 'sim.gym_env']\n"
            "print(json.dumps([gymnasium.spec('omnibench/OmniHighway-v0').entry_point,"
            " [m for m in heavy if m in sys.modules]]))"
        )
    )
    assert got == ["sim.gym_env:OmniHighwayEnv", []]


def test_make_by_module_prefixed_id_in_a_fresh_interpreter():
    """``sim:omnibench/OmniHighway-v0`` with nothing imported; then the documented
    ``sim.gym_env:merge-v0`` form that loads the observation type for a plain id."""
    got = json.loads(
        _run(
            "import json, sys, gymnasium\n"
            "assert 'sim' not in sys.modules\n"
            "env = gymnasium.make('sim:omnibench/OmniHighway-v0',"
            " config={'vehicles_count': 5, 'observation': {'width': 64, 'height': 48}})\n"
            "obs, _ = env.reset(seed=0)\n"
            "ok = bool(env.observation_space.contains(obs))\n"
            "env.close()\n"
            "m = gymnasium.make('sim.gym_env:merge-v0', config={'observation':"
            " {'type': 'omnibench.OmniObservation', 'width': 32, 'height': 32}})\n"
            "shape_m = list(m.reset(seed=0)[0].shape)\n"
            "m.close()\n"
            "print(json.dumps([list(obs.shape), str(obs.dtype), ok, int(obs.max()), shape_m]))"
        )
    )
    shape, dtype, ok, vmax, shape_m = got
    assert shape == [48, 64, 3] and dtype == "uint8" and ok and vmax > 0
    assert shape_m == [32, 32, 3]


def test_make_after_import_sim_has_the_default_omni_observation():
    assert "omnibench/OmniHighway-v0" in sim.GYM_ENV_IDS
    e = gymnasium.make(ENV_ID)
    try:
        assert isinstance(e.unwrapped, OmniHighwayEnv)
        assert isinstance(e.unwrapped.observation_type, OmniObservation)
        assert e.observation_space == spaces.Box(0, 255, (128, 128, 3), np.uint8)
        # the reset inside highway-env's constructor renders nothing (no GL context yet)
        assert not _renderer(e).is_open
    finally:
        e.close()


def test_partial_observation_config_updates_the_defaults():
    e = gymnasium.make(ENV_ID, config={"observation": {"width": 64, "camera": "omni-far"}})
    try:
        assert e.observation_space.shape == (128, 64, 3)
        assert e.unwrapped.config["observation"]["type"] == OBSERVATION_TYPE
        assert _renderer(e).camera.max_elevation_deg == 15.0  # omni-far
    finally:
        e.close()


def test_the_env_builds_its_observation_without_the_factory_patch(monkeypatch):
    """OmniHighwayEnv.define_spaces builds the omni type itself: with highway-env's own
    factory back in place, the env still has it, while merge-v0 cannot name it."""
    from highway_env.envs.common import abstract

    monkeypatch.setattr(abstract, "observation_factory", abstract.observation_factory.__wrapped__)
    e = gymnasium.make(ENV_ID, config={"observation": {"width": 48}})
    try:
        assert isinstance(e.unwrapped.observation_type, OmniObservation)
        assert e.observation_space.shape == (128, 48, 3)
    finally:
        e.close()
    with pytest.raises(ValueError, match="Unknown observation type"):
        gymnasium.make("merge-v0", config={"observation": {"type": OBSERVATION_TYPE}})


def test_bad_config_names_the_key():
    with pytest.raises(ValueError, match="widht"):
        gymnasium.make(ENV_ID, config={"observation": {"widht": 64}})


# --------------------------------------------------------------------------- observations


def test_observation_shape_dtype_and_space(env):
    space = env.observation_space
    assert isinstance(space, spaces.Dict)
    assert space["image"] == spaces.Box(0, 255, (96, 96, 3), np.uint8)
    assert space["vehicle_ids"].dtype == np.int32 and space["vehicle_ids"].shape == (96, 96)
    obs, _ = env.reset(seed=1)
    for _ in range(3):
        assert space.contains(obs)
        img, ids = obs["image"], obs["vehicle_ids"]
        assert img.dtype == np.uint8 and img.shape == (96, 96, 3)
        assert ids.dtype == np.int32 and ids.shape == (96, 96)
        # black outside the mirror's circle, a picture inside
        assert img[0, 0].max() == 0 and ids[0, 0] == -1
        assert img[48, 90].max() > 0 or img[90, 48].max() > 0
        assert ids[48, 48] == 0  # the ego's roof in the centre
        obs, *_ = env.step(1)


def test_check_env_passes():
    e = gymnasium.make(ENV_ID, config=CONFIG)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(e.unwrapped)
        msgs = [str(w.message) for w in caught if "WARN" in str(w.message)]
        assert not msgs, msgs
    finally:
        e.close()


def test_reset_with_a_seed_reproduces_the_frames(env):
    def episode(seed):
        obs, _ = env.reset(seed=seed)
        frames = [obs]
        for a in (1, 3, 1):
            obs, *_ = env.step(a)
            frames.append(obs)
        return frames

    a, b, c = episode(11), episode(11), episode(12)
    for fa, fb in zip(a, b, strict=True):
        assert np.array_equal(fa["image"], fb["image"])
        assert np.array_equal(fa["vehicle_ids"], fb["vehicle_ids"])
    assert not all(np.array_equal(fa["image"], fc["image"]) for fa, fc in zip(a, c, strict=True))
    # successive observations are fresh arrays (check_env: data not reused)
    assert not np.shares_memory(a[1]["image"], a[2]["image"])


def test_vehicle_ids_are_the_vehicles_in_view(env):
    """Every id in the id image is a vehicle on the road, and its pixels lie inside
    the camera-model projection of its box (the tallest box a car may have), within
    1.5 px; the ego's roof is id 0."""
    base = env.unwrapped
    obs_type = base.observation_type
    cam, mount = obs_type.camera, obs_type.mount
    obs, _ = env.reset(seed=4)
    checked = 0
    for _ in range(4):
        ids = obs["vehicle_ids"]
        by_id = obs_type.vehicles_by_id()
        assert by_id[0] is base.vehicle
        ex, ey = world_from_hw_xy(np.asarray(base.vehicle.position, float))
        eyaw = float(world_yaw_from_hw_heading(base.vehicle.heading))
        pose = camera_pose(T_world_car(ex, ey, eyaw), mount, None, 0.0)
        T_cw = np.linalg.inv(pose.T_world_actual)
        for vid in np.unique(ids[ids > 0]):
            v = by_id[int(vid)]
            assert v in base.road.vehicles
            x, y = world_from_hw_xy(np.asarray(v.position, float))
            yaw = float(world_yaw_from_hw_heading(v.heading))
            box = VehicleState(
                int(vid), x, y, yaw, 0.0, v.LENGTH, v.WIDTH, HEIGHT_RANGE_M[1], 0.0, False
            )
            P = vehicle_corners_world(box) @ T_cw[:3, :3].T + T_cw[:3, 3]
            w = cam.project(P)
            vv, uu = np.nonzero(ids == vid)
            if len(uu) < 4 or not np.all(np.isfinite(w)):
                continue
            assert uu.min() >= w[:, 0].min() - 1.5 and uu.max() <= w[:, 0].max() + 1.5
            assert vv.min() >= w[:, 1].min() - 1.5 and vv.max() <= w[:, 1].max() + 1.5
            checked += 1
        obs, *_ = env.step(1)
    assert checked >= 2, "too few vehicles in view: pick another seed"


def test_close_releases_the_gl_context_and_may_be_repeated():
    e = gymnasium.make(ENV_ID, config={"vehicles_count": 5, "observation": {"width": 48}})
    e.reset(seed=0)
    r = _renderer(e)
    assert r.is_open
    e.close()
    assert not r.is_open
    e.close()
