"""The paper's state x = (V, W, A) and the road-plane homography H(x) (eq. 3-4, Table 1).

State (docs/CONVENTIONS.md), 9 numbers, all in the nominal camera frame c:

- ``V`` = x[0:3] [m/s]: velocity of the camera viewpoint,
- ``W`` = x[3:6] [rad/s]: angular velocity of the camera,
- ``A`` = x[6:9] [rad]: angular displacement of the actual camera from nominal.

Road rays of the actual camera at time t (frame a) and t + dt (frame b) are
related by ``P_b ~ H P_a`` with ``H = R + D K^T`` (eq. 3). Derivation of the
small-angle forms (eq. 4), with ``R_c_a = exp([A]x)`` (actual camera ``a`` is
the nominal camera rotated by A) and the camera turning by ``exp([W]x dt)``
between the frames:

- rotation from a to b: ``R = exp(-[W]x dt) ~= I - [W]x dt``;
- translation: the viewpoint moves by ``V dt`` (in c), which is
  ``-R_b_c V dt = -R exp(-[A]x) V dt`` in frame b, so
  ``D ~= -(I - [W]x dt - [A]x) V dt`` (eq. 4; Table 1 prints it without the
  minus sign, i.e. for V the velocity of the scene relative to the camera);
- road plane in frame a: ``K = exp(-[A]x) K0 ~= (I - [A]x) K0``.

Dropped terms are of second order in (W dt, A). `tests/estimator/egomotion/test_homography.py`
checks the sign of D and the order of the error against the exact H of the
simulator, and `homography_jacobian` against central differences.
"""

from __future__ import annotations

import numpy as np

from estimator.geometry import skew

N_STATE = 9
V_SLICE = slice(0, 3)  # [m/s] viewpoint velocity in c
W_SLICE = slice(3, 6)  # [rad/s] angular velocity in c
A_SLICE = slice(6, 9)  # [rad] angular displacement of the actual camera in c
STATE_NAMES = ("Vx", "Vy", "Vz", "Wx", "Wy", "Wz", "Ax", "Ay", "Az")

_E = np.eye(3)
_SKEW_E = np.stack([skew(_E[i]) for i in range(3)])  # (3, 3, 3): [e_i]x


def check_state(x: np.ndarray, where: str = "state") -> np.ndarray:
    """(9,) float64 copy of x; the error names the shape or values received."""
    arr = np.asarray(x, dtype=float)
    if arr.shape != (N_STATE,):
        raise ValueError(f"{where} must have shape (9,) = (V, W, A), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where} must be finite, got {arr}")
    return arr.copy()


def make_state(V_mps: np.ndarray, W_rps: np.ndarray, A_rad: np.ndarray) -> np.ndarray:
    """(9,) state from V (3,) [m/s], W (3,) [rad/s], A (3,) [rad], all in frame c."""
    return np.concatenate([np.reshape(V_mps, 3), np.reshape(W_rps, 3), np.reshape(A_rad, 3)])


def homography_parts(
    x: np.ndarray, K0: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R (3, 3), D (3,), K (3,)) of eq. 4 for state x (9,), road plane K0 (3,), dt [s]."""
    R, D, K, _ = _parts(x, K0, dt_s)
    return R, D, K


def _parts(
    x: np.ndarray, K0: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`homography_parts` and M = I - [W]x dt - [A]x (for `homography_jacobian`)."""
    V, W, A = x[V_SLICE], x[W_SLICE], x[A_SLICE]
    Ax = skew(A)
    # eq. 4: R = I - [W]x dt
    R = _E - skew(W) * dt_s
    # eq. 4: D = -(I - [W]x dt - [A]x) V dt  (sign derived in the module docstring)
    M = R - Ax
    D = -M @ V * dt_s
    # eq. 4: K = (I - [A]x) K0
    K = (_E - Ax) @ np.asarray(K0, dtype=float)
    return R, D, K, M


