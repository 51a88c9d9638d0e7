"""Pixel motion of the road between two frames, and its Jacobian w.r.t. the state.

The warp of a pixel ``w_a`` of frame a (paper section 3, Table 1)::

    w_a --K^-1, F^-1 (eq. 9-10)--> P_a --H(x) (eq. 3)--> P_b --F, K (eq. 6, 8)--> w_b

is ``camera.unproject``, one homography multiply and ``camera.project``, for
any camera of the `estimator.camera.models.CameraModel` interface (omni or pinhole).
``P_a`` depends only on ``w_a``: it is computed once per point (`RoadPoints`).

Jacobian of ``w_b`` w.r.t. the state x by the chain of eq. 16 / Table 1::

    dw_b/dx = dw_b/dP_b (camera.project_jacobian, rows 4-5)
              @ dP_b/dh (row 3: P_a placed in a 3 x 9 matrix)
              @ dh/dx   (rows 1-2: `estimator.egomotion.homography.dh_dx`)

and the optical-flow constraint row of a point with image gradient ``g`` is
``C_i = g^T dw_b/dx`` (eq. 13-16), computed without forming dw_b/dx:
``C_i = (q_i kron P_a,i)^T dh/dx`` with ``q_i = dw_b/dP_b^T g`` (3,).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.camera.models import CameraModel
from estimator.egomotion.homography import N_STATE, dh_dx, homography


@dataclass(frozen=True)
class RoadPoints:
    """Points of frame a and what depends only on them.

    w_a: (N, 2) pixels (u, v) in frame a [px]; rays_a: (N, 3) unit rays of the
    actual camera at a (eq. 9-10).
    """

    w_a: np.ndarray
    rays_a: np.ndarray

    @classmethod
    def from_pixels(cls, camera: CameraModel, w_a: np.ndarray) -> RoadPoints:
        w_a = np.asarray(w_a, dtype=float).reshape(-1, 2)
        return cls(w_a, camera.unproject(w_a))

    def __len__(self) -> int:
        return len(self.w_a)


def map_rays(rays_a: np.ndarray, H: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """(N, 3) rays of frame a -> (N, 3) P_b = H P_a (eq. 3), positive scale kept; computed
    in dtype (float32 for dense per-pixel maps, as `CameraModel.project`)."""
    # a contiguous Hᵀ: numpy's matmul with a transposed (3, 3) view takes a slow path
    # (measured 1.0 vs 0.09 ms for 59k rays)
    return np.asarray(rays_a, dtype) @ np.ascontiguousarray(np.asarray(H, float).T, dtype)


def warp_pixels(camera: CameraModel, rays_a: np.ndarray, H: np.ndarray) -> np.ndarray:
    """(N, 3) rays of frame a, H (3, 3) -> (N, 2) pixels w_b in frame b (NaN: no image)."""
    return camera.project(map_rays(rays_a, H))


def warp_points(
    camera: CameraModel, points: RoadPoints, x: np.ndarray, K0: np.ndarray, dt_s: float
) -> np.ndarray:
    """(N, 2) w_b of the points for state x (9,), road plane K0 (3,), time step dt [s]."""
    return warp_pixels(camera, points.rays_a, homography(x, K0, dt_s))


def warp_jacobian(
    camera: CameraModel, rays_a: np.ndarray, x: np.ndarray, K0: np.ndarray, dt_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """(w_b (N, 2), dw_b/dx (N, 2, 9)) for rays_a (N, 3) at state x (eq. 16 chain, Table 1)."""
    P_b = map_rays(rays_a, homography(x, K0, dt_s))
    w_b = camera.project(P_b)
    dw_dP = camera.project_jacobian(P_b)  # (N, 2, 3), Table 1 rows 4-5
    return w_b, dw_dP @ dP_dx(rays_a, dh_dx(x, K0, dt_s))


def dP_dx(rays_a: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(N, 3, 9) dP_b/dx = dP_b/dh (Table 1 row 3) @ dh/dx (G (9, 9), rows 1-2)."""
    # dP_b[k]/dh[3k + l] = P_a[l]  =>  dP_b[k]/dx_j = sum_l P_a[l] G[3k + l, j]
    return np.einsum("nl,klj->nkj", rays_a, G.reshape(3, 3, N_STATE))


def constraint_rows(
    camera: CameraModel, rays_a: np.ndarray, P_b: np.ndarray, grad_b: np.ndarray, G: np.ndarray
) -> np.ndarray:
    """Optical-flow constraint rows C (N, 9) = g^T dw_b/dx (eq. 14-16).

    rays_a: (N, 3) rays of the points in frame a; P_b: (N, 3) = H rays_a at the
    current state; grad_b: (N, 2) spatial gradient (d/du, d/dv) of image B at
    w_b = project(P_b) [intensity / px]; G: (9, 9) dh/dx at the current state.
    """
    dw_dP = camera.project_jacobian(P_b)  # (N, 2, 3), Table 1 rows 4-5
    # eq. 16: dc/dP_b = (g_u, g_v) dw_b/dP_b
    q = grad_b[:, 0, None] * dw_dP[:, 0] + grad_b[:, 1, None] * dw_dP[:, 1]  # (N, 3)
    # Table 1 row 3: dc/dh = q kron P_a (h = H.ravel() row-major)
    dc_dh = (q[:, :, None] * rays_a[:, None, :]).reshape(-1, 9)
    # Table 1 rows 1-2: C = dc/dh dh/dx
    return dc_dh @ G
