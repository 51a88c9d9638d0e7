"""Iterated extended Kalman filter of the ego-motion state (paper section 4, eq. 14-21).

Symbols (one frame pair a -> b):

- ``x`` (9,): state (V, W, A) of `estimator.egomotion.homography` (V [m/s], W [rad/s], A [rad],
  nominal camera frame c); ``x̂`` its current estimate.
- ``P`` (9, 9): covariance of ``x̂``.
- ``x⁻``, ``P⁻``: the prior of this frame pair, i.e. the previous posterior moved
  forward by the time update (eq. 19: ``x⁻ = B x̂``, ``P⁻ = B P Bᵀ + Q``) and
  corrected by the CAN speed (`can_speed_update`; a CAN speed that rules the
  predicted one out first re-initialises V and W, `can_consistent`, `reset_speed`).
- ``B`` (9, 9), ``Q`` (9, 9): state transition and process noise (`transition`); A of
  the next pair is A plus the roll/pitch part of the rotation W measured over this one.
- ``z``: the measurements, one per image point: the brightness of image A at the
  point. The model predicts it as the brightness of image B at the warped
  pixel ``w_b(x)``.
- ``Δz`` (N,): innovation at ``x̂``: ``Δz = -g_t``, with ``g_t = B(w_b(x̂)) - A(w_a)``
  the temporal gradient (eq. 15).
- ``C`` (N, 9): Jacobian of the predicted measurement, ``C_i = g_iᵀ dw_b/dx``
  (eq. 14, 16; `estimator.egomotion.motion_model.constraint_rows`).
- ``R`` (N,): measurement noise variances (diagonal), [intensity²].

Measurement update, iterated (each iteration relinearises at the new x̂; it is a
Gauss-Newton step on the posterior cost, the prior term keeps it a MAP estimate):

- eq. 17: ``P ← [Cᵀ R⁻¹ C + P⁻⁻¹]⁻¹``
- eq. 18: ``x̂ ← x̂ + P [Cᵀ R⁻¹ Δz − P⁻⁻¹ (x̂ − x⁻)]``

Outliers (section 4.1): data snooping compares each point's residual with its
expected variance, ``R + C_i P C_iᵀ`` if the point is currently excluded (eq. 20),
``R − C_i P C_iᵀ`` if it is included (eq. 21), and reclassifies all points every
iteration (`data_snooping`). Robust-M reweighting (Huber or Tukey) is the
alternative (`robust_weights`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.egomotion.homography import A_SLICE, N_STATE, V_SLICE, W_SLICE, check_state
from estimator.geometry import road_normal

_MIN_INLIER_VAR = 0.05  # eq. 21 variance is floored at this fraction of R (never <= 0)


@dataclass(frozen=True)
class FilterConfig:
    """Process model, priors and CAN noise of the filter: one line each, [unit] and range
    (checked by `estimator.egomotion.direct_config.check_settings`).

    Axes "forward / lateral / vertical" are the car's x, y, z; "plane / normal"
    split A into rotations about axes in the road plane (roll, pitch: vibration)
    and about the road normal (yaw of the camera on its mount: rigid).
    """

    # time update (eq. 19)
    # random walk of V, forward / lateral / vertical in car axes [m/s/sqrt(s)], >= 0 each
    V_walk_mps: tuple[float, float, float] = (1.5, 0.5, 0.2)
    W_walk_rps: float = 0.3  # random walk of the roll/pitch rates [rad/s/sqrt(s)], >= 0
    W_walk_yaw_rps: float = 0.1  # random walk of the yaw rate [rad/s/sqrt(s)], >= 0
    W_tau_s: float = 0.5  # roll/pitch rates decay to 0 over unmeasured pairs [s], > 0 (inf: kept)
    A_from_W: bool = True  # A moves with the roll/pitch part of W between frame pairs
    A_walk_rad: float = float(np.radians(0.1))  # roll/pitch change W leaves [rad/sqrt(s)], >= 0
    A_tau_s: float = 1.0  # correlation time of A, reverting to the mount [s], > 0
    rate_bias_tau_s: float = 0.0  # averaging time of the roll/pitch rates' bias [s], >= 0 (0: off)
    A_sigma_plane_rad: float = float(np.radians(1.0))  # prior std of A's roll/pitch [rad], > 0
    A_sigma_normal_rad: float = float(np.radians(0.05))  # stationary std of A's yaw [rad], > 0
    # prior of the first frame pair (before the CAN speed)
    # prior std of V, forward / lateral / vertical in car axes [m/s], > 0 each
    V0_sigma_mps: tuple[float, float, float] = (30.0, 1.0, 0.3)
    W0_sigma_rps: float = 0.2  # prior std of W [rad/s], > 0
    # CAN speed (a pseudo-measurement of the forward speed, `can_speed_update`)
    can_rel_sigma: float = 0.12  # relative std of the CAN speed [-], >= 0
    can_abs_sigma_mps: float = 0.3  # absolute std of the CAN speed [m/s], > 0
    nonholonomic_sigma_mps: float = 0.2  # std of the rear axle's side slip [m/s], >= 0 (0: off)
    vertical_speed_sigma_mps: float = 0.0  # std of the road-normal speed [m/s], >= 0 (0: off)
    can_gate_rel: float = 0.3  # relative CAN disagreement that resets V [-], >= 0 (0: never)
    # time gaps
    nominal_dt_s: float | None = None  # expected frame interval [s], > 0; None: learnt
    gap_factor: float = 2.5  # dt beyond this x the nominal is a gap [-], >= 1


def _car_cov(R_car_cam: np.ndarray, sig_car: tuple[float, float, float]) -> np.ndarray:
    """(3, 3) covariance in camera axes of a diagonal one in car axes (std sig_car)."""
    return R_car_cam.T @ np.diag(np.square(sig_car)) @ R_car_cam


def _A_cov(K0: np.ndarray, sig_plane: float, sig_normal: float) -> np.ndarray:
    """(3, 3) covariance of A: sig_normal about the road normal, sig_plane across."""
    n = road_normal(K0)
    nn = np.outer(n, n)
    return sig_plane**2 * (np.eye(3) - nn) + sig_normal**2 * nn


def stationary_A_cov(cfg: FilterConfig, K0: np.ndarray) -> np.ndarray:
    """(3, 3) stationary covariance of A's Gauss-Markov process (`transition`): in the road
    plane ``A_walk_rad² A_tau_s / 2`` (the part W does not explain), ``A_sigma_normal_rad²``
    about the normal."""
    sig_plane = cfg.A_walk_rad * math.sqrt(cfg.A_tau_s / 2.0)
    return _A_cov(K0, sig_plane, cfg.A_sigma_normal_rad)


def initial_prior(
    cfg: FilterConfig, R_car_cam: np.ndarray, K0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(x (9,), P (9, 9)) before any measurement: V = W = A = 0, wide on the forward speed."""
    P = np.zeros((N_STATE, N_STATE))
    P[V_SLICE, V_SLICE] = _car_cov(R_car_cam, cfg.V0_sigma_mps)
    P[W_SLICE, W_SLICE] = np.eye(3) * cfg.W0_sigma_rps**2
    P[A_SLICE, A_SLICE] = _A_cov(K0, cfg.A_sigma_plane_rad, cfg.A_sigma_normal_rad)
    return np.zeros(N_STATE), P


