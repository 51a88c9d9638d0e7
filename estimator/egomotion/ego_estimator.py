"""What every ego-motion estimator shares (`egomotion.direct`, `egomotion.baselines`): the
per-frame record, the input checks (frame, CAN speed, road mask) and the base class that
runs the time update (eq. 19) and the CAN speed prior before a subclass's measurement
update.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.fast_stats import fast_median
from estimator.egomotion.homography import A_SLICE, N_STATE, V_SLICE, W_SLICE, check_state
from estimator.egomotion.iekf import FilterConfig, IteratedEKF

UNUSED, INLIER, OUTLIER = 0, 1, 2  # point labels (paper Fig. 4b: black, gray, white)


# ------------------------------------------------------------------ record
@dataclass
class EgoMotionRecord:
    """Estimate of one frame (the motion from the previous frame to this one).

    x (9,), P (9, 9): posterior (V [m/s], W [rad/s], A [rad], nominal camera frame).
    x_prior (9,), P_prior (9, 9): the prior x⁻, P⁻ (time update + CAN speed).
    speed_mps: forward speed of the viewpoint in the car frame, ``(R_car_cam V)[0]``.
    yaw_rate_rps: ``(R_car_cam W)[2]`` (left turn positive).
    points_px (N, 2), point_labels (N,): points of the finest level used, in the
    previous frame, with UNUSED / INLIER / OUTLIER; point_speed_info (N,): what each
    told about the forward speed at the last linearisation, ``(C_i d)² / R_i`` with d
    the forward direction [1/(m/s)²] (0: left the view), for audits of the point set.
    iterations: IEKF iterations per level (coarse to fine).
    noise_scale: median of (residual² / R) / 0.455 at the finest level (~1 when the
    residuals match the noise model; large when the road did not align).
    degraded: True when the output is (or leans on) the prior; reason says why;
    flags: short machine-readable names of every condition met.
    compensated: (H, W) float32 previous frame warped onto this one, on request.
    """

    frame: int
    t_s: float
    dt_s: float
    x: np.ndarray
    P: np.ndarray
    x_prior: np.ndarray
    P_prior: np.ndarray
    speed_mps: float
    yaw_rate_rps: float
    can_speed_mps: float = math.nan
    noise_scale: float = math.nan
    n_points: int = 0
    n_inliers: int = 0
    iterations: tuple[int, ...] = ()
    points_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point_labels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    point_speed_info: np.ndarray = field(default_factory=lambda: np.zeros(0))
    flags: tuple[str, ...] = ()
    degraded: bool = False
    reason: str = ""
    compensated: np.ndarray | None = None

    @classmethod
    def from_rates(
        cls,
        frame: int,
        t_s: float,
        dt_s: float,
        speed_mps: float,
        yaw_rate_rps: float,
        mount: CameraMount,
        speed_var_m2ps2: float = math.nan,
        yaw_rate_var_r2ps2: float = math.nan,
        **fields: Any,
    ) -> EgoMotionRecord:
        """A record of a forward speed [m/s] and a yaw rate [rad/s] in the car frame (an
        estimator that measures only those, e.g. a plug-in): the state is the viewpoint
        moving along the car's x axis and turning about its z axis, A = 0; P holds the
        given variances (NaN: unknown) in those directions, NaN for A (not measured).
        ``fields``: any other field (degraded, reason, n_points, ...)."""
        R = np.asarray(mount.R_car_cam, float)
        x = np.zeros(N_STATE)
        x[V_SLICE] = R.T @ np.array([speed_mps, 0.0, 0.0])
        x[W_SLICE] = R.T @ np.array([0.0, 0.0, yaw_rate_rps])
        P = np.zeros((N_STATE, N_STATE))
        P[V_SLICE, V_SLICE] = speed_var_m2ps2 * np.outer(R[0], R[0])
        P[W_SLICE, W_SLICE] = yaw_rate_var_r2ps2 * np.outer(R[2], R[2])
        P[A_SLICE, A_SLICE] = math.nan
        return cls(frame, t_s, dt_s, x, P, x.copy(), P.copy(), speed_mps, yaw_rate_rps, **fields)

    @property
    def V(self) -> np.ndarray:
        """(3,) viewpoint velocity in the nominal camera frame [m/s]."""
        return self.x[V_SLICE]

    @property
    def W(self) -> np.ndarray:
        """(3,) angular velocity in the nominal camera frame [rad/s]."""
        return self.x[W_SLICE]

    @property
    def A(self) -> np.ndarray:
        """(3,) angular displacement of the actual camera [rad]."""
        return self.x[A_SLICE]


@dataclass
class PointPull:
    """What the last pair's finest-level inliers ask of a state (`DirectEstimator.point_pull`).

    points_px (N, 2): the inliers in the pair's first frame [px]; dx (N, 9): each one's part
    of one IEKF step from that state (eq. 17-18 with the prior's covariance but not its
    mean), so that ``dx.sum(0)`` is where the images alone move it. At the true state the
    sum is the images' own pull off the truth (0 on average for a road that fits the
    model); the points that carry it show where the road model fails.
    """

    points_px: np.ndarray
    dx: np.ndarray


def make_record(
    frame: int, t_s: float, dt_s: float, ekf: IteratedEKF, R_car_cam: np.ndarray, **kw: Any
) -> EgoMotionRecord:
    """Record of the filter's current posterior and prior (shared by all estimators)."""
    x = ekf.x.copy()
    reasons = kw.pop("reasons", [])
    return EgoMotionRecord(
        frame=frame,
        t_s=float(t_s),
        dt_s=float(dt_s),
        x=x,
        P=ekf.P.copy(),
        x_prior=ekf.x_prior.copy(),
        P_prior=ekf.P_prior.copy(),
        speed_mps=float((R_car_cam @ x[V_SLICE])[0]),
        yaw_rate_rps=float((R_car_cam @ x[W_SLICE])[2]),
        degraded=bool(reasons),
        reason="; ".join(reasons),
        **kw,
    )


