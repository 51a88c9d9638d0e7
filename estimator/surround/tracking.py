"""Multi-vehicle tracking on the road plane (paper section 5).

The detector reports, per frame, the road-plane point of each vehicle blob
nearest to the camera (section 5: "the points on the blob that are nearest to
the camera center usually correspond to the road plane"). This module tracks
those points over frames with one constant-velocity Kalman filter per vehicle
(the paper's "tracked over frames using Kalman filter [4]"), global-nearest-
neighbour assignment and M-of-N track management.

Frames. ``e_k``, the **ego road frame** of frame k: x forward, y left, origin on
the road under the camera viewpoint, moving with the car (docs/CONVENTIONS.md).
Between frames k-1 and k (interval ``dt``) the origin moves with forward speed
``s`` and lateral speed ``u`` (both in its own axes, constant over the interval)
while the frame turns at yaw rate ``ω``; with ``ψ = ω dt``::

    d = dt M(ψ) (s, u),   M(ψ) = [[f1, -f2], [f2, f1]],
    f1 = sin ψ / ψ,   f2 = (1 - cos ψ) / ψ            (exact for a constant turn)

is the displacement of the origin expressed in ``e_{k-1}``, and a point fixed
on the ground at ``p`` in ``e_{k-1}`` is at ``R(ψ)ᵀ (p - d)`` in ``e_k``
(``R(ψ)`` the 2-D rotation by ψ, `ego_frame_change`).

Symbols, per track:

- ``x`` (4,): state ``(x, y, vx, vy)`` in ``e_k``: position of the reported
  ground point [m], and its velocity **over the ground** [m/s] expressed in the
  axes of ``e_k``. Ground velocity (not velocity relative to the ego car) keeps
  the constant-velocity model exact while the ego car turns or brakes: a parked
  car has v = 0 whatever the ego car does, and the ego motion enters only
  through the change of frame below.
- ``P`` (4, 4): covariance of ``x``.
- ``G`` (4, 4) = blockdiag(Rᵀ, Rᵀ), ``g`` (4,) = (-Rᵀ d, 0): change of frame
  ``e_{k-1} -> e_k``: ``x ← G x + g``, ``P ← G P Gᵀ + J Σ_ego Jᵀ`` with ``J``
  (4, 2) the Jacobian of the new state w.r.t. ``(s, ω)`` and ``Σ_ego`` (2, 2)
  the variance of the ego speed and yaw rate (`TrackerConfig`).
- ``F`` (4, 4): constant-velocity transition, ``[[I, dt I], [0, I]]``.
- ``Q`` (4, 4): process noise of continuous white-noise acceleration of power
  spectral density ``q`` per axis: ``q [[dt³/3 I, dt²/2 I], [dt²/2 I, dt I]]``
  (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking and
  Navigation*, 2001, eq. 6.2.2-12).
- ``x⁻``, ``P⁻``: prior of frame k (after the change of frame and prediction).
- ``z`` (2,): a detection; ``H`` (2, 4) = ``[I 0]``; ``R`` (2, 2) = ``σ(z)² I``
  its noise, ``σ(z) = σ0 + σ1 |z|`` (inverse perspective loses accuracy with
  range).
- ``ν = z - H x⁻``: innovation; ``S = H P⁻ Hᵀ + R``: its covariance;
  ``d² = νᵀ S⁻¹ ν``: squared Mahalanobis distance (the assignment cost).
- ``K = P⁻ Hᵀ S⁻¹``: gain; ``x = x⁻ + K ν``; ``P = (I - K H) P⁻ (I - K H)ᵀ + K R Kᵀ``
  (Joseph form, symmetric and positive for any K).

Detections with a hidden ground point. Where the ground under a vehicle is
hidden (the omni camera's car-body mask), the detector measures the bearing
``β`` of the vehicle well but not its range: it only knows the point is inside
the hidden region, and reports it at an assumed range ``r0`` on that bearing.
Such a detection (``bearing_only``) is a position measurement whose covariance
is elongated along the bearing: std ``hidden_range_sigma_m`` along it, ``r0
σ_β`` across (`TrackerConfig.bearing_sigma_rad`), i.e. ``R = σ_a² u uᵀ + σ_c² v
vᵀ`` with u the unit bearing and v ⟂ u; association, update and births then
follow the linear filter above with that R.

Extended vehicles. The tracked point is a vehicle's nearest *visible* point;
close by (body mask) it jumps between the vehicle's front, side and rear. So the
tracks and detections the point-to-point assignment leaves are assigned again
against each established track's body: the points ``p + o e_x``, o over one
vehicle length (`TrackerConfig.vehicle_length_m`) away from the camera along x;
such a detection updates the track with ``z - o e_x`` (the body point it saw,
moved back to the tracked point).

Detections on the road a vehicle uncovered. A two-frame motion test marks, besides a
moving vehicle, the road it uncovered over the baseline ``Δt_b``: no earlier frame saw that
road, so no hypothesis explains it. The marked region is the vehicle's footprint swept back
along its ground velocity ``v`` over ``Δt_b``, and its nearest point lies up to ``|v| Δt_b``
behind the vehicle's (2.7 m at 20 m/s over two frames at 15 Hz): a vehicle ahead is seen
that far nearer than it is. With ``swept_s = Δt_b`` such a detection measures
``h(x) = p - σ v``, ``σ = clip(p·v / |v|², 0, Δt_b)`` (`swept_measurement`): the whole
sweep where the range falls along all of it, the foot of the perpendicular from the camera
where it passes alongside, none where the vehicle drives towards the camera. ``H = [I, -σ I]``
with σ taken at the prior, so the filter stays linear; a track born from such a detection
starts ``Δt_b v0`` ahead of it. The track's point is then the vehicle's own nearest point.

Per frame (`Tracker.step`): change of frame and prediction of every track;
cost matrix ``d²`` with a gate (``d² > gate_chi2`` or ``|ν| > gate_m``: never
assigned); assignment by `scipy.optimize.linear_sum_assignment`, then of the
rest against the tracks' bodies; update of assigned tracks; births of tentative
tracks from unassigned detections;
confirmation after ``confirm_hits`` hits within the first ``confirm_window``
frames of a track; deletion after ``delete_after_misses`` consecutive misses
(or a tentative track that can no longer be confirmed). Ids come from a
monotonic counter and are never reused. A `StepRecord` per frame keeps what
happened (priors, costs, assignments, births, confirmations, deaths).

``estimator`` imports neither ``sim`` nor ``scenarios``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

_SMALL_PSI = 1e-4  # [rad] below this, f1, f2 and their derivatives use their series


# ------------------------------------------------------------------ config
@dataclass(frozen=True)
class TrackerConfig:
    """Settings of `Tracker` (units beside each value)."""

    # motion model
    accel_psd_m2ps3: float = 4.0  # [m²/s³] q: white-noise acceleration PSD per axis
    ego_speed_sigma_mps: float = 0.3  # [m/s] std of the ego forward speed input
    ego_yaw_rate_sigma_rps: float = 0.01  # [rad/s] std of the ego yaw-rate input
    # measurements
    meas_sigma_m: float = 0.3  # [m] σ0: detection noise std at the camera
    meas_sigma_per_m: float = 0.05  # [m/m] σ1: added std per metre of range (omni: ~1 px
    # of radial error is ~0.6 m at 17 m)
    # births: vehicles around a moving car mostly move with it (the paper's
    # detector finds independently moving vehicles), so the ground velocity
    # prior is the ego velocity, with a wide std
    init_velocity_from_ego: bool = True  # [-] prior mean of v: ego velocity (else 0)
    init_velocity_sigma_mps: float = 10.0  # [m/s] prior std of each velocity component
    # gating: a pair beyond either gate is never assigned
    gate_chi2: float = 9.21  # [-] on d² (chi², 2 dof: 9.21 = 99 %)
    gate_m: float | None = 4.0  # [m] on |ν|; None: no metric gate
    # extended object: a detection that fails the gates at the track's point may still
    # be the same vehicle's nearest visible point at another place along its body (a
    # vehicle alongside: front, side or rear as the body mask hides its ground); it is
    # gated against the segment of this length along x from the track's point, away
    # from the camera (both ways while the track is within half of it of x = 0)
    vehicle_length_m: float = 5.0  # [m] 0: point gating only
    vehicle_length_step_m: float = 0.5  # [m] spacing of the segment's points
    # ... for tracks with at least this many hits: the body keeps an established
    # vehicle's identity, it does not build one from scattered clutter
    body_min_hits: int = 8  # [frames]
    # bearing-only detections (ground hidden)
    bearing_sigma_rad: float = 0.05  # [rad] σ_β: std of a hidden detection's bearing
    hidden_range_sigma_m: float = 2.0  # [m] σ_a: its std along the bearing (range unknown)
    # track management
    confirm_hits: int = 3  # [frames] M: hits needed ...
    confirm_window: int = 4  # [frames] N: ... within the first N frames of a track
    delete_after_misses: int = 5  # [frames] K: consecutive misses that delete a track
    max_tracks: int = 64  # [-] live tracks (tentative included); extra births refused
    max_records: int | None = None  # [-] StepRecords kept (oldest dropped); None: all

    def __post_init__(self) -> None:
        positive = (
            "accel_psd_m2ps3",
            "meas_sigma_m",
            "init_velocity_sigma_mps",
            "gate_chi2",
            "bearing_sigma_rad",
            "hidden_range_sigma_m",
        )
        for name in positive:
            check_positive(f"TrackerConfig.{name}", getattr(self, name))
        for name in ("ego_speed_sigma_mps", "ego_yaw_rate_sigma_rps", "meas_sigma_per_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"TrackerConfig.{name} must be finite and >= 0, got {value!r}")
        if self.gate_m is not None:
            check_positive("TrackerConfig.gate_m", self.gate_m)
        for name in (
            "confirm_hits",
            "confirm_window",
            "delete_after_misses",
            "max_tracks",
            "body_min_hits",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"TrackerConfig.{name} must be an int >= 1, got {value!r}")
        if self.confirm_hits > self.confirm_window:
            raise ValueError(
                f"TrackerConfig.confirm_hits ({self.confirm_hits}) must be <= "
                f"confirm_window ({self.confirm_window})"
            )
        if self.max_records is not None and not (
            isinstance(self.max_records, int) and self.max_records >= 1
        ):
            raise ValueError(
                f"TrackerConfig.max_records must be None or >= 1, got {self.max_records!r}"
            )

    @classmethod
    def from_dict(cls, overrides: dict[str, Any]) -> TrackerConfig:
        """Config with ``overrides`` applied; an unknown key raises with its dotted path."""
        known = {f.name for f in fields(cls)}
        for key in overrides:
            if key not in known:
                raise KeyError(f"unknown setting 'TrackerConfig.{key}' (known: {sorted(known)})")
        return cls(**overrides)


# ------------------------------------------------------------------ checks
def check_positive(name: str, value: float) -> None:
    """Raise ValueError unless ``value`` is a finite number > 0."""
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")


def check_detections(detections_xy: Any) -> np.ndarray:
    """(N, 2) float64 finite road-plane points [m]; an empty input gives (0, 2)."""
    z = np.asarray(detections_xy, dtype=float)
    if z.size == 0:
        return np.zeros((0, 2))
    if z.ndim != 2 or z.shape[1] != 2:
        raise ValueError(f"detections_xy must have shape (N, 2), got {z.shape}")
    if not np.all(np.isfinite(z)):
        raise ValueError(f"detections_xy must be finite, got {z[~np.isfinite(z).all(axis=1)]}")
    return z


# ------------------------------------------------------------------ ego motion
def _f12(psi: float) -> tuple[float, float, float, float]:
    """f1 = sin ψ/ψ, f2 = (1 - cos ψ)/ψ and their derivatives df1/dψ, df2/dψ."""
    if abs(psi) < _SMALL_PSI:  # Taylor series, error O(ψ⁴)
        return 1.0 - psi**2 / 6.0, psi / 2.0 - psi**3 / 24.0, -psi / 3.0, 0.5 - psi**2 / 8.0
    s, c = math.sin(psi), math.cos(psi)
    f1, f2 = s / psi, (1.0 - c) / psi
    return f1, f2, (psi * c - s) / psi**2, (psi * s - (1.0 - c)) / psi**2


def _rot(psi: float) -> np.ndarray:
    """(2, 2) rotation by ψ (counter-clockwise, i.e. towards +y = left)."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s], [s, c]])