def homography(x: np.ndarray, K0: np.ndarray, dt_s: float) -> np.ndarray:
    """(3, 3) H = R + D K^T (eq. 3) mapping road rays of frame a to frame b (up to scale > 0).

    x: (9,) state (V, W, A); K0: (3,) nominal road plane (K0^T P = 1 on the road) [1/m];
    dt_s: time from frame a to frame b [s].
    """
    R, D, K, _ = _parts(np.asarray(x, dtype=float), K0, dt_s)
    # eq. 3: H = R + D K^T
    return R + D[:, None] * K


def _skews(v: np.ndarray) -> np.ndarray:
    """(G, 3, 3) `skew` of each row of v (G, 3)."""
    S = np.zeros((len(v), 3, 3))
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    S[:, 0, 1], S[:, 0, 2] = -z, y
    S[:, 1, 0], S[:, 1, 2] = z, -x
    S[:, 2, 0], S[:, 2, 1] = -y, x
    return S


def homographies(X: np.ndarray, K0: np.ndarray, dt_s: float) -> np.ndarray:
    """(G, 3, 3) `homography` of each state of X (G, 9) (a grid of states).

    The same values as calling `homography` per state: the same elementwise operations,
    and the matrix-vector products of eq. 4 as one batched np.matmul, which runs the
    same BLAS matrix-vector product per state as the (3, 3) @ (3,) of `homography`
    (tests/estimator/egomotion/test_homography.py compares them bit for bit).
    """
    X = np.asarray(X, dtype=float)
    V, W, A = X[:, V_SLICE], X[:, W_SLICE], X[:, A_SLICE]
    Ax = _skews(A)
    R = _E - _skews(W) * dt_s  # eq. 4
    M = R - Ax
    D = np.matmul(-M, V[:, :, None])[:, :, 0] * dt_s
    K = np.matmul(_E - Ax, np.asarray(K0, dtype=float))
    return R + D[:, :, None] * K[:, None, :]  # eq. 3


def homography_jacobian(x: np.ndarray, K0: np.ndarray, dt_s: float) -> np.ndarray:
    """(9, 3, 3) dH/dx_j for each state component j (Table 1, rows 1-2).

    With our sign of D (module docstring):
    ``dH = dR + dD K^T + D dK^T``, ``dR = -[dW]x dt``,
    ``dD = -(I - [W]x dt - [A]x) dV dt + ([dW]x dt + [dA]x) V dt``, ``dK = -[dA]x K0``.
    """
    x = np.asarray(x, dtype=float)
    K0 = np.asarray(K0, dtype=float)
    V = x[V_SLICE]
    _, D, K, M = _parts(x, K0, dt_s)  # M = I - [W]x dt - [A]x
    EV = _SKEW_E @ V  # (3, 3): row i = [e_i]x V
    EK0 = _SKEW_E @ K0  # (3, 3): row i = [e_i]x K0
    dH = np.empty((N_STATE, 3, 3))
    # Table 1: dD/dV_i = -(I - [W]x dt - [A]x) e_i dt
    dH[V_SLICE] = -dt_s * M.T[:, :, None] * K[None, None, :]
    # Table 1: dR/dW_i = -[e_i]x dt, dD/dW_i = [e_i]x V dt^2
    dH[W_SLICE] = -dt_s * _SKEW_E + dt_s**2 * EV[:, :, None] * K[None, None, :]
    # Table 1: dD/dA_i = [e_i]x V dt, dK/dA_i = -[e_i]x K0
    dH[A_SLICE] = dt_s * EV[:, :, None] * K[None, None, :] - D[None, :, None] * EK0[:, None, :]
    return dH


def dh_dx(x: np.ndarray, K0: np.ndarray, dt_s: float) -> np.ndarray:
    """(9, 9) Jacobian of h = (h1 .. h9) = H.ravel() (row-major, Table 1) w.r.t. x."""
    return homography_jacobian(x, K0, dt_s).reshape(N_STATE, 9).T