# ------------------------------------------------------------------ inputs
def to_gray(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) float32 brightness [DN] of a gray or RGB frame; ValueError on a bad frame."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValueError(f"frame must be (H, W) gray or (H, W, 3) RGB, got shape {img.shape}")
    if img.shape[:2] != shape:
        raise ValueError(
            f"frame size {img.shape[1]}x{img.shape[0]} (WxH) does not match the camera: "
            f"expected {shape[1]}x{shape[0]}"
        )
    if img.dtype == bool or not np.issubdtype(img.dtype, np.number):
        raise ValueError(f"frame must be numeric, got dtype {img.dtype}")
    if img.ndim == 3:
        img = cv2.cvtColor(
            img if img.dtype == np.uint8 else img.astype(np.float32), cv2.COLOR_RGB2GRAY
        )
    img = img.astype(np.float32, copy=False)
    if not np.issubdtype(np.asarray(image).dtype, np.integer):
        img = np.nan_to_num(img, nan=0.0, posinf=255.0, neginf=0.0)
    return img


def check_road_mask(mask: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    """(H, W) bool road mask, or None; a mask of another size is a caller error."""
    if mask is None:
        return None
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"road_mask must be {shape[0]}x{shape[1]} (the frame), got {mask.shape}")
    return mask.astype(bool)