def transition(
    dt_s: float, cfg: FilterConfig, R_car_cam: np.ndarray, K0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(B (9, 9), Q (9, 9)) of the time update over dt [s] (eq. 19).

    V: random walk. W: random walk, ``W_walk_rps`` about axes in the road plane (roll
    and pitch rates, which vibration makes oscillate) and ``W_walk_yaw_rps`` about the
    road normal n (the car's yaw rate). A: the state of a frame pair (t, t + dt) holds A
    at t and the rotation W over the pair, so the next pair's A is, to first order,
    ``A + Π W dt`` with ``Π = I - n nᵀ`` (``A_from_W``): the roll/pitch of the camera
    relative to the road changes by the roll/pitch rotation measured between the frames
    (the yaw part is the car turning, which leaves the mount alone). On top of that A
    is a first-order Gauss-Markov process towards the nominal mount (A = 0):
    ``A_k+1 = rho (A_k + Π W_k dt) + noise``, ``rho = exp(-dt / A_tau_s)``, with noise
    ``A_walk_rad`` (changes W does not explain, e.g. road slope) in the plane and
    ``A_sigma_normal_rad² (1 - rho²)`` about the normal (the rigid mount's yaw keeps its
    stationary std).
    """
    n = road_normal(K0)
    nn = np.outer(n, n)
    Pi = np.eye(3) - nn
    rho = float(np.exp(-dt_s / cfg.A_tau_s))
    B = np.eye(N_STATE)
    B[A_SLICE, A_SLICE] *= rho
    if cfg.A_from_W:
        B[A_SLICE, W_SLICE] = rho * Pi * dt_s
    Q = np.zeros((N_STATE, N_STATE))
    Q[V_SLICE, V_SLICE] = _car_cov(R_car_cam, cfg.V_walk_mps) * dt_s
    Q[W_SLICE, W_SLICE] = (cfg.W_walk_rps**2 * Pi + cfg.W_walk_yaw_rps**2 * nn) * dt_s
    Q[A_SLICE, A_SLICE] = (
        cfg.A_walk_rad**2 * dt_s * Pi + cfg.A_sigma_normal_rad**2 * (1 - rho**2) * nn
    )
    return B, Q


def time_update(
    x: np.ndarray, P: np.ndarray, B: np.ndarray, Q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """eq. 19: ``x ← B x``, ``P ← B P Bᵀ + Q``."""
    # eq. 19: time update
    return B @ x, _sym(B @ P @ B.T + Q)


def scalar_update(
    x: np.ndarray, P: np.ndarray, h: np.ndarray, z: float, var: float
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with one linear measurement ``z = h x + e``, ``e ~ N(0, var)``."""
    Ph = P @ h
    k = Ph / (float(h @ Ph) + var)
    return x + k * (z - float(h @ x)), _sym(P - np.outer(k, Ph))


def nonholonomic_row(lever_m: float, R_car_cam: np.ndarray) -> np.ndarray:
    """(9,) h with ``h x`` = the rear axle's sideways speed [m/s] (`nonholonomic_update`)."""
    h = np.zeros(N_STATE)
    h[V_SLICE] = R_car_cam[1]
    h[W_SLICE] = -lever_m * R_car_cam[2]
    return h


def yaw_direction(lever_m: float | None, R_car_cam: np.ndarray) -> np.ndarray:
    """(9,) change of x per unit of the car's yaw rate [rad/s]: W about the car's z and,
    when the rear axle is known (lever_m [m]), the sideways speed ``lever_m x yaw rate``
    that the kinematic model ties to it (``nonholonomic_row(lever_m, R) @ g == 0``)."""
    g = np.zeros(N_STATE)
    g[W_SLICE] = R_car_cam[2]
    if lever_m is not None:
        g[V_SLICE] = lever_m * R_car_cam[1]
    return g


def nonholonomic_update(
    x: np.ndarray, P: np.ndarray, lever_m: float, R_car_cam: np.ndarray, sigma_mps: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-measurement of the kinematic vehicle model: the rear axle does not slide.

    A rigid car whose rear axle r moves straight ahead moves the viewpoint p sideways
    at ``v_lat(p) = yaw_rate * (p_x - r_x)`` (v(p) = v(r) + W x (p - r)). Measured:
    ``(R_car_cam V)[1] - lever_m (R_car_cam W)[2] = 0`` with std ``sigma_mps``. It ties
    the sideways speed to the yaw rate, two motions that a narrow view (or a slow car)
    hardly tells apart.
    """
    return scalar_update(x, P, nonholonomic_row(lever_m, R_car_cam), 0.0, sigma_mps**2)


def vertical_speed_update(
    x: np.ndarray, P: np.ndarray, K0: np.ndarray, sigma_mps: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-measurement of a car that stays on the road: the camera does not move along
    the road normal n (``n . V = 0`` with std ``sigma_mps``, the body's heave).

    On a narrow view of the road (a pinhole's one lane) a speed along the normal moves
    the points much as a tilt of the plane and a roll rate do; the car's kinematics
    tell it where the images hardly can.
    """
    h = np.zeros(N_STATE)
    h[V_SLICE] = road_normal(K0)
    return scalar_update(x, P, h, 0.0, sigma_mps**2)


def can_row(R_car_cam: np.ndarray, offset_y_m: float = 0.0) -> np.ndarray:
    """(9,) h with ``h x`` = the forward speed of the car's centreline [m/s]: what the CAN
    (wheel) speed measures.

    A rigid car turning at yaw rate r moves a viewpoint ``offset_y_m`` to the left of its
    centreline forward at ``v - r y`` (v(p) = v(o) + W x (p - o)), so
    ``h x = (R_car_cam V)[0] + y (R_car_cam W)[2]``. A side camera (y = 0.95 m) in a
    22 deg/s turn would otherwise read a CAN speed 0.36 m/s (5 % at 7.5 m/s) off.
    """
    h = np.zeros(N_STATE)
    h[V_SLICE] = R_car_cam[0]
    h[W_SLICE] = offset_y_m * R_car_cam[2]
    return h


def can_speed_update(
    x: np.ndarray,
    P: np.ndarray,
    v_can_mps: float,
    R_car_cam: np.ndarray,
    cfg: FilterConfig,
    offset_y_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with the CAN speed as a measurement of the car's forward speed.

    The measured quantity is the forward speed of the car's centreline (`can_row`: the
    viewpoint's ``(R_car_cam V)[0]`` plus ``offset_y_m`` times the yaw rate); its std is
    ``can_rel_sigma |v| + can_abs_sigma_mps``. On the first frame pair (wide prior) this
    sets ``V⁻ ≈ R_cam_car (v_can, 0, 0)``.
    """
    var = (cfg.can_rel_sigma * abs(v_can_mps) + cfg.can_abs_sigma_mps) ** 2
    return scalar_update(x, P, can_row(R_car_cam, offset_y_m), v_can_mps, var)


def can_consistent(
    x: np.ndarray,
    P: np.ndarray,
    v_can_mps: float,
    R_car_cam: np.ndarray,
    cfg: FilterConfig,
    offset_y_m: float = 0.0,
) -> bool:
    """False when the CAN speed rules out the predicted forward speed (gross error).

    The CAN speed has a bounded scale error (tyres, calibration: ~10 %); a predicted
    forward speed (`can_row`) further from it than ``can_gate_rel |v_can|`` plus
    3 sigma (prediction and CAN noise) cannot be right: the images locked onto a wrong
    solution (e.g. yaw traded for speed when the road ahead and behind is hidden).
    """
    if cfg.can_gate_rel <= 0:
        return True
    h = can_row(R_car_cam, offset_y_m)
    nu = v_can_mps - float(h @ x)
    sigma = math.sqrt(float(h @ P @ h) + cfg.can_abs_sigma_mps**2)
    return abs(nu) <= cfg.can_gate_rel * abs(v_can_mps) + 3.0 * sigma


def reset_speed(
    x: np.ndarray,
    P: np.ndarray,
    v_can_mps: float,
    R_car_cam: np.ndarray,
    cfg: FilterConfig,
    offset_y_m: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """(x, P) with V set to the CAN speed (forward, at the viewpoint for the current yaw
    rate: `can_row`) and V, W back to the initial prior std."""
    x, P = x.copy(), P.copy()
    yaw_rate = float(R_car_cam[2] @ x[W_SLICE])
    x[V_SLICE] = R_car_cam.T @ np.array([v_can_mps - offset_y_m * yaw_rate, 0.0, 0.0])
    for sl, cov in (
        (V_SLICE, _car_cov(R_car_cam, cfg.V0_sigma_mps)),
        (W_SLICE, np.eye(3) * cfg.W0_sigma_rps**2),
    ):
        P[sl, :] = 0.0
        P[:, sl] = 0.0
        P[sl, sl] = cov
    return x, _sym(P)


def iekf_update(
    x: np.ndarray,
    x_prior: np.ndarray,
    P_prior_inv: np.ndarray,
    C: np.ndarray,
    dz: np.ndarray,
    R_diag: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One IEKF iteration: (x̂ (9,), P (9, 9)) from C (N, 9), Δz (N,), R (N,) (eq. 17-18)."""
    Ci = C / R_diag[:, None]  # R⁻¹ C
    info = C.T @ Ci + P_prior_inv
    # eq. 17: P = [Cᵀ R⁻¹ C + P⁻⁻¹]⁻¹
    L = np.linalg.cholesky(_sym(info))
    L_inv = np.linalg.inv(L)
    P = L_inv.T @ L_inv
    # eq. 18: x̂ ← x̂ + P [Cᵀ R⁻¹ Δz − P⁻⁻¹ (x̂ − x⁻)]
    x_new = x + P @ (Ci.T @ dz - P_prior_inv @ (x - x_prior))
    return x_new, P


def data_snooping(
    residual: np.ndarray,
    C: np.ndarray,
    P: np.ndarray,
    R_diag: np.ndarray,
    inlier: np.ndarray,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Reclassify points (section 4.1): (inlier (N,) bool, Mahalanobis² d2 (N,)).

    residual: (N,) ``Δz_i`` at the current x̂; C (N, 9); P (9, 9) the current
    covariance; R_diag (N,); inlier: (N,) current labels (True = used in x̂).
    Expected variance: eq. 20 ``R + C_i P C_iᵀ`` for excluded points, eq. 21
    ``R − C_i P C_iᵀ`` for included ones (floored at a small fraction of R).
    threshold: d2 above which a point is an outlier (e.g. 3² for 3 sigma).
    """
    cpc = np.sum((C @ P) * C, axis=1)  # C_i P C_iᵀ
    # eq. 20 / eq. 21: expected residual variance of an excluded / included point
    var = np.where(inlier, np.maximum(R_diag - cpc, _MIN_INLIER_VAR * R_diag), R_diag + cpc)
    d2 = residual**2 / var
    return d2 <= threshold, d2


def robust_weights(residual: np.ndarray, sigma: np.ndarray, kind: str, k: float) -> np.ndarray:
    """(N,) Robust-M weights of normalised residuals ``e = residual / sigma``.

    kind ``"huber"``: ``min(1, k/|e|)``; ``"tukey"``: ``(1 - (e/k)²)²`` for ``|e| < k``, else 0.
    The update then uses ``R / w`` (zero weight: point dropped).
    """
    e = np.abs(residual / sigma)
    if kind == "huber":
        return np.minimum(1.0, k / np.maximum(e, 1e-12))
    if kind == "tukey":
        return np.where(e < k, (1.0 - (e / k) ** 2) ** 2, 0.0)
    raise ValueError(f"robust weighting must be 'huber' or 'tukey', got {kind!r}")


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


class IteratedEKF:
    """The filter's state across frames: posterior, prior and the iterations between them.

    Attributes:
        x: (9,) current estimate x̂ (V [m/s], W [rad/s], A [rad], frame c).
        P: (9, 9) its covariance.
        x_prior: (9,) prior x⁻ of the current frame pair.
        P_prior: (9, 9) its covariance P⁻; P_prior_inv (9, 9) its inverse.
        B, Q: (9, 9) transition and process noise of the last time update (eq. 19).
        n_iterations: measurement-update iterations since the prior was set.
        can_offset_y_m: the viewpoint's car-frame y [m]: its sideways offset from the
            centreline whose forward speed the CAN reports (`can_row`).
    """

    def __init__(
        self, cfg: FilterConfig, R_car_cam: np.ndarray, K0: np.ndarray, can_offset_y_m: float = 0.0
    ) -> None:
        self.cfg = cfg
        self.R_car_cam = np.asarray(R_car_cam, dtype=float)
        self.can_offset_y_m = float(can_offset_y_m)
        self.K0 = np.asarray(K0, dtype=float)
        self.x, self.P = initial_prior(cfg, self.R_car_cam, self.K0)
        self.B = np.eye(N_STATE)
        self.Q = np.zeros((N_STATE, N_STATE))
        self.rate_bias = np.zeros(3)  # [rad/s] in c, about axes in the road plane
        self.set_prior(self.x, self.P)

    def predict(self, dt_s: float, q_scale: float = 1.0) -> None:
        """Time update over dt [s] (eq. 19); Q is multiplied by q_scale (inflation)."""
        self.B, Q = transition(dt_s, self.cfg, self.R_car_cam, self.K0)
        self.Q = Q * q_scale
        self.x, self.P = time_update(self.x, self.P, self.B, self.Q)
        # A integrates the rates less their running mean (a known input: P unchanged)
        self.x[A_SLICE] -= self.B[A_SLICE, W_SLICE] @ self.rate_bias

    def learn_rate_bias(self, dt_s: float) -> None:
        """After a measured pair: the roll/pitch part of W joins the running mean
        ``rate_bias`` (time constant ``rate_bias_tau_s``), the measurement's bias."""
        if self.cfg.rate_bias_tau_s <= 0:
            return
        alpha = 1.0 - math.exp(-dt_s / self.cfg.rate_bias_tau_s)
        self.rate_bias += alpha * (self._rates_in_plane() - self.rate_bias)

    def _rates_in_plane(self) -> np.ndarray:
        """(3,) the part of W about axes in the road plane (roll and pitch rates) [rad/s]."""
        n = road_normal(self.K0)
        W = self.x[W_SLICE]
        return W - n * float(n @ W)

    def settle_rates(self, dt_s: float) -> None:
        """No measurement over the last pair: the roll/pitch part of W (about axes in the
        road plane) decays by ``exp(-dt / W_tau_s)``; the yaw rate is kept. Over frames
        that keep the prior, a rate left by the last fit would otherwise move A through
        every time update (``A_from_W``) and hold it at ``A_tau_s`` times that rate."""
        decay = 1.0 - math.exp(-dt_s / self.cfg.W_tau_s)
        self.x[W_SLICE] = self.x[W_SLICE] - decay * self._rates_in_plane()

    def hold_A(self) -> None:
        """A back to the prior's mean x⁻ with the stationary covariance of its process
        (`stationary_A_cov`), uncorrelated with V and W: the measurement's word on A is
        dropped, its word on V and W kept."""
        self.x[A_SLICE] = self.x_prior[A_SLICE]
        P = self.P.copy()
        P[A_SLICE, :] = 0.0
        P[:, A_SLICE] = 0.0
        P[A_SLICE, A_SLICE] = stationary_A_cov(self.cfg, self.K0)
        self.P = P

    def fuse_can(self, v_can_mps: float) -> None:
        """CAN forward speed as a measurement (`can_speed_update`)."""
        self.x, self.P = can_speed_update(
            self.x, self.P, v_can_mps, self.R_car_cam, self.cfg, self.can_offset_y_m
        )

    def can_consistent(self, v_can_mps: float) -> bool:
        """False when the CAN speed rules the current x̂, P out (`can_consistent`)."""
        return can_consistent(
            self.x, self.P, v_can_mps, self.R_car_cam, self.cfg, self.can_offset_y_m
        )

    def reset_to_can(self, v_can_mps: float) -> None:
        """V set from the CAN speed, V and W back to their initial std (`reset_speed`)."""
        self.x, self.P = reset_speed(
            self.x, self.P, v_can_mps, self.R_car_cam, self.cfg, self.can_offset_y_m
        )

    def fuse_nonholonomic(self, lever_m: float) -> None:
        """The rear axle does not slide sideways (`nonholonomic_update`), when configured."""
        if self.cfg.nonholonomic_sigma_mps > 0:
            self.x, self.P = nonholonomic_update(
                self.x, self.P, lever_m, self.R_car_cam, self.cfg.nonholonomic_sigma_mps
            )

    def fuse_vertical(self) -> None:
        """The camera does not leave the road plane (`vertical_speed_update`), when
        configured."""
        if self.cfg.vertical_speed_sigma_mps > 0:
            self.x, self.P = vertical_speed_update(
                self.x, self.P, self.K0, self.cfg.vertical_speed_sigma_mps
            )

    def inflate(self, factor: float) -> None:
        """Multiply P by factor (>= 1): less trust in the prior after a degraded step."""
        self.P = self.P * factor

    def set_prior(self, x: np.ndarray, P: np.ndarray) -> None:
        """Start a measurement update: x⁻ = x̂ = x, P⁻ = P = P (section 4.2)."""
        self.x_prior = check_state(x, "prior x")
        self.P_prior = _sym(np.asarray(P, dtype=float))
        self.P_prior_inv = _sym(np.linalg.inv(self.P_prior))
        self.x = self.x_prior.copy()
        self.P = self.P_prior.copy()
        self.n_iterations = 0

    def begin_update(self) -> None:
        """Freeze the current (time-updated, CAN-corrected) state as the prior x⁻, P⁻."""
        self.set_prior(self.x, self.P)

    def update(self, C: np.ndarray, dz: np.ndarray, R_diag: np.ndarray) -> np.ndarray:
        """One iterated measurement update (eq. 17-18); returns the step Δx̂ (9,)."""
        x_new, P = iekf_update(self.x, self.x_prior, self.P_prior_inv, C, dz, R_diag)
        dx = x_new - self.x
        self.x, self.P = x_new, P
        self.n_iterations += 1
        return dx
