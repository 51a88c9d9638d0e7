"""True camera motion: car pose, mount, vibration, and the paper's state x = (V, W, A).

Frames (docs/CONVENTIONS.md): the nominal camera frame c is fixed to the car by
the mount; the actual frame a is c rotated by the vibration angle A
(``R_c_a = exp([A]x)``). The state for the frame pair (k, k+1), time step dt:

- ``V`` [m/s]: viewpoint velocity in frame c at k,
- ``W`` [rad/s]: angular velocity of the actual camera, in its frame at k,
- ``A`` [rad]: angular displacement at k, in c,

and the exact plane-induced homography ``H = R_b_a + t_b_a K_a^T`` mapping
actual-camera rays of the road at k to those at k+1 (eq. 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.camera.mount import CameraMount
from estimator.geometry import make_T, rot_z, so3_exp, so3_log


@dataclass(frozen=True)
class Vibration:
    """Roll/pitch oscillation of the camera on its mount (the paper's A).

    Roll (about car x) at ``frequency_hz``, pitch (about car y) at 1.37x that,
    each with a seeded phase; ``amplitude_deg`` is the peak of each.
    """

    amplitude_deg: float
    frequency_hz: float
    phase_roll_rad: float = 0.0
    phase_pitch_rad: float = 0.0

    @classmethod
    def seeded(cls, amplitude_deg: float, frequency_hz: float, rng: np.random.Generator):
        ph = rng.uniform(0, 2 * np.pi, size=2)
        return cls(amplitude_deg, frequency_hz, float(ph[0]), float(ph[1]))

    def angles_car_rad(self, t_s: float) -> np.ndarray:
        """(3,) rotation vector of the camera about the car axes (roll, pitch, 0) [rad]."""
        amp = np.radians(self.amplitude_deg)
        w = 2 * np.pi * self.frequency_hz
        return np.array(
            [
                amp * np.sin(w * t_s + self.phase_roll_rad),
                amp * np.sin(1.37 * w * t_s + self.phase_pitch_rad),
                0.0,
            ]
        )


def T_world_car(x_m: float, y_m: float, yaw_rad: float) -> np.ndarray:
    """(4, 4) pose of the car frame (origin on the road under its centre) in the world."""
    return make_T(rot_z(yaw_rad), (x_m, y_m, 0.0))


@dataclass(frozen=True)
class CameraPose:
    """Nominal and actual camera poses at one instant, and the vibration angle.

    T_world_nominal, T_world_actual: (4, 4); A_cam_rad: (3,) in nominal camera frame.
    """

    T_world_nominal: np.ndarray
    T_world_actual: np.ndarray
    A_cam_rad: np.ndarray


def camera_pose(
    T_world_car_: np.ndarray, mount: CameraMount, vibration: Vibration | None, t_s: float
) -> CameraPose:
    T_wn = T_world_car_ @ mount.T_car_cam
    A_car = vibration.angles_car_rad(t_s) if vibration is not None else np.zeros(3)
    A_cam = mount.R_car_cam.T @ A_car  # the same rotation vector, in camera axes
    T_wa = T_wn.copy()
    T_wa[:3, :3] = T_wn[:3, :3] @ so3_exp(A_cam)  # R_c_a = exp([A]x)
    return CameraPose(T_wn, T_wa, A_cam)


def road_plane_K(T_world_cam: np.ndarray) -> np.ndarray:
    """(3,) road plane z = 0 in a camera frame: K^T P = 1 for road points P."""
    n_cam = T_world_cam[:3, :3].T @ np.array([0.0, 0.0, -1.0])
    return n_cam / T_world_cam[2, 3]


@dataclass(frozen=True)
class MotionState:
    """The paper's state for a frame pair and the exact homography.

    V_mps (3,), W_rps (3,), A_rad (3,) as in the module docstring; H (3, 3)
    normalised so that H[2, 2] is not rescaled (the exact R + t K^T).
    """

    V_mps: np.ndarray
    W_rps: np.ndarray
    A_rad: np.ndarray
    H: np.ndarray
    dt_s: float


def motion_between(a: CameraPose, b: CameraPose, dt_s: float) -> MotionState:
    """State and exact road homography from pose a (time t) to pose b (t + dt)."""
    R_wa, R_wb = a.T_world_actual[:3, :3], b.T_world_actual[:3, :3]
    dp_w = b.T_world_actual[:3, 3] - a.T_world_actual[:3, 3]
    V = a.T_world_nominal[:3, :3].T @ dp_w / dt_s
    W = so3_log(R_wa.T @ R_wb) / dt_s
    R_ba = R_wb.T @ R_wa  # P_b = R_ba P_a + t_ba
    t_ba = -R_wb.T @ dp_w
    H = R_ba + np.outer(t_ba, road_plane_K(a.T_world_actual))  # eq. 3
    return MotionState(V, W, a.A_cam_rad.copy(), H, dt_s)
