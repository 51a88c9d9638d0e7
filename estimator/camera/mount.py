"""Where a camera sits on the car: `T_car_cam`, and the road plane it sees.

Frames (docs/CONVENTIONS.md): the car frame has x forward, y left, z up, origin
on the road under the vehicle centre. Each camera kind has a *base* orientation
(all mount angles zero):

- ``"omni"``: Z down the mirror axis, X to the car's right, Y backward;
- ``"pinhole"``: OpenCV axes looking forward: Z forward, X right, Y down.

The mount angles then rotate that base about the car axes:
``R_car_cam = Rz(yaw) @ Ry(pitch) @ Rx(roll) @ R_car_base``; positive pitch
tilts a forward-looking axis down, positive yaw turns it to the left.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from estimator.geometry import make_T, rot_x, rot_y, rot_z

R_CAR_BASE = {
    # columns: camera X, Y, Z axes in car coordinates
    "omni": np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
    "pinhole": np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]),
}


@dataclass(frozen=True)
class CameraMount:
    """Pose of a camera's single viewpoint on the car.

    position_m: viewpoint in the car frame [m]; z is its height above the road.
    yaw_deg, pitch_deg, roll_deg: rotation of the camera's base axes [deg].
    base: ``"omni"`` or ``"pinhole"`` (see module docstring).
    rear_axle_x_m: x of the car's rear axle in the car frame [m], the point of the car
    that does not slide sideways (kinematic vehicle model); None when unknown. With it
    the estimators know that the viewpoint moves sideways at the yaw rate times its
    lever arm (`estimator.egomotion.iekf.nonholonomic_update`).
    """

    position_m: tuple[float, float, float] = (0.0, 0.0, 1.95)
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    base: str = "omni"
    rear_axle_x_m: float | None = None
    _R: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.base not in R_CAR_BASE:
            raise ValueError(f"mount base must be one of {sorted(R_CAR_BASE)}, got {self.base!r}")
        pos = np.asarray(self.position_m, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError(f"mount position_m must be 3 finite numbers, got {self.position_m!r}")
        if pos[2] <= 0:
            raise ValueError(f"mount height position_m[2] must be > 0 m, got {pos[2]}")
        if self.rear_axle_x_m is not None and not np.isfinite(self.rear_axle_x_m):
            raise ValueError(f"mount rear_axle_x_m must be finite, got {self.rear_axle_x_m!r}")
        R = (
            rot_z(np.radians(self.yaw_deg))
            @ rot_y(np.radians(self.pitch_deg))
            @ rot_x(np.radians(self.roll_deg))
            @ R_CAR_BASE[self.base]
        )
        object.__setattr__(self, "_R", R)

    @property
    def height_m(self) -> float:
        """Viewpoint height above the (flat) road [m]."""
        return float(self.position_m[2])

    @property
    def lever_arm_m(self) -> float | None:
        """Viewpoint x minus rear-axle x in the car frame [m] (None: axle unknown)."""
        if self.rear_axle_x_m is None:
            return None
        return float(self.position_m[0]) - float(self.rear_axle_x_m)

    @property
    def R_car_cam(self) -> np.ndarray:
        """(3, 3) rotation from nominal camera to car coordinates."""
        return self._R.copy()

    @property
    def T_car_cam(self) -> np.ndarray:
        """(4, 4) pose of the nominal camera frame in the car frame."""
        return make_T(self._R, self.position_m)

    @property
    def road_normal_cam(self) -> np.ndarray:
        """(3,) unit normal from the viewpoint down to the road, in camera coordinates."""
        return self._R.T @ np.array([0.0, 0.0, -1.0])

    @property
    def K0(self) -> np.ndarray:
        """(3,) road plane in nominal camera coordinates: K0^T P = 1 on the road."""
        return self.road_normal_cam / self.height_m

    def to_dict(self) -> dict:
        return {
            "position_m": [float(x) for x in self.position_m],
            "yaw_deg": float(self.yaw_deg),
            "pitch_deg": float(self.pitch_deg),
            "roll_deg": float(self.roll_deg),
            "base": self.base,
            **({} if self.rear_axle_x_m is None else {"rear_axle_x_m": float(self.rear_axle_x_m)}),
        }