def valid_can(v: Any) -> float:
    """The CAN speed as a float, NaN when missing (None, NaN, inf, negative)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return math.nan
    return f if math.isfinite(f) and f >= 0.0 else math.nan


def frame_quality(gray: np.ndarray, roi_full: np.ndarray, cfg: DirectConfig) -> str:
    """Empty string if the frame is usable, else why not (dark, saturated).

    roi_full: (H, W) bool mask, or (M,) flat indices of the ROI pixels to look at.
    """
    vals = gray.ravel()[roi_full] if roi_full.ndim == 1 else gray[roi_full]
    if vals.size == 0:
        return "no road region of interest"
    mean = float(vals.mean())
    if mean < cfg.dark_level:
        return f"dark frame (mean {mean:.1f} DN in the road ROI < {cfg.dark_level})"
    sat = float(np.mean(vals >= cfg.saturated_level))
    if sat > cfg.saturated_fraction:
        return f"saturated frame ({100 * sat:.0f} % of the road ROI >= {cfg.saturated_level} DN)"
    return ""


# ------------------------------------------------------------------ estimator
class EgoMotionEstimator:
    """Base of every estimator: input checks, time update, CAN prior, flags, record.

    ``step(image, t_s, can_speed_mps) -> EgoMotionRecord``: the first call only
    initialises (``_first_frame``); later calls run the time update (eq. 19) and
    the CAN speed update on the filter `ekf`, freeze the prior, and call
    ``_measure`` (the subclass's measurement update). Subclasses set ``name``.
    """

    name: str = ""

    def __init__(
        self,
        camera: CameraModel,
        mount: CameraMount,
        filter_cfg: FilterConfig,
        can_missing_inflation: float = 4.0,
        flat_field: bool = False,
    ) -> None:
        if camera.kind != mount.base:
            raise ValueError(
                f"camera kind {camera.kind!r} does not match mount base {mount.base!r}"
            )
        self.camera, self.mount = camera, mount
        self.K0 = mount.K0
        self.R_car_cam = mount.R_car_cam
        self.filter_cfg = filter_cfg
        self.can_missing_inflation = can_missing_inflation
        # the CAN speed is the centreline's: the viewpoint is position_m[1] to its left
        self.ekf = IteratedEKF(filter_cfg, self.R_car_cam, self.K0, float(mount.position_m[1]))
        self._k = 0
        self._t_prev: float | None = None
        self._can_prev = math.nan
        self._dts: list[float] = []
        self._v_can = math.nan  # CAN speed of the current frame pair [m/s] (NaN: missing)
        self._road_mask_new: np.ndarray | None = None  # road mask given with the frame
        self._image_new: np.ndarray | None = None  # the frame as given (colour)
        # photometric calibration (``flat_field``): the camera's vignetting divided out, so
        # that the road's brightness does not change as it crosses the image
        self._flat_field = (
            1.0 / camera.vignetting_gain() if flat_field and camera.vignetting > 0 else None
        )

    def step(
        self,
        image: np.ndarray,
        t_s: float,
        can_speed_mps: float | None,
        compensate: bool | None = None,
        road_mask: np.ndarray | None = None,
    ) -> EgoMotionRecord:
        """Estimate the motion from the previous frame to ``image`` taken at t_s [s].

        image: (H, W) gray or (H, W, 3) RGB of the camera's size; can_speed_mps:
        latest CAN speed [m/s] (None / NaN when missing). compensate: also return
        the motion-compensated previous frame (estimators that support it).
        road_mask: optional (H, W) bool, True where ``image`` shows the road (a
        segmentation from elsewhere), used when this frame is the previous one of a
        pair: `DirectEstimator` lets its points off the road tell the rotation only
        (``offroad_depth_sigma``), the features baseline takes corners on it only.
        """
        gray = to_gray(image, (self.camera.height, self.camera.width))
        if self._flat_field is not None:
            gray = gray * self._flat_field
        self._image_new = image
        self._road_mask_new = check_road_mask(road_mask, (self.camera.height, self.camera.width))
        t_s, t_prev = float(t_s), self._t_prev
        if not math.isfinite(t_s) or (t_prev is not None and not t_s > t_prev):
            raise ValueError(
                f"t_s must be finite and increase: frame {self._k} at {t_s} s"
                + (f" after {t_prev} s" if t_prev is not None else "")
            )
        can, can_prev = valid_can(can_speed_mps), self._can_prev
        k, self._k, self._t_prev, self._can_prev = self._k, self._k + 1, t_s, can
        if t_prev is None:
            return self._first(gray, t_s, can, k)
        dt = t_s - t_prev
        flags, reasons = [], []
        cfg = self.filter_cfg
        nominal = cfg.nominal_dt_s or (fast_median(np.asarray(self._dts)) if self._dts else None)
        if nominal is not None and dt > cfg.gap_factor * nominal:
            flags.append("time-gap")
            reasons.append(
                f"time gap: dt {dt:.3f} s > {cfg.gap_factor} x nominal "
                f"{nominal:.3f} s (process noise scaled by dt)"
            )
        else:
            self._dts = (self._dts + [dt])[-15:]
        # eq. 19: time update (Q grows with dt)
        self.ekf.predict(dt)
        self._v_can = math.nan
        if math.isnan(can):
            flags.append("can-missing")
            reasons.append("CAN speed missing: time-updated speed used, V covariance inflated")
            S = np.ones(N_STATE)
            S[V_SLICE] = math.sqrt(self.can_missing_inflation)
            self.ekf.P = self.ekf.P * np.outer(S, S)
        else:
            # the pair's mean speed: mean of the CAN at both ends when both are known
            v_can = can if math.isnan(can_prev) else 0.5 * (can + can_prev)
            ekf = self.ekf
            if not ekf.can_consistent(v_can):
                flags.append("can-reset")
                reasons.append(
                    f"predicted speed {(self.R_car_cam @ ekf.x[V_SLICE])[0]:.2f} m/s "
                    f"contradicts the CAN ({v_can:.2f} m/s): speed and yaw rate re-initialised"
                )
                ekf.reset_to_can(v_can)
            ekf.fuse_can(v_can)
            self._v_can = v_can
        if self.mount.lever_arm_m is not None:  # kinematic model: no side slip at the axle
            self.ekf.fuse_nonholonomic(self.mount.lever_arm_m)
        self.ekf.fuse_vertical()  # nor leaves the road plane
        self.ekf.begin_update()
        extra = self._measure(gray, t_s, dt, flags, reasons, compensate)
        rec = make_record(
            k,
            t_s,
            dt,
            self.ekf,
            self.R_car_cam,
            can_speed_mps=can,
            flags=tuple(flags),
            reasons=reasons,
            **extra,
        )
        if np.array_equal(self.ekf.x, self.ekf.x_prior):  # nothing measured: prior kept
            self.ekf.settle_rates(dt)
        elif not rec.degraded:
            self.ekf.learn_rate_bias(dt)
        return rec

    def _first(self, gray: np.ndarray, t_s: float, can: float, k: int) -> EgoMotionRecord:
        """First frame: no motion yet. The record shows the prior with the CAN speed."""
        self._first_frame(gray, t_s, can)
        ekf = self.ekf
        if not math.isnan(can):
            # V⁻ = R_cam_car (v_can, 0, 0); its covariance stays wide until the next CAN
            ekf.x[V_SLICE] = self.R_car_cam.T @ np.array([can, 0.0, 0.0])
        saved = ekf.x.copy(), ekf.P.copy()
        if not math.isnan(can):
            ekf.fuse_can(can)
        ekf.begin_update()
        rec = make_record(k, t_s, 0.0, ekf, self.R_car_cam, can_speed_mps=can, flags=("init",))
        rec.reason = "first frame: prior only"
        ekf.x, ekf.P = saved  # the CAN of this frame is fused with the next one
        return rec

    def _first_frame(self, gray: np.ndarray, t_s: float, can: float) -> None:
        """Keep what the next step needs from the first frame (subclasses)."""

    def point_pull(self, x: np.ndarray) -> PointPull | None:
        """What the last pair's points ask of the state x (9,), point by point
        (`DirectEstimator.point_pull`); None from an estimator whose fit has no such points."""
        check_state(x, "point_pull x")
        return None

    def _measure(
        self,
        gray: np.ndarray,
        t_s: float,
        dt: float,
        flags: list[str],
        reasons: list[str],
        compensate: bool | None,
    ) -> dict[str, Any]:
        """Measurement update of ``ekf`` from the previous frame and ``gray``; returns
        extra record fields. The base class measures nothing (prior only)."""
        return {}
