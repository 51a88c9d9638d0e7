"""Traffic added to a highway-env road: vehicles that enter where the road begins.

Some highway-env environments bring only a handful of vehicles (roundabout-v0: four)
and have no setting for more. A scenario's `sim.scenario.TrafficConfig` adds vehicles
(`sim.highway.HighwayBridge` drives them as it drives the ego: IDM + MOBIL and a yield at
predicted crossing conflicts, since roundabout-v0 has no right-of-way rule): ``initial``
of them spread over the entry roads at the start, then ``per_min`` a minute entering at
the start of an entry road (Poisson arrivals). An entry road is a lane of the road
network that no lane leads into; each vehicle is routed to a random exit (a node that no
lane leaves) reachable from it, and is removed once past the end of its exit road. A
vehicle is placed only where no other is within ``CLEARANCE_M`` (an arrival waits for the
next frame).
Everything is drawn from the generator the bridge seeds with the drive's seed.
"""

from __future__ import annotations

import numpy as np

from sim.scenario import TrafficConfig

CLEARANCE_M = 12.0  # [m] nearest other vehicle where one is placed, 5..30
SPEED_RANGE = (0.6, 0.9)  # [-] a placed vehicle's speed, as a fraction of the lane's limit


def entries_and_exits(network: object) -> tuple[list[tuple], list[str]]:
    """The lanes (from, to, i) that no lane leads into, and the nodes no lane leaves."""
    graph = network.graph
    entered = {to for frm in graph for to in graph[frm]}
    entries = [
        (frm, to, i)
        for frm in graph
        if frm not in entered
        for to in graph[frm]
        for i in range(len(graph[frm][to]))
    ]
    exits = sorted(to for to in entered if to not in graph)
    return entries, exits


class TrafficSource:
    """Places a `TrafficConfig`'s vehicles on a highway-env env's road: vehicle_type's
    (a highway-env vehicle class with a ``sim_dt_s``, the integration step [s])."""

    def __init__(
        self,
        traffic: TrafficConfig,
        env: object,
        rng: np.random.Generator,
        vehicle_type: type,
        sim_dt_s: float,
    ) -> None:
        base = env.unwrapped
        self.traffic, self.road, self.rng = traffic, base.road, rng
        self.vehicle_type = vehicle_type
        network = self.road.network
        entries, exits = entries_and_exits(network)
        self.routes: list[tuple[tuple, list[str]]] = []
        for lane in entries:
            reach = [x for x in exits if x == lane[1] or network.shortest_path(lane[1], x)]
            if reach:
                self.routes.append((lane, reach))
        if traffic.active and not self.routes:
            raise ValueError(
                f"{base.spec.id if base.spec else type(base).__name__}: its road has no "
                "entry lane that leads to an exit, so no traffic can be added"
            )
        self.exits = set(exits)
        self.sim_dt_s = sim_dt_s
        self.added: list[object] = []

    def populate(self) -> int:
        """Spread ``initial`` vehicles over the entry roads; returns how many were placed."""
        placed = 0
        for _ in range(self.traffic.initial):
            for _try in range(20):
                lane, exits = self.routes[int(self.rng.integers(len(self.routes)))]
                length = self.road.network.get_lane(lane).length
                if self._place(lane, exits, float(self.rng.uniform(0.0, 0.85 * length))):
                    placed += 1
                    break
        return placed

    def step(self, dt_s: float) -> None:
        """Arrivals over dt_s [s] at the entries' starts; vehicles past their exit leave."""
        for _ in range(int(self.rng.poisson(self.traffic.per_min / 60.0 * dt_s))):
            lane, exits = self.routes[int(self.rng.integers(len(self.routes)))]
            self._place(lane, exits, 0.0)
        for v in list(self.added):
            if v.lane_index[1] in self.exits:
                lane = self.road.network.get_lane(v.lane_index)
                if lane.local_coordinates(v.position)[0] > lane.length:
                    self.road.vehicles.remove(v)
                    self.added.remove(v)

    def _place(self, lane_index: tuple, exits: list[str], s_m: float) -> bool:
        lane = self.road.network.get_lane(lane_index)
        p = lane.position(s_m, 0.0)
        if any(np.hypot(*(np.asarray(v.position) - p)) < CLEARANCE_M for v in self.road.vehicles):
            return False
        limit = lane.speed_limit or 15.0
        speed = limit * float(self.rng.uniform(*SPEED_RANGE))
        v = self.vehicle_type.make_on_lane(self.road, lane_index, longitudinal=s_m, speed=speed)
        v.sim_dt_s = self.sim_dt_s
        v.plan_route_to(exits[int(self.rng.integers(len(exits)))])
        v.randomize_behavior()
        self.road.vehicles.append(v)
        self.added.append(v)
        return True
