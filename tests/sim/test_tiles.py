"""sim/tiles.py: the tiled static world."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

from sim.highway import road_geometry
from sim.tiles import TiledWorld

# highway-env's own notice on merge-v0 ("out of date"): not ours
pytestmark = pytest.mark.filterwarnings("ignore:.*is out of date:DeprecationWarning")


def test_tiled_world_is_deterministic_and_rebuilt_only_when_the_window_moves():
    e = gymnasium.make("merge-v0")
    e.reset(seed=0)
    road = road_geometry(e)
    e.close()
    world = TiledWorld(tile_m=50.0, view_range_m=60.0)
    world.reset(road, (7, 0))
    first = world.window_meshes(100.0, -5.0)
    assert [m.metadata["name"] for m in first] == ["road", "markings", "ground", "roadside"]
    assert world.window_meshes(105.0, -6.0) is None  # same tiles
    moved = world.window_meshes(200.0, -5.0)
    assert moved is not None and world.builds == 2
    again = TiledWorld(tile_m=50.0, view_range_m=60.0)
    again.reset(road, (7, 0))
    for a, b in zip(first, again.window_meshes(100.0, -5.0), strict=True):
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