def ego_displacement(
    dt_s: float, speed_mps: float, yaw_rate_rps: float, lateral_speed_mps: float = 0.0
) -> tuple[np.ndarray, float]:
    """Motion of the ego road frame over ``dt_s``: (d (2,) [m] in the old frame, ψ [rad]).

    Constant forward speed ``s``, lateral speed ``u`` and yaw rate ``ω``:
    ``d = dt M(ψ) (s, u)``, ``ψ = ω dt`` (module docstring).
    """
    psi = yaw_rate_rps * dt_s
    f1, f2, _, _ = _f12(psi)
    M = np.array([[f1, -f2], [f2, f1]])
    return dt_s * M @ np.array([speed_mps, lateral_speed_mps]), psi


def ego_frame_change(
    dt_s: float, speed_mps: float, yaw_rate_rps: float, lateral_speed_mps: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Affine map of a track state from ``e_{k-1}`` to ``e_k``: ``x' = G x + g``.

    Returns ``G`` (4, 4), ``g`` (4,) and the displacement ``d`` (2,) [m] of
    `ego_displacement`. The Jacobian of ``x'`` w.r.t. the ego-motion inputs
    depends on ``x``: `frame_change_input_jacobian`.
    """
    d, psi = ego_displacement(dt_s, speed_mps, yaw_rate_rps, lateral_speed_mps)
    Rt = _rot(psi).T
    G = np.zeros((4, 4))
    G[:2, :2] = Rt
    G[2:, 2:] = Rt
    g = np.concatenate([-Rt @ d, np.zeros(2)])
    return G, g, d


def frame_change_input_jacobian(
    x: np.ndarray,
    dt_s: float,
    speed_mps: float,
    yaw_rate_rps: float,
    lateral_speed_mps: float = 0.0,
) -> np.ndarray:
    """(4, 2) Jacobian of the state in ``e_k`` w.r.t. (s, ω), at the old state ``x`` (4,).

    With ``p' = Rᵀ(ψ) (p - d)``, ``v' = Rᵀ(ψ) v``, ``ψ = ω dt``,
    ``dRᵀ/dψ = -Rᵀ S`` (S = [[0, -1], [1, 0]]):
    ``dp'/ds = -Rᵀ dd/ds``, ``dp'/dω = -dt Rᵀ S (p - d) - Rᵀ dd/dω``,
    ``dv'/ds = 0``, ``dv'/dω = -dt Rᵀ S v``, where ``dd/ds = dt M (1, 0)`` and
    ``dd/dω = dt² M'(ψ) (s, u)``.
    """
    psi = yaw_rate_rps * dt_s
    f1, f2, df1, df2 = _f12(psi)
    M = np.array([[f1, -f2], [f2, f1]])
    dM = np.array([[df1, -df2], [df2, df1]])
    su = np.array([speed_mps, lateral_speed_mps])
    d = dt_s * M @ su
    dd_ds = dt_s * M[:, 0]
    dd_dw = dt_s**2 * dM @ su
    Rt = _rot(psi).T
    S = np.array([[0.0, -1.0], [1.0, 0.0]])
    p, v = x[:2], x[2:]
    J = np.zeros((4, 2))
    J[:2, 0] = -Rt @ dd_ds
    J[:2, 1] = -dt_s * Rt @ S @ (p - d) - Rt @ dd_dw
    J[2:, 1] = -dt_s * Rt @ S @ v
    return J


def cv_transition(dt_s: float, accel_psd: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity ``F`` (4, 4) and white-noise-acceleration ``Q`` (4, 4)."""
    I2 = np.eye(2)
    F = np.block([[I2, dt_s * I2], [np.zeros((2, 2)), I2]])
    # Q = q [[dt³/3, dt²/2], [dt²/2, dt]] ⊗ I (Bar-Shalom et al. 2001, eq. 6.2.2-12)
    Q = accel_psd * np.block([[dt_s**3 / 3 * I2, dt_s**2 / 2 * I2], [dt_s**2 / 2 * I2, dt_s * I2]])
    return F, Q


_H = np.hstack([np.eye(2), np.zeros((2, 2))])  # (2, 4) position measurement


def swept_measurement(X: np.ndarray, swept_s: np.ndarray) -> np.ndarray:
    """(T, N, 2, 4) measurement matrices of tracks X (T, 4) for detections that are the
    nearest point of the road each vehicle covered over the last swept_s (N,) [s].

    A moving vehicle's motion mask holds the road it uncovered over the baseline: its
    footprint swept back along its ground velocity v over swept_s. Where that carries
    its nearest point nearer the camera (p . v > 0), the measured point is
    ``p - sigma v``, sigma = clip(p . v / |v|², 0, swept_s): the whole sweep when the
    range falls all along it, else the foot of the perpendicular from the camera
    (a box alongside). H = [I, -sigma I], sigma taken at the prior (its own dependence
    on the state left out); swept_s = 0 gives [I 0].
    """
    p, v = X[:, :2], X[:, 2:]
    v2 = np.maximum(np.einsum("ti,ti->t", v, v), 1e-9)
    along = np.einsum("ti,ti->t", p, v) / v2  # (T,) [s] of the sweep to the foot
    sigma = np.clip(along[:, None], 0.0, np.asarray(swept_s, float)[None, :])  # (T, N)
    H = np.zeros((len(X), len(swept_s), 2, 4))
    H[..., 0, 0] = H[..., 1, 1] = 1.0
    H[..., 0, 2] = H[..., 1, 3] = -sigma
    return H


# ------------------------------------------------------------------ tracks
@dataclass
class Track:
    """One tracked vehicle.

    x (4,): (x, y, vx, vy) in the current ego road frame: position [m] of the
    vehicle's nearest ground point, velocity over the ground [m/s] in ego axes.
    P (4, 4): its covariance. hits: frames with a detection; misses: consecutive
    frames without one (0 after a hit); age: frames since birth, birth included;
    confirmed: passed M-of-N (stays True until deletion). history: (t [s], x, y)
    per frame alive, in the ego road frame of that frame; history_odom: the same
    points in the odometry frame (the ego road frame of the tracker's first
    frame, integrated from the ego-motion inputs). extra: the per-detection extra
    info of the last detection assigned (e.g. blob size), None if none given.
    """

    id: int
    x: np.ndarray
    P: np.ndarray
    hits: int = 1
    misses: int = 0
    age: int = 1
    confirmed: bool = False
    history: list[tuple[float, float, float]] = field(default_factory=list)
    history_odom: list[tuple[float, float, float]] = field(default_factory=list)
    extra: Any = None

    @property
    def position_xy(self) -> np.ndarray:
        """(2,) position in the current ego road frame [m]."""
        return self.x[:2].copy()

    @property
    def velocity_xy(self) -> np.ndarray:
        """(2,) velocity over the ground, in current ego axes [m/s]."""
        return self.x[2:].copy()

    @property
    def position_cov(self) -> np.ndarray:
        """(2, 2) covariance of the position [m²]."""
        return self.P[:2, :2].copy()


@dataclass
class StepRecord:
    """What `Tracker.step` did in one frame (for inspection and plots).

    track_ids: tracks alive before association (rows of ``d2``); priors: their
    ``x⁻`` (T, 4); d2: (T, N) squared Mahalanobis distances, ``inf`` where the
    gate forbids the pair; assignments: (track id, detection index, d²);
    innovations: track id -> ν (2,) [m] of its assigned detection.
    """

    t_s: float
    dt_s: float | None
    ego_displacement_m: np.ndarray  # (2,) in the previous ego road frame
    ego_yaw_change_rad: float
    n_detections: int
    track_ids: list[int] = field(default_factory=list)
    priors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    d2: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    assignments: list[tuple[int, int, float]] = field(default_factory=list)
    innovations: dict[int, np.ndarray] = field(default_factory=dict)
    missed: list[int] = field(default_factory=list)  # track ids without a detection
    unassigned: list[int] = field(default_factory=list)  # detection indices
    births: list[int] = field(default_factory=list)  # new track ids
    refused_births: list[int] = field(default_factory=list)  # detection indices (max_tracks)
    confirmations: list[int] = field(default_factory=list)
    deaths: list[tuple[int, str]] = field(default_factory=list)  # (track id, reason)


# ------------------------------------------------------------------ assignment
def gated_assignment(cost: np.ndarray, allowed: np.ndarray) -> list[tuple[int, int]]:
    """Minimum-cost assignment that never uses a forbidden pair.

    cost: (T, N) finite where ``allowed``; allowed: (T, N) bool. Forbidden pairs
    get a cost larger than any sum of allowed costs, so
    `scipy.optimize.linear_sum_assignment` first maximises the number of allowed
    pairs and then minimises their total cost; forbidden pairs it had to use to
    complete its assignment are dropped. Returns (row, column) pairs.
    """
    cost = np.asarray(cost, dtype=float)
    allowed = np.asarray(allowed, dtype=bool)
    if cost.size == 0 or not allowed.any():
        return []
    c = cost[allowed]
    c = c - min(0.0, float(c.min()))  # non-negative: the bound below then holds
    big = 1.0 + min(cost.shape) * (float(c.max()) + 1.0)
    work = np.full(cost.shape, big)
    work[allowed] = c
    rows, cols = linear_sum_assignment(work)
    return [(int(r), int(k)) for r, k in zip(rows, cols, strict=True) if allowed[r, k]]


# ------------------------------------------------------------------ tracker
class Tracker:
    """Multi-vehicle tracker on the road plane (module docstring for the model).

    ``step`` once per frame, with strictly increasing times. The odometry pose
    ``pose_odom_ego`` = (x [m], y [m], yaw [rad]) of the current ego road frame
    in the first frame's, integrated from the same ego-motion inputs.
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config if config is not None else TrackerConfig()
        self.reset()

    def reset(self) -> None:
        """Forget all tracks and records (ids keep counting: never reused)."""
        self._tracks: list[Track] = []
        self._t_prev: float | None = None
        self._next_id = getattr(self, "_next_id", 1)
        self.pose_odom_ego = np.zeros(3)
        self.records: deque[StepRecord] = deque(maxlen=self.config.max_records)

    # -------------------------------------------------------------- views
    @property
    def tracks(self) -> list[Track]:
        """All live tracks, tentative included, by id."""
        return list(self._tracks)

    @property
    def confirmed_tracks(self) -> list[Track]:
        """Live confirmed tracks, by id."""
        return [t for t in self._tracks if t.confirmed]

    # -------------------------------------------------------------- model
    def measurement_cov(self, z: np.ndarray, bearing_only: bool = False) -> np.ndarray:
        """(2, 2) R [m²] of one detection at z (2,) [m]: `_meas_cov`, or `_hidden_cov`
        for a detection whose ground point is hidden."""
        z = np.asarray(z, float)
        return self._hidden_cov(z) if bearing_only else self._meas_cov(z)

    def _meas_cov(self, z: np.ndarray) -> np.ndarray:
        """(2, 2) R for a detection at z: σ(z)² I, σ = σ0 + σ1 |z|."""
        sigma = self.config.meas_sigma_m + self.config.meas_sigma_per_m * float(np.hypot(*z))
        return sigma**2 * np.eye(2)

    def _predict(self, track: Track, dt: float, s: float, w: float, u: float) -> None:
        cfg = self.config
        # change of frame e_{k-1} -> e_k: x ← G x + g, P ← G P Gᵀ + J Σ_ego Jᵀ
        G, g, _ = ego_frame_change(dt, s, w, u)
        J = frame_change_input_jacobian(track.x, dt, s, w, u)
        sigma_ego = np.diag([cfg.ego_speed_sigma_mps**2, cfg.ego_yaw_rate_sigma_rps**2])
        x = G @ track.x + g
        P = G @ track.P @ G.T + J @ sigma_ego @ J.T
        # prediction: x⁻ = F x, P⁻ = F P Fᵀ + Q
        F, Q = cv_transition(dt, cfg.accel_psd_m2ps3)
        track.x = F @ x
        track.P = F @ P @ F.T + Q
        track.P = 0.5 * (track.P + track.P.T)

    def _update(self, track: Track, z: np.ndarray, R: np.ndarray, H: np.ndarray = _H) -> np.ndarray:
        # ν = z - H x⁻ ; S = H P⁻ Hᵀ + R ; K = P⁻ Hᵀ S⁻¹
        nu = z - H @ track.x
        S = H @ track.P @ H.T + R
        K = np.linalg.solve(S, H @ track.P).T  # P⁻ Hᵀ S⁻¹ (S, P symmetric)
        # x = x⁻ + K ν ; P = (I - K H) P⁻ (I - K H)ᵀ + K R Kᵀ (Joseph form)
        track.x = track.x + K @ nu
        IKH = np.eye(4) - K @ H
        track.P = IKH @ track.P @ IKH.T + K @ R @ K.T
        track.P = 0.5 * (track.P + track.P.T)
        return nu

    def _gated_d2(
        self, z_pred: np.ndarray, S_inv: np.ndarray, z_all: np.ndarray, bo: np.ndarray
    ) -> np.ndarray:
        """(T, N) d² of the detections z_all (N, 2) to the predicted measurements
        z_pred (T, N, 2) with inverse innovation covariances S_inv (T, N, 2, 2); inf
        beyond either gate."""
        cfg = self.config
        nu = z_all[None, :, :] - z_pred  # (T, N, 2) ν = z - H x⁻
        d2 = np.einsum("tni,tnij,tnj->tn", nu, S_inv, nu)  # d² = νᵀ S⁻¹ ν
        if cfg.gate_m is not None:
            # metric gate; a hidden detection's range is not known: its range error
            # counts up to hidden_range_sigma_m less
            dist = np.linalg.norm(nu, axis=2)
            for j in np.flatnonzero(bo):
                ub = z_all[j] / max(float(np.linalg.norm(z_all[j])), 1e-6)
                along = np.abs(nu[:, j] @ ub)
                across = np.abs(nu[:, j] @ np.array([-ub[1], ub[0]]))
                dist[:, j] = np.hypot(np.maximum(along - cfg.hidden_range_sigma_m, 0), across)
            d2[dist > cfg.gate_m] = np.inf
        d2[d2 > cfg.gate_chi2] = np.inf
        return d2

    def _body_offsets(self, x_m: np.ndarray) -> list[tuple[float, np.ndarray]]:
        """(offset along x [m], (T,) bool: tracks whose body reaches it) for the points
        of the extended body, nearest first; the body lies away from the camera along
        x from the track's point x_m (T,), either way within half a length of 0."""
        L = self.config.vehicle_length_m
        step = self.config.vehicle_length_step_m
        if L <= 0:
            return []
        n = max(1, int(round(L / step)))
        out = []
        for o in np.linspace(step, L, n):
            out.append((float(-o), x_m < 0.5 * L))  # body behind the point
            out.append((float(o), x_m > -0.5 * L))  # body ahead of the point
        return out

    def _hidden_cov(self, z: np.ndarray) -> np.ndarray:
        """(2, 2) R of a detection at z whose ground point is hidden (module docstring)."""
        r = max(float(np.hypot(*z)), 1e-3)
        u = z / r
        v = np.array([-u[1], u[0]])
        along, across = self.config.hidden_range_sigma_m, r * self.config.bearing_sigma_rad
        return along**2 * np.outer(u, u) + across**2 * np.outer(v, v)

    def _birth(
        self, z: np.ndarray, R: np.ndarray, s: float, u: float, extra: Any, swept_s: float = 0.0
    ) -> Track:
        cfg = self.config
        v0 = np.array([s, u]) if cfg.init_velocity_from_ego else np.zeros(2)
        P0 = np.zeros((4, 4))
        P0[:2, :2] = R
        P0[2:, 2:] = cfg.init_velocity_sigma_mps**2 * np.eye(2)
        # a point on the road the vehicle uncovered: the vehicle is swept_s v0 ahead of it
        # (the inverse of `swept_measurement` where the range falls along the whole sweep)
        p0 = z + swept_s * v0 if float(z @ v0) > 0 else z
        track = Track(id=self._next_id, x=np.concatenate([p0, v0]), P=P0, extra=extra)
        self._next_id += 1
        return track

    # -------------------------------------------------------------- step
    def step(
        self,
        t_s: float,
        detections_xy: np.ndarray,
        ego_speed_mps: float,
        ego_yaw_rate_rps: float,
        *,
        extras: Sequence[Any] | None = None,
        ego_lateral_speed_mps: float = 0.0,
        bearing_only: Sequence[bool] | None = None,
        swept_s: Sequence[float] | None = None,
    ) -> list[Track]:
        """Process one frame; return the confirmed tracks after the update, by id.

        t_s: frame time [s], strictly increasing. detections_xy: (N, 2) road-plane
        points in the ego road frame of this frame [m]. ego_speed_mps,
        ego_yaw_rate_rps (and ego_lateral_speed_mps): motion of the ego road frame
        from the previous frame to this one [m/s], [rad/s] (ignored on the first
        frame). extras: optional per-detection info (length N), kept on the track
        it updates or creates. bearing_only: optional (N,) flags: that detection's
        ground point is hidden, its range is uncertain (module docstring). swept_s:
        optional (N,) [s]: the detection is the nearest point of the road a vehicle
        covered over this time before the frame (module docstring); 0: of the vehicle.
        Returned tracks include confirmed tracks that missed this frame
        (``misses > 0``: coasting on their prediction).
        """
        cfg = self.config
        t_s = float(t_s)
        z_all = check_detections(detections_xy)
        n_det = len(z_all)
        for name, value in (
            ("t_s", t_s),
            ("ego_speed_mps", ego_speed_mps),
            ("ego_yaw_rate_rps", ego_yaw_rate_rps),
            ("ego_lateral_speed_mps", ego_lateral_speed_mps),
        ):
            if not math.isfinite(float(value)):
                raise ValueError(f"{name} must be finite, got {value!r}")
        if extras is not None and len(extras) != n_det:
            raise ValueError(
                f"extras must have one entry per detection ({n_det}), got {len(extras)}"
            )
        if bearing_only is None:
            bo = np.zeros(n_det, bool)
        else:
            bo = np.asarray(bearing_only, bool).reshape(-1)
            if len(bo) != n_det:
                raise ValueError(
                    f"bearing_only must have one flag per detection ({n_det}), got {len(bo)}"
                )
        sw = np.zeros(n_det) if swept_s is None else np.asarray(swept_s, float).reshape(-1)
        if len(sw) != n_det or not np.all(np.isfinite(sw) & (sw >= 0)):
            raise ValueError(
                f"swept_s must hold one finite time >= 0 per detection ({n_det}), got {swept_s!r}"
            )
        if self._t_prev is not None and not t_s > self._t_prev:
            raise ValueError(f"t_s must increase: got {t_s} after {self._t_prev}")
        s, w, u = float(ego_speed_mps), float(ego_yaw_rate_rps), float(ego_lateral_speed_mps)

        # 1. ego-motion compensation and prediction
        dt = None if self._t_prev is None else t_s - self._t_prev
        if dt is None:
            d, psi = np.zeros(2), 0.0
        else:
            d, psi = ego_displacement(dt, s, w, u)
            for track in self._tracks:
                self._predict(track, dt, s, w, u)
            # odometry pose: T_odo_ek = T_odo_ek-1 ∘ (d, ψ)
            x0, y0, yaw0 = self.pose_odom_ego
            dx, dy = _rot(yaw0) @ d
            self.pose_odom_ego = np.array([x0 + dx, y0 + dy, yaw0 + psi])
        self._t_prev = t_s
        rec = StepRecord(t_s, dt, d, psi, n_det)
        rec.track_ids = [t.id for t in self._tracks]
        rec.priors = np.array([t.x for t in self._tracks]).reshape(-1, 4)

        # 2. gated Mahalanobis costs, all pairs at once; d2_body: the same against the
        # points of each track's extended body (offset_m along x), for the pairs the
        # point-to-point assignment leaves
        Rs = [self.measurement_cov(z, b) for z, b in zip(z_all, bo, strict=True)]
        n_trk = len(self._tracks)
        d2 = np.full((n_trk, n_det), np.inf)
        d2_body = np.full((n_trk, n_det), np.inf)
        offset_m = np.zeros((n_trk, n_det))  # [m] along x: where on the body z was seen
        H = np.broadcast_to(_H, (n_trk, n_det, 2, 4)).copy()  # per pair: swept_measurement
        if n_trk and n_det:
            X = np.array([t.x for t in self._tracks])  # (T, 4)
            x_prior = X[:, :2]
            P = np.array([t.P for t in self._tracks])  # (T, 4, 4)
            H = swept_measurement(X, sw)
            z_pred = np.einsum("tnij,tj->tni", H, X)  # (T, N, 2) H x⁻
            HP = np.einsum("tnij,tjk->tnik", H, P)
            S = np.einsum("tnik,tnjk->tnij", HP, H) + np.array(Rs)[None]  # H P⁻ Hᵀ + R
            S_inv = np.linalg.inv(S)  # once: the body's points share it
            d2 = self._gated_d2(z_pred, S_inv, z_all, bo)
            for o, sel in self._body_offsets(x_prior[:, 0]):
                shift = np.outer(sel * o, [1.0, 0.0])[:, None, :]
                d2_o = self._gated_d2(z_pred + shift, S_inv, z_all, bo)
                better = (d2_o < d2_body) & sel[:, None]
                d2_body = np.where(better, d2_o, d2_body)
                offset_m = np.where(better, o, offset_m)
        allowed = np.isfinite(d2)
        rec.d2 = np.where(allowed, d2, np.inf)

        # 3. assignment (the tracks' points first, then their bodies) and update
        pairs = gated_assignment(np.where(allowed, d2, 0.0), allowed)
        offset_m[tuple(np.array(pairs, int).reshape(-1, 2).T)] = 0.0
        body = np.isfinite(d2_body)
        body[[i for i, _ in pairs]] = False
        body[[i for i, t in enumerate(self._tracks) if t.hits < cfg.body_min_hits]] = False
        body[:, [j for _, j in pairs]] = False
        pairs += gated_assignment(np.where(body, d2_body, 0.0), body)
        assigned_tracks = {i for i, _ in pairs}
        assigned_dets = {j for _, j in pairs}
        for i, j in pairs:
            track = self._tracks[i]
            # the detection measures the body point at offset_m: the track's point is there
            z_point = z_all[j] - np.array([offset_m[i, j], 0.0])
            rec.innovations[track.id] = self._update(track, z_point, Rs[j], H[i, j])
            rec.assignments.append((track.id, j, float(d2[i, j])))
            track.hits += 1
            track.misses = 0
            if extras is not None:
                track.extra = extras[j]
        for i, track in enumerate(self._tracks):
            track.age += 1
            if i not in assigned_tracks:
                track.misses += 1
                rec.missed.append(track.id)

        # 4. confirmation and deletion of existing tracks
        alive = []
        for track in self._tracks:
            if not track.confirmed and track.hits >= cfg.confirm_hits:
                track.confirmed = True
                rec.confirmations.append(track.id)
            if track.misses >= cfg.delete_after_misses:
                rec.deaths.append((track.id, f"{track.misses} consecutive misses"))
            elif not track.confirmed and (
                track.hits + max(0, cfg.confirm_window - track.age) < cfg.confirm_hits
            ):
                rec.deaths.append(
                    (
                        track.id,
                        f"tentative: {track.hits} hits in {track.age} frames, "
                        f"cannot reach {cfg.confirm_hits} of {cfg.confirm_window}",
                    )
                )
            else:
                alive.append(track)
        self._tracks = alive

        # 5. births from unassigned detections
        rec.unassigned = [j for j in range(n_det) if j not in assigned_dets]
        for j in rec.unassigned:
            if len(self._tracks) >= cfg.max_tracks:
                rec.refused_births.append(j)
                continue
            extra = None if extras is None else extras[j]
            track = self._birth(z_all[j], Rs[j], s, u, extra, float(sw[j]))
            if cfg.confirm_hits <= 1:
                track.confirmed = True
                rec.confirmations.append(track.id)
            self._tracks.append(track)
            rec.births.append(track.id)

        # 6. history
        c, sn = math.cos(self.pose_odom_ego[2]), math.sin(self.pose_odom_ego[2])
        for track in self._tracks:
            px, py = float(track.x[0]), float(track.x[1])
            track.history.append((t_s, px, py))
            track.history_odom.append(
                (
                    t_s,
                    float(self.pose_odom_ego[0] + c * px - sn * py),
                    float(self.pose_odom_ego[1] + sn * px + c * py),
                )
            )
        self.records.append(rec)
        return self.confirmed_tracks
