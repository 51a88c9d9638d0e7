"""sim/traffic.py on the real highway-env roundabout (no mocks)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.highway import HighwayBridge, simulate
from sim.scenario import Scenario, ScenarioError, TrafficConfig, scenario_from_dict
from sim.traffic import entries_and_exits

FPS = 15.0


def test_the_roundabouts_entries_and_exits_are_its_four_access_roads():
    b = HighwayBridge("roundabout-v0", {}, 0, FPS)
    try:
        entries, exits = entries_and_exits(b.env.unwrapped.road.network)
    finally:
        b.close()
    assert sorted(e[0] for e in entries) == ["eer", "ner", "ser", "wer"]
    assert exits == ["exr", "nxr", "sxr", "wxr"]


def test_added_traffic_enters_spreads_and_is_the_same_for_the_same_seed():
    traffic = TrafficConfig(initial=8, per_min=60.0)
    a = simulate("roundabout-v0", {}, 3, FPS, 4.0, traffic=traffic)
    b = simulate("roundabout-v0", {}, 3, FPS, 4.0, traffic=traffic)
    plain = simulate("roundabout-v0", {}, 3, FPS, 4.0)
    n_plain = len(plain[0].others)
    # the 8 placed at the start (each where no other vehicle is within 12 m)
    assert len(a[0].others) == n_plain + 8
    xy = np.array([(v.x_m, v.y_m) for v in a[0].vehicles])
    gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) + 1e3 * np.eye(len(xy))
    assert gaps.min() > 5.0
    # about one a second arrives later (Poisson: 4 s at 1/s, at least one)
    assert max(v.id for f in a for v in f.others) > n_plain + 8
    for fa, fb in zip(a, b, strict=True):
        assert [(v.id, v.x_m, v.y_m) for v in fa.others] == [
            (v.id, v.x_m, v.y_m) for v in fb.others
        ]


def test_added_vehicles_leave_past_their_exit():
    b = HighwayBridge("roundabout-v0", {}, 1, FPS, traffic=TrafficConfig(initial=6))
    try:
        src = b._traffic
        first = list(src.added)
        assert len(first) == 6
        for _ in range(int(40 * FPS)):  # 40 s: every vehicle has driven ~500 m
            b.step()
        left = [v for v in first if v not in b.env.unwrapped.road.vehicles]
    finally:
        b.close()
    gone = [v for v in left if v not in src.added]
    assert gone and len(gone) == len(left)


def test_traffic_settings_are_checked():
    with pytest.raises(ValueError, match="initial"):
        TrafficConfig(initial=-1)
    with pytest.raises(ScenarioError, match="traffic.per_min"):
        scenario_from_dict({"name": "x", "traffic": {"per_min": -3}})
    # no added traffic is left out of a scenario's data (render caches keep their keys)
    assert "traffic" not in Scenario(name="x").to_dict()
    assert Scenario(name="x", traffic={"initial": 3}).to_dict()["traffic"]["initial"] == 3
