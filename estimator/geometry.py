"""Small rotation helpers shared by the estimator and the simulator.

Conventions (docs/CONVENTIONS.md): `R_a_b` maps vectors from frame b to frame a;
`T_a_b` (4x4) is the pose of frame b in frame a. Angles in radians.
"""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix `[v]x` of a 3-vector, so that `[v]x @ u = v x u`."""
    x, y, z = np.asarray(v, dtype=float).reshape(3).tolist()  # (Python floats: faster to build)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rot_x(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector `w` (Rodrigues)."""
    w = np.asarray(w, dtype=float).reshape(3)
    theta = float(np.linalg.norm(w))
    K = skew(w)
    if theta < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + np.sin(theta) / theta * K + (1 - np.cos(theta)) / theta**2 * K @ K


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of the rotation matrix `R` (inverse of `so3_exp`, angle < pi)."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos_t))
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-8:
        return 0.5 * v
    return theta / (2.0 * np.sin(theta)) * v


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 pose from a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert_T(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose."""
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def road_normal(K0: np.ndarray) -> np.ndarray:
    """(3,) unit normal of the road plane K0 (3,) (``K0ᵀ P = 1`` on the road, [1/m])."""
    K0 = np.asarray(K0, dtype=float)
    return K0 / np.linalg.norm(K0)


def road_distance_m(rays: np.ndarray, K0: np.ndarray) -> np.ndarray:
    """(N,) horizontal distance [m] from the viewpoint to where unit rays (N, 3) hit the road
    plane K0 (3,) (``K0ᵀ P = 1`` on the road, [1/m]); inf or negative for rays that do not."""
    kr = rays @ K0
    n = road_normal(K0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = 1.0 / kr  # range along the unit ray to the road [m]
        return t * np.sqrt(np.maximum(1.0 - (rays @ n) ** 2, 0.0))
