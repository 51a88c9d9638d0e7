"""Bridge from highway-env traffic to world-frame vehicle states and road geometry.

highway-env's ``(x, y)`` has y growing to the right of the direction of travel and
its heading is measured the same way; it is not a right-handed z-up frame. This
module is where that is converted, once (docs/CONVENTIONS.md):

    world = (x_hw, -y_hw, 0),   yaw_world = -heading_hw.

Rates. highway-env integrates its vehicles at ``simulation_frequency`` and takes a
decision (one ``env.step``) at ``policy_frequency`` (1 Hz by default). The bridge
sets ``policy_frequency = fps`` (the camera rate) and ``simulation_frequency =
k * fps`` (the smallest integer multiple of fps that is an integer and at least
``min_sim_hz``), so each :meth:`HighwayBridge.step` advances exactly ``1/fps`` s.

The ego. The env's controlled vehicle is replaced after reset by an
:class:`EgoIDMVehicle` (highway-env's ``IDMVehicle``: IDM longitudinal control,
MOBIL lane changes, plus a yield at predicted crossing conflicts, since
highway-env's IDM vehicles drive into each other where lanes cross and
roundabout-v0 has no right-of-way rule at all) at the same position, heading,
speed, lane, target speed and route; ``ego_policy="keep-lane"`` turns the lane
changes off. It follows curves, routes (intersection, roundabout) and junctions on
its own; the env is stepped with a no-op action that the IDM vehicle ignores. The
env's observation is set to a trivial one (never read; Kinematics costs ~25 %).

Crashes. highway-env reports a crash as ``terminated``; the bridge ignores
``terminated``/``truncated`` and keeps stepping: a crashed vehicle brakes to a stop
(highway-env's own behaviour) and its state carries ``crashed=True``. The time of
the ego's first crash is kept in :attr:`HighwayBridge.ego_crash_t_s`; with
``stop_on_ego_crash=True`` :meth:`HighwayBridge.frames` ends after the frame that
shows the crash. Measured over seeds 0-19, 10 s at 15 fps, default configs: no ego
crash on highway-v0, merge-v0, roundabout-v0, racetrack-v0 (plain IDM ego:
roundabout 4/20 from 2.3 s, intersection 5/20 from 5.3 s); on intersection-v0 2/20
at 9.5-9.7 s, a car driving into the ego while highway-env's ``RegulatedRoad``
holds it yielding inside the junction (it may wait there several seconds).

Ids. The ego is id 0; other vehicles get 1, 2, ... in order of first appearance
(sorted by their order in ``road.vehicles`` within a frame); vehicles that leave
(intersection) are absent from later frames and their ids are never reused.

Two quirks of highway-env 1.12.1 that this module neutralises:

- ``intersection-v0`` writes ``DISTANCE_WANTED``, ``COMFORT_ACC_MAX`` and
  ``COMFORT_ACC_MIN`` onto the IDM vehicle *class* at every reset, which silently
  changes every later env in the process. Each bridge restores the pristine class
  attributes around its reset and its steps (:class:`_BehaviourClassState`).
- ``intersection-v0`` spawns a vehicle with ``spawn_probability`` at every
  ``env.step``; its default (0.6) is meant per 1-Hz decision. The bridge rescales it
  to ``1 - (1 - p)**(1/fps)`` per frame so the spawn rate per second is unchanged.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

# highway-env imports pygame for its viewer; silence its banner (no window is opened).
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import gymnasium  # noqa: E402
import highway_env  # noqa: E402, F401  (importing registers the highway-env ids)
from highway_env.road.lane import CircularLane, LineType, SineLane, StraightLane  # noqa: E402
from highway_env.vehicle.behavior import IDMVehicle  # noqa: E402
from highway_env.vehicle.kinematics import Vehicle  # noqa: E402

from sim.scenario import TrafficConfig  # noqa: E402
from sim.traffic import TrafficSource  # noqa: E402

EGO_POLICIES = ("idm", "keep-lane")

#: Vehicle height range for cars [m]; each vehicle draws its height from it.
HEIGHT_RANGE_M = (1.4, 1.7)
#: The ego car's roof height [m]: the omni presets put the mirror's viewpoint
#: 0.45 m above a 1.5 m roof (the paper's first test run).
EGO_HEIGHT_M = 1.5
#: x of the ego car's rear axle in the car frame [m]: highway-env's kinematic bicycle
#: model (slip angle beta at the centre, heading rate v sin(beta) / (L/2)) moves the point
#: L/2 behind the centre straight ahead, so it is the point that does not slide sideways.
EGO_REAR_AXLE_X_M = -0.5 * Vehicle.LENGTH

#: Sample spacing along curved lanes [m] and the largest along straight lanes [m].
CURVE_STEP_M = 1.0
STRAIGHT_STEP_M = 5.0


# --------------------------------------------------------------------------- states


@dataclass(frozen=True)
class VehicleState:
    """One vehicle at one instant, in the world frame (right-handed, z up).

    (x_m, y_m) is the centre of the footprint on the road [m]; yaw_rad is the world
    yaw of the vehicle's x (forward) axis [rad], wrapped to (-pi, pi]; yaw_rate_rps
    is the world yaw rate [rad/s]: the central difference of the yaw over the
    neighbouring frames (one-sided at a vehicle's first/last frame).
    """

    id: int  # stable over the drive: ego 0, others 1, 2, ... by first appearance
    x_m: float
    y_m: float
    yaw_rad: float
    speed_mps: float
    length_m: float
    width_m: float
    height_m: float
    yaw_rate_rps: float
    is_ego: bool
    crashed: bool = False


@dataclass(frozen=True)
class WorldFrame:
    """All vehicles at camera frame ``index``, time ``t_s = index / fps`` [s]."""

    index: int
    t_s: float
    ego: VehicleState
    others: tuple[VehicleState, ...]

    @property
    def vehicles(self) -> tuple[VehicleState, ...]:
        """The ego first, then the others."""
        return (self.ego, *self.others)


# --------------------------------------------------------------------------- road


@dataclass(frozen=True, eq=False)
class LaneGeometry:
    """One highway-env lane (or a clipped piece of it), sampled in the world frame.

    N samples along the centre-line; "left"/"right" are relative to the direction
    of travel (highway-env's ``line_types[0]`` is the left side, ``[1]`` the right).

    index: highway-env lane index ``(from, to, id)``.
    s_m: (N,) longitudinal coordinate along the lane [m] (highway-env's).
    center_xy, left_xy, right_xy: (N, 2) centre-line and edges [m].
    yaw_rad: (N,) world heading of the lane [rad]. width_m: (N,) [m].
    line_types: (left, right) highway-env ``LineType`` codes (0 NONE, 1 STRIPED,
        2 CONTINUOUS, 3 CONTINUOUS_LINE).
    speed_limit_mps: the lane's speed limit [m/s] (None if unset).
    kind: "straight", "circular", "sine" or "poly".
    """

    index: tuple[str, str, int]
    s_m: np.ndarray
    center_xy: np.ndarray
    left_xy: np.ndarray
    right_xy: np.ndarray
    yaw_rad: np.ndarray
    width_m: np.ndarray
    line_types: tuple[int, int]
    speed_limit_mps: float | None
    kind: str

    def take(self, sl: slice) -> LaneGeometry:
        """The samples ``sl`` of this lane, as a new piece."""
        return replace(
            self,
            s_m=self.s_m[sl],
            center_xy=self.center_xy[sl],
            left_xy=self.left_xy[sl],
            right_xy=self.right_xy[sl],
            yaw_rad=self.yaw_rad[sl],
            width_m=self.width_m[sl],
        )


@dataclass(frozen=True, eq=False)
class RoadGeometry:
    """Every lane of a highway-env road network, in the world frame.

    lanes: the lane pieces (a clipped lane may give several pieces, same index).
    obstacles_xyyaw_lw: (M, 5) static obstacles of the road (``road.objects``):
        x [m], y [m], yaw [rad], length [m], width [m].
    """

    lanes: tuple[LaneGeometry, ...]
    obstacles_xyyaw_lw: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)))

    def bounds_xy(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of all lane edges [m]."""
        pts = np.concatenate([np.concatenate([ln.left_xy, ln.right_xy]) for ln in self.lanes])
        return (
            float(pts[:, 0].min()),
            float(pts[:, 0].max()),
            float(pts[:, 1].min()),
            float(pts[:, 1].max()),
        )

    def clipped(self, clip_xy: Sequence[float], margin_m: float = 5.0) -> RoadGeometry:
        """The lane pieces whose samples lie in ``clip_xy`` grown by ``margin_m``.

        A piece keeps one extra sample on each side of a run, so the clipped road
        still reaches past the box; a lane that leaves and re-enters gives two pieces.
        """
        xmin, xmax, ymin, ymax = check_box(clip_xy, "clip_xy")
        pieces: list[LaneGeometry] = []
        for lane in self.lanes:
            half = 0.5 * float(lane.width_m.max())
            inside = _in_box(lane.center_xy, (xmin, xmax, ymin, ymax), margin_m + half)
            for a, b in _runs(inside, pad=1):
                if b - a >= 2:
                    pieces.append(lane.take(slice(a, b)))
        obs = self.obstacles_xyyaw_lw
        keep = _in_box(obs[:, :2], (xmin, xmax, ymin, ymax), margin_m) if len(obs) else []
        return RoadGeometry(lanes=tuple(pieces), obstacles_xyyaw_lw=obs[keep])

    def contains_xy(self, points_xy: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """(M,) bool: which points lie on some lane (within half its width + margin).

        Exact per lane segment (distance to the sampled centre polyline), vectorised.
        """
        pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
        inside = np.zeros(len(pts), dtype=bool)
        for lane in self.lanes:
            c = lane.center_xy
            if len(c) < 2:
                continue
            a, b = c[:-1], c[1:]
            hw = 0.5 * np.minimum(lane.width_m[:-1], lane.width_m[1:]) + margin_m
            lo = np.minimum(a, b).min(axis=0) - hw.max()
            hi = np.maximum(a, b).max(axis=0) + hw.max()
            cand = np.flatnonzero(~inside & np.all((pts >= lo) & (pts <= hi), axis=1))
            if cand.size == 0:
                continue
            d = _point_segment_distance(pts[cand], a, b)  # (m, S)
            inside[cand] = np.any(d <= hw[None, :], axis=1)
        return inside


def check_box(box: Sequence[float], name: str) -> tuple[float, float, float, float]:
    """Validate an (xmin, xmax, ymin, ymax) box [m]."""
    arr = np.asarray(box, dtype=float)
    if arr.shape != (4,) or not np.all(np.isfinite(arr)) or arr[0] >= arr[1] or arr[2] >= arr[3]:
        raise ValueError(f"{name} must be (xmin, xmax, ymin, ymax) with min < max, got {box!r}")
    return float(arr[0]), float(arr[1]), float(arr[2]), float(arr[3])


def world_from_hw_xy(xy_hw: np.ndarray) -> np.ndarray:
    """(..., 2) highway-env (x, y) -> world (x, y): y flips sign."""
    out = np.array(xy_hw, dtype=float, copy=True)
    out[..., 1] *= -1.0
    return out


def world_yaw_from_hw_heading(heading_hw: np.ndarray | float) -> np.ndarray | float:
    """highway-env heading -> world yaw (the sign flips), wrapped to (-pi, pi]."""
    return _wrap(-np.asarray(heading_hw, dtype=float))


def road_geometry(env: gymnasium.Env, clip_xy: Sequence[float] | None = None) -> RoadGeometry:
    """Sample every lane of ``env.unwrapped.road.network`` in the world frame.

    Curved lanes (circular, sine, poly) are sampled every ``CURVE_STEP_M``; straight
    lanes every ``STRAIGHT_STEP_M`` at most. With ``clip_xy = (xmin, xmax, ymin,
    ymax)`` (world, [m]) straight lanes are first cut analytically to the box (the
    highway's 10-km lanes) and every lane is then clipped to it
    (:meth:`RoadGeometry.clipped`).
    """
    road = env.unwrapped.road
    if road is None:
        raise ValueError("env has no road: call env.reset() first")
    box_hw = None
    if clip_xy is not None:
        xmin, xmax, ymin, ymax = check_box(clip_xy, "clip_xy")
        box_hw = (xmin, xmax, -ymax, -ymin)  # the same box in highway-env coordinates
    lanes = []
    for _from, tos in road.network.graph.items():
        for _to, lane_list in tos.items():
            for i, lane in enumerate(lane_list):
                geo = _sample_lane(lane, (_from, _to, i), box_hw)
                if geo is not None:
                    lanes.append(geo)
    obstacles = []
    for obj in road.objects:
        x, y = world_from_hw_xy(np.asarray(obj.position, dtype=float))
        yaw = float(world_yaw_from_hw_heading(obj.heading))
        obstacles.append((x, y, yaw, float(obj.LENGTH), float(obj.WIDTH)))
    geo = RoadGeometry(
        lanes=tuple(lanes), obstacles_xyyaw_lw=np.array(obstacles, dtype=float).reshape(-1, 5)
    )
    return geo.clipped(clip_xy) if clip_xy is not None else geo


def _lane_kind(lane: object) -> str:
    if isinstance(lane, SineLane):  # before StraightLane: SineLane subclasses it
        return "sine"
    if isinstance(lane, StraightLane):
        return "straight"
    if isinstance(lane, CircularLane):
        return "circular"
    return "poly"


def _sample_lane(
    lane: object, index: tuple[str, str, int], box_hw: tuple[float, ...] | None
) -> LaneGeometry | None:
    kind = _lane_kind(lane)
    length = float(lane.length)
    s0, s1 = 0.0, length
    if kind == "straight" and box_hw is not None:
        margin = 10.0 + float(lane.width_at(0.0))
        rng_s = _segment_box_interval(
            np.asarray(lane.start, float), np.asarray(lane.direction, float), length, box_hw, margin
        )
        if rng_s is None:
            return None
        s0, s1 = rng_s
    step = STRAIGHT_STEP_M if kind == "straight" else CURVE_STEP_M
    n = max(2, int(math.ceil((s1 - s0) / step)) + 1)
    s = np.linspace(s0, s1, n)
    width = np.array([float(lane.width_at(si)) for si in s])
    center = np.array([lane.position(si, 0.0) for si in s], dtype=float)
    left = np.array([lane.position(si, -0.5 * w) for si, w in zip(s, width, strict=True)])
    right = np.array([lane.position(si, 0.5 * w) for si, w in zip(s, width, strict=True)])
    heading = np.array([float(lane.heading_at(si)) for si in s])
    line_types = tuple(int(t) for t in (lane.line_types or (LineType.NONE, LineType.NONE)))
    limit = getattr(lane, "speed_limit", None)
    return LaneGeometry(
        index=(str(index[0]), str(index[1]), int(index[2])),
        s_m=s,
        center_xy=world_from_hw_xy(center),
        left_xy=world_from_hw_xy(left),
        right_xy=world_from_hw_xy(right),
        yaw_rad=world_yaw_from_hw_heading(heading),
        width_m=width,
        line_types=(line_types[0], line_types[1]),
        speed_limit_mps=None if limit is None else float(limit),
        kind=kind,
    )


def _segment_box_interval(
    start: np.ndarray,
    direction: np.ndarray,
    length: float,
    box: tuple[float, ...],
    margin: float,
) -> tuple[float, float] | None:
    """[s0, s1] of the segment start + s*direction (0 <= s <= length) inside the box."""
    lo = np.array([box[0] - margin, box[2] - margin])
    hi = np.array([box[1] + margin, box[3] + margin])
    s0, s1 = 0.0, length
    for k in range(2):
        if abs(direction[k]) < 1e-12:
            if not lo[k] <= start[k] <= hi[k]:
                return None
            continue
        a = (lo[k] - start[k]) / direction[k]
        b = (hi[k] - start[k]) / direction[k]
        s0, s1 = max(s0, min(a, b)), min(s1, max(a, b))
    return (s0, s1) if s1 > s0 else None


def _in_box(xy: np.ndarray, box: tuple[float, ...], margin: float) -> np.ndarray:
    return (
        (xy[:, 0] >= box[0] - margin)
        & (xy[:, 0] <= box[1] + margin)
        & (xy[:, 1] >= box[2] - margin)
        & (xy[:, 1] <= box[3] + margin)
    )


def _runs(mask: np.ndarray, pad: int = 0) -> list[tuple[int, int]]:
    """[start, stop) of the True runs of ``mask``, each grown by ``pad`` samples."""
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return []
    d = np.diff(np.concatenate([[0], m.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    out: list[tuple[int, int]] = []
    for a, b in zip(starts, stops, strict=True):
        a, b = max(0, int(a) - pad), min(len(m), int(b) + pad)
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(M, S) distances from points p (M, 2) to segments a-b (S, 2)."""
    ab = b - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    ap = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("msk,sk->ms", ap, ab) / ab2[None, :], 0.0, 1.0)
    q = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - q, axis=-1)


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to (-pi, pi]."""
    w = np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)
    return float(w) if np.ndim(w) == 0 else w


# --------------------------------------------------------------------------- bridge


class _BehaviourClassState:
    """Upper-case class attributes of highway-env's vehicle behaviour classes.

    Some envs write tuning constants onto the behaviour *class* at reset
    (intersection-v0: ``DISTANCE_WANTED``, ``COMFORT_ACC_*``). Capturing the state
    and re-applying it makes each bridge independent of the others and of the
    order in which envs were created.
    """

    def __init__(self, classes: Sequence[type]) -> None:
        self.classes = tuple(dict.fromkeys(classes))
        self.attrs = {
            cls: {k: v for k, v in vars(cls).items() if k.isupper()} for cls in self.classes
        }

    def apply(self) -> None:
        for cls, attrs in self.attrs.items():
            for k in [k for k in vars(cls) if k.isupper() and k not in attrs]:
                delattr(cls, k)
            for k, v in attrs.items():
                setattr(cls, k, v)


def _behaviour_classes(config: dict) -> list[type]:
    from highway_env import utils

    classes = [c for c in IDMVehicle.__mro__ if c is not object]
    classes += list(_all_subclasses(IDMVehicle))
    try:
        other = utils.class_from_path(config["other_vehicles_type"])
        classes += [c for c in other.__mro__ if c is not object]
    except (KeyError, ImportError, AttributeError, ValueError):
        pass
    return classes


def _all_subclasses(cls: type) -> list[type]:
    out = []
    for sub in cls.__subclasses__():
        out.append(sub)
        out.extend(_all_subclasses(sub))
    return out


# Captured when this module is imported, before any env had a chance to write on them.
_PRISTINE = _BehaviourClassState(_behaviour_classes({}))


def _pristine_state(config: dict) -> _BehaviourClassState:
    """The behaviour classes' attributes as first seen by this module."""
    for cls in _behaviour_classes(config):
        if cls not in _PRISTINE.attrs:  # first seen now: record it as it is
            _PRISTINE.attrs[cls] = {k: v for k, v in vars(cls).items() if k.isupper()}
    _PRISTINE.classes = tuple(_PRISTINE.attrs)
    return _PRISTINE


class EgoIDMVehicle(IDMVehicle):
    """highway-env's IDMVehicle (IDM + MOBIL) that also yields at crossing conflicts.

    highway-env's IDM only sees the vehicles in its own and target lanes, and
    roundabout-v0 has no right-of-way rule: circulating and entering vehicles drive
    into each other (the ego crashed within 10 s in 4 of 20 seeds). At each decision
    the ego predicts itself and every vehicle within ``CONFLICT_RANGE_M`` at
    constant speed and turn rate (the bicycle model's current steering) for
    ``CONFLICT_HORIZON_S``; if their boxes (grown by ``CONFLICT_GROWTH``) would
    overlap at some time t_c, it brakes with IDM as for a stopped vehicle where it
    would be at t_c. Vehicles that follow the ego (behind it, heading within 45 deg),
    its IDM leader/follower, and vehicles that highway-env's ``RegulatedRoad``
    (intersection-v0) told to yield are left out.
    """

    CONFLICT_HORIZON_S = 3.0  # [s]
    CONFLICT_STEP_S = 0.25  # [s]
    CONFLICT_RANGE_M = 45.0  # [m]
    CONFLICT_GROWTH = (1.3, 1.25)  # [-] box scale (length, width) for the overlap test

    #: integration step of the simulation [s]; set by the bridge (braking never reverses)
    sim_dt_s = 1.0 / 15.0

    def act(self, action: dict | str | None = None) -> None:
        super().act(action)
        if self.crashed:
            return
        acc = float(self.action["acceleration"])
        t_c = self.conflict_time()
        if t_c is not None:
            # IDM interaction term for a stopped obstacle where the ego would be at t_c
            v = max(float(self.speed), 0.0)
            gap = max(v * t_c - 0.5 * self.LENGTH, 0.5)
            ab = -self.COMFORT_ACC_MAX * self.COMFORT_ACC_MIN
            d_star = self.DISTANCE_WANTED + v * self.TIME_WANTED + v * v / (2.0 * np.sqrt(ab))
            acc = min(acc, self.COMFORT_ACC_MAX * (1.0 - (d_star / gap) ** 2))
        # highway-env lets IDM braking run the speed below zero (reversing): stop at 0
        acc = max(acc, -max(float(self.speed), 0.0) / self.sim_dt_s)
        self.action["acceleration"] = float(np.clip(acc, -self.ACC_MAX, self.ACC_MAX))

    def conflict_time(self) -> float | None:
        """First predicted time [s] of a box overlap with a crossing vehicle, or None."""
        from highway_env import utils

        leader, follower = self.road.neighbour_vehicles(self, self.lane_index)
        others = []
        for v in self.road.vehicles:
            if v is self or v is leader or v is follower or getattr(v, "is_yielding", False):
                continue  # IDM handles leader/follower; a yielding vehicle stops for us
            rel = np.asarray(v.position) - self.position
            if np.hypot(*rel) > self.CONFLICT_RANGE_M:
                continue
            behind = np.dot(rel, self.direction) < 0.0
            if behind and abs(_wrap(v.heading - self.heading)) < np.pi / 4:
                continue
            others.append(v)
        if not others:
            return None
        gl, gw = self.CONFLICT_GROWTH
        times = np.arange(0.0, self.CONFLICT_HORIZON_S + 1e-9, self.CONFLICT_STEP_S)
        ego_path = _ctrv_path(self, times)
        for v in others:
            path = _ctrv_path(v, times)
            reach = 0.5 * gl * (self.LENGTH + v.LENGTH)
            for t, (p, h), (q, g) in zip(times, ego_path, path, strict=True):
                if np.hypot(*(q - p)) > reach:
                    continue
                if utils.rotated_rectangles_intersect(
                    (p, gl * self.LENGTH, gw * self.WIDTH, h),
                    (q, gl * v.LENGTH, gw * v.WIDTH, g),
                ):
                    return float(t)
        return None


def _ctrv_path(v: object, times: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """Positions and headings (highway-env frame) at constant speed and steering."""
    steering = float(v.action.get("steering", 0.0)) if isinstance(v.action, dict) else 0.0
    beta = np.arctan(0.5 * np.tan(steering))
    speed = float(v.speed)
    rate = speed * np.sin(beta) / (0.5 * v.LENGTH)
    pos = np.array(v.position, dtype=float)
    heading = float(v.heading)
    out = [(pos.copy(), heading)]
    for dt in np.diff(times):
        pos = pos + speed * dt * np.array([np.cos(heading + beta), np.sin(heading + beta)])
        heading += rate * dt
        out.append((pos.copy(), heading))
    return out


@dataclass
class _Raw:
    """A vehicle's state in one frame, before the yaw rate is known."""

    x: float
    y: float
    heading_hw: float
    speed: float
    length: float
    width: float
    crashed: bool
    is_ego: bool


class HighwayBridge:
    """Runs a highway-env environment at the camera rate and reports world states.

    env_id: a registered highway-env id (``"highway-v0"``, ``"roundabout-v0"`` ...).
    env_config: overrides of the env's ``default_config()`` (top-level keys are
        checked). ``policy_frequency`` must not be set (it is ``fps``);
        ``simulation_frequency`` may be set to an integer multiple of ``fps``.
    seed: seeds ``env.reset`` and the vehicles' heights.
    fps: camera frame rate [Hz]; each :meth:`step` advances ``1/fps`` s.
    ego_policy: ``"idm"`` (IDM + MOBIL lane changes) or ``"keep-lane"`` (IDM only).
    ego_speed_mps: the ego's IDM target speed [m/s] (None: the env's own vehicle's).
    min_sim_hz: lowest highway-env integration rate [Hz].
    stop_on_ego_crash: end :meth:`frames` after the first frame with the ego crashed.
    traffic: vehicles added to the env's own (`sim.traffic`), drawn from the seed.

    Attributes: ``env`` (the gymnasium env), ``sim_hz``, ``substeps`` (sim steps
    per frame), ``road`` (:class:`RoadGeometry`, unclipped), ``ego_crash_t_s``.
    """

    def __init__(
        self,
        env_id: str,
        env_config: dict | None,
        seed: int,
        fps: float,
        ego_policy: str = "idm",
        ego_speed_mps: float | None = None,
        *,
        min_sim_hz: float = 15.0,
        stop_on_ego_crash: bool = False,
        traffic: TrafficConfig | None = None,
    ) -> None:
        if ego_policy not in EGO_POLICIES:
            raise ValueError(f"ego_policy must be one of {EGO_POLICIES}, got {ego_policy!r}")
        if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a positive number [Hz], got {fps!r}")
        if env_id not in gymnasium.registry:
            raise ValueError(f"unknown environment {env_id!r} (not in gymnasium's registry)")
        env_config = dict(env_config or {})
        self.env_id = env_id
        self.seed = int(seed)
        self.fps = float(fps)
        self.dt_s = 1.0 / self.fps
        self.ego_policy = ego_policy
        if ego_speed_mps is not None and not (math.isfinite(ego_speed_mps) and ego_speed_mps > 0):
            raise ValueError(f"ego_speed_mps must be > 0 [m/s] or None, got {ego_speed_mps!r}")
        self.ego_speed_mps = ego_speed_mps
        self.stop_on_ego_crash = stop_on_ego_crash

        defaults = gymnasium.registry[env_id]
        env_cls = gymnasium.envs.registration.load_env_creator(defaults.entry_point)
        default_cfg = env_cls.default_config() if hasattr(env_cls, "default_config") else {}
        self.sim_hz, self.substeps = _sim_rate(self.fps, min_sim_hz, env_config)
        config = _bridge_config(default_cfg, env_config, self.sim_hz, self.fps)

        self._pristine = _pristine_state(config)
        self._pristine.apply()
        with warnings.catch_warnings():  # "<env>-v0 is out of date": the id was asked for
            warnings.simplefilter("ignore", DeprecationWarning)
            self.env = gymnasium.make(
                env_id, config=config, render_mode=None, disable_env_checker=True
            )
        self.env.reset(seed=self.seed)
        base = self.env.unwrapped
        got = int(base.config["simulation_frequency"] // base.config["policy_frequency"])
        if got != self.substeps:  # highway-env floors the float ratio
            raise ValueError(f"fps {fps!r}: highway-env would run {got} sim steps per frame")
        self._behaviour = _BehaviourClassState(self._pristine.classes)
        self._pristine.apply()

        self._install_ego()
        self._noop = _noop_action(self.env)
        self.road = road_geometry(self.env)
        self._traffic = None
        if traffic is not None and traffic.active:
            rng = np.random.default_rng([self.seed, 0x7A])
            self._traffic = TrafficSource(
                traffic, self.env, rng, vehicle_type=EgoIDMVehicle, sim_dt_s=1.0 / self.sim_hz
            )
            self._traffic.populate()

        self._ids: dict[int, tuple[object, int]] = {}  # id(vehicle) -> (vehicle, our id)
        self._next_id = 1
        self._heights: dict[int, float] = {}
        self.ego_crash_t_s: float | None = None
        self._env_index = 0  # frame index of the env's current state
        self._emit_index = 0  # next frame index to yield
        self._hist: dict[int, dict[int, _Raw]] = {0: self._snapshot()}

    # -- set-up -------------------------------------------------------------

    def _install_ego(self) -> None:
        base = self.env.unwrapped
        old = base.vehicle
        ego = EgoIDMVehicle(
            base.road,
            np.array(old.position, dtype=float),
            heading=float(old.heading),
            speed=float(old.speed),
            target_lane_index=getattr(old, "target_lane_index", None) or old.lane_index,
            target_speed=self.ego_speed_mps or getattr(old, "target_speed", None),
            route=getattr(old, "route", None),
            enable_lane_change=self.ego_policy == "idm",
        )
        ego.LENGTH, ego.WIDTH = old.LENGTH, old.WIDTH
        ego.sim_dt_s = 1.0 / self.sim_hz
        base.road.vehicles[base.road.vehicles.index(old)] = ego
        base.controlled_vehicles[0] = ego
        self._ego = ego

    # -- stepping -----------------------------------------------------------

    def step(self) -> None:
        """Advance the traffic by exactly 1/fps s."""
        self._behaviour.apply()
        try:
            if self._traffic is not None:
                self._traffic.step(self.dt_s)
            self.env.unwrapped.step(self._noop)  # terminated/truncated are ignored
        finally:
            self._pristine.apply()
        self._env_index += 1
        self._hist[self._env_index] = self._snapshot()
        for k in [k for k in self._hist if k < self._env_index - 2]:
            del self._hist[k]

    def frames(self, n: int) -> Iterator[WorldFrame]:
        """Yield the next ``n`` frames (the first call starts at t = 0).

        The env runs one frame ahead of the yielded frame (for the yaw rate's
        central difference).
        """
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        for _ in range(n):
            k = self._emit_index
            while self._env_index < k + 1:
                self.step()
            frame = self._frame(k)
            self._emit_index += 1
            yield frame
            if self.stop_on_ego_crash and frame.ego.crashed:
                return

    def _snapshot(self) -> dict[int, _Raw]:
        base = self.env.unwrapped
        out: dict[int, _Raw] = {}
        for v in base.road.vehicles:
            vid = self._vehicle_id(v)
            out[vid] = _Raw(
                x=float(v.position[0]),
                y=float(v.position[1]),
                heading_hw=float(v.heading),
                speed=float(v.speed),
                length=float(v.LENGTH),
                width=float(v.WIDTH),
                crashed=bool(v.crashed),
                is_ego=v is self._ego,
            )
        if 0 not in out:
            raise RuntimeError(f"{self.env_id}: the ego vehicle left the road's vehicle list")
        return out

    def _vehicle_id(self, v: object) -> int:
        if v is getattr(self, "_ego", None):
            return 0
        entry = self._ids.get(id(v))
        if entry is None or entry[0] is not v:
            entry = (v, self._next_id)  # keeps v alive, so id(v) is never reused
            self._ids[id(v)] = entry
            self._next_id += 1
        return entry[1]

    def _height(self, vid: int) -> float:
        h = self._heights.get(vid)
        if h is None and vid == 0:
            h = self._heights[vid] = EGO_HEIGHT_M
        if h is None:
            u = np.random.default_rng([self.seed, vid, 0x0B]).uniform()
            h = HEIGHT_RANGE_M[0] + (HEIGHT_RANGE_M[1] - HEIGHT_RANGE_M[0]) * float(u)
            self._heights[vid] = h
        return h

    def _frame(self, k: int) -> WorldFrame:
        cur = self._hist[k]
        prev = self._hist.get(k - 1, {})
        nxt = self._hist.get(k + 1, {})
        states = []
        for vid, r in cur.items():
            p, q = prev.get(vid), nxt.get(vid)
            if p is not None and q is not None:
                rate_hw = _wrap(q.heading_hw - p.heading_hw) / (2 * self.dt_s)
            elif q is not None:
                rate_hw = _wrap(q.heading_hw - r.heading_hw) / self.dt_s
            elif p is not None:
                rate_hw = _wrap(r.heading_hw - p.heading_hw) / self.dt_s
            else:
                rate_hw = 0.0
            states.append(
                VehicleState(
                    id=vid,
                    x_m=r.x,
                    y_m=-r.y,
                    yaw_rad=float(world_yaw_from_hw_heading(r.heading_hw)),
                    speed_mps=r.speed,
                    length_m=r.length,
                    width_m=r.width,
                    height_m=self._height(vid),
                    yaw_rate_rps=-float(rate_hw),
                    is_ego=r.is_ego,
                    crashed=r.crashed,
                )
            )
        ego = next(s for s in states if s.is_ego)
        if ego.crashed and self.ego_crash_t_s is None:
            self.ego_crash_t_s = k * self.dt_s
        others = tuple(sorted((s for s in states if not s.is_ego), key=lambda s: s.id))
        return WorldFrame(index=k, t_s=k * self.dt_s, ego=ego, others=others)

    def road_geometry(self, clip_xy: Sequence[float] | None = None) -> RoadGeometry:
        """The env's road in the world frame, optionally clipped (see :func:`road_geometry`)."""
        return road_geometry(self.env, clip_xy) if clip_xy is not None else self.road

    def close(self) -> None:
        self.env.close()


def simulate(
    env_id: str,
    env_config: dict | None,
    seed: int,
    fps: float,
    duration_s: float,
    ego_policy: str = "idm",
    ego_speed_mps: float | None = None,
    *,
    return_road: bool = False,
    traffic: TrafficConfig | None = None,
) -> list[WorldFrame] | tuple[list[WorldFrame], RoadGeometry]:
    """``floor(duration_s * fps)`` frames of a fresh drive (t = 0, 1/fps, ...).

    With ``return_road=True`` returns ``(frames, road)``, road the unclipped
    :class:`RoadGeometry` of the env.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be > 0 [s], got {duration_s!r}")
    bridge = HighwayBridge(
        env_id, env_config, seed, fps, ego_policy, ego_speed_mps, traffic=traffic
    )
    try:
        frames = list(bridge.frames(int(math.floor(duration_s * fps + 1e-9))))
    finally:
        bridge.close()
    return (frames, bridge.road) if return_road else frames


# --------------------------------------------------------------------------- config


def _sim_rate(fps: float, min_sim_hz: float, env_config: dict) -> tuple[int, int]:
    """(simulation_frequency [Hz], sim steps per frame)."""
    if "simulation_frequency" in env_config:
        sim = env_config["simulation_frequency"]
        k = sim / fps
        if not (isinstance(sim, int) and sim > 0 and abs(k - round(k)) < 1e-9 and round(k) >= 1):
            raise ValueError(
                f"env_config.simulation_frequency must be an integer multiple of fps={fps}, "
                f"got {sim!r}"
            )
        return sim, int(round(k))
    for k in range(max(1, math.ceil(min_sim_hz / fps - 1e-9)), 1001):
        sim = fps * k
        if abs(sim - round(sim)) < 1e-6:
            return int(round(sim)), k
    raise ValueError(f"fps={fps!r}: no integer simulation rate k*fps (k <= 1000) exists")


def _bridge_config(default_cfg: dict, env_config: dict, sim_hz: int, fps: float) -> dict:
    unknown = sorted(set(env_config) - set(default_cfg)) if default_cfg else []
    if unknown:
        raise ValueError(
            f"env_config.{unknown[0]}: unknown key for this env (known: {sorted(default_cfg)})"
        )
    if "policy_frequency" in env_config and env_config["policy_frequency"] != fps:
        raise ValueError(
            f"env_config.policy_frequency is set by the bridge to fps={fps}, "
            f"got {env_config['policy_frequency']!r}"
        )
    config = dict(env_config)
    config.update(
        {
            "simulation_frequency": sim_hz,  # [Hz]
            "policy_frequency": fps,  # [Hz] one env.step per camera frame
            "duration": 1e9,  # [s] never truncate
            "offscreen_rendering": True,
            "real_time_rendering": False,
            "manual_control": False,
            "show_trajectories": False,
            # the bridge never reads observations: the cheapest one (Kinematics costs ~25 %)
            "observation": {"type": "AttributesObservation", "attributes": ["steps"]},
        }
    )
    if "spawn_probability" in default_cfg:
        # highway-env means it per 1-Hz decision: keep the per-second rate
        p = float(env_config.get("spawn_probability", default_cfg["spawn_probability"]))
        config["spawn_probability"] = 1.0 - (1.0 - min(max(p, 0.0), 1.0)) ** (1.0 / fps)
    return config


def _noop_action(env: gymnasium.Env) -> object:
    """An action that means 'keep going' (the IDM ego ignores it anyway)."""
    base = env.unwrapped
    space = base.action_space
    indexes = getattr(base.action_type, "actions_indexes", None)
    if isinstance(space, gymnasium.spaces.Discrete):
        return int(indexes.get("IDLE", 0)) if indexes else 0
    return np.zeros(space.shape, dtype=space.dtype)
