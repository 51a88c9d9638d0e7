"""Direct ego-motion estimation from image gradients (paper section 4.2): `DirectEstimator`.

For each new frame B (previous frame A)::

    Gaussian pyramids of A and B; x̂ = x⁻, P = P⁻ (time update eq. 19 + CAN speed)
    one coarse-to-fine pass of IEKF iterations (`coarse_to_fine`): per level, the points
        of A (`level_points`), a grid search (`grid_search`), then Δz, C, R at x̂
        (`constraints`, eq. 13-16), data snooping (eq. 20-21) and the update (eq. 17-18)
    is the fit usable (`fit_failure`)? then, in turn:
    - own map: a pair without an off-road map from the previous pair maps A from its own
      fit (the same tests run backward) and fits again without those pixels (`own_map`,
      flag ``own-map``; kept only if it fits at least as well)
    - map dropped: a map that leaves the finest level too few points is dropped for the
      pair (flag ``offroad-map-dropped``): a road is not textureless because of a map
    - yaw refit: a fit that moved the yaw rate far beyond what the prior allowed is
      refitted with the prior's yaw rate widened (`yaw_refit`, flag ``yaw-jump``)
    - manoeuvre retry: a fit that fails, or whose residuals are far above the recent
      ones, is retried with the manoeuvre covariance added to the prior (`manoeuvre`,
      flag ``manoeuvre``)
    after a usual fit, the residual of A compensated onto B and a plane-parallax test
    mark what the road motion does not explain (`estimator.egomotion.offroad_map`): the
    next pair, where B is A, takes no points there (`exclusion`); after a failed or
    unusual fit the last usual fit's map is carried over, dilated, for ``map_carry``
    pairs (flag ``map-carried``)

With ``first_fit_A`` off (the pinhole's setting), the first fit's A is dropped: A stays
at the mount with its process's stationary std (flag ``A-held``); with ``fit_A`` off (the
pinhole's setting too), so is every later fit's: A is then the integral of the measured
roll/pitch rates.

`EgoMotionEstimator` (base of all estimators, also `estimator.egomotion.baselines`) does
the input checks, the time update and the CAN prior, and builds the record. A CAN speed
that rules out the predicted speed (beyond its bounded scale error) re-initialises the
speed and the yaw rate (flag ``can-reset``).

Degraded inputs never raise (except a frame of the wrong size, or time not increasing:
caller errors) and never give a silent number: ``degraded=True`` with a reason and flags.
A dark or saturated frame, a textureless road, too few inliers, a poor fit or a fit that
contradicts the CAN give the prior (time update + CAN); a missing CAN speed (time-updated
speed, V covariance inflated) or a time gap (Q grows with dt) are flagged and the images
still measure.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.coarse_to_fine import FineLevel, Fit, FitSetup, coarse_to_fine
from estimator.egomotion.compensation import FrameCompensator
from estimator.egomotion.constraints import linearise
from estimator.egomotion.direct_config import DirectConfig, default_config
from estimator.egomotion.ego_estimator import INLIER, EgoMotionEstimator, PointPull, frame_quality
from estimator.egomotion.exclusion import carry_map, excluded, given_offroad, set_mask_index
from estimator.egomotion.fit_failure import fit_failure, unusual_noise
from estimator.egomotion.homography import check_state
from estimator.egomotion.iekf import yaw_direction
from estimator.egomotion.level_points import Pair
from estimator.egomotion.levels import build_levels
from estimator.egomotion.manoeuvre import RETRIED_FAILURES, manoeuvre_cov, manoeuvre_retry
from estimator.egomotion.offroad_map import OffroadMapper
from estimator.egomotion.own_map import own_map_refit
from estimator.egomotion.pyramid import Frame, build_frame
from estimator.egomotion.road_appearance import offroad_by_appearance, seed_indices
from estimator.egomotion.yaw_refit import yaw_refit


class DirectEstimator(EgoMotionEstimator):
    """Direct (gradient-based) IEKF ego-motion estimator of the paper (section 4).

    ``step(image, t_s, can_speed_mps) -> EgoMotionRecord``; the first call only
    initialises. Holds the previous frame's pyramid, the per-level camera
    precomputations (`Level`), the filter (`IteratedEKF`) and what carries from pair to
    pair: the off-road map, the brightness gain, the recent fits' noise scales.
    """

    name = "direct"

    def __init__(
        self, camera: CameraModel, mount: CameraMount, config: DirectConfig | None = None
    ) -> None:
        cfg = config if config is not None else default_config(camera.kind)
        super().__init__(camera, mount, cfg.filter, cfg.can_missing_inflation, cfg.flat_field)
        self.cfg = cfg
        self.levels = build_levels(camera, mount, cfg)
        roi0 = np.zeros(camera.height * camera.width, bool)
        roi0[self.levels[0].roi_idx] = True
        self._roi_full = roi0.reshape(camera.height, camera.width)
        self._roi_sample = self.levels[0].roi_idx[::4]  # ROI pixels for the frame checks
        self._prev: Frame | None = None
        self._compensator: FrameCompensator | None = None
        self._mask_lvl = min(max(cfg.mask_level, 0), cfg.levels - 1)
        mask_level = self.levels[self._mask_lvl]
        self._mask_roi = np.zeros(mask_level.shape[0] * mask_level.shape[1], bool)
        self._mask_roi[mask_level.roi_idx] = True
        self._mask_roi = self._mask_roi.reshape(mask_level.shape)
        set_mask_index(self.levels, self._mask_lvl)
        self._mask_scale = float(mask_level.scale)
        yaw_dir = yaw_direction(mount.lever_arm_m, self.R_car_cam)
        self._setup = FitSetup(
            cfg, camera, self.K0, self.R_car_cam, yaw_dir, self.levels, self._mask_scale
        )
        self._offroad: np.ndarray | None = None  # (H_m, W_m) uint8 of the previous frame
        self._carried: tuple[np.ndarray, int] | None = None  # last usual fit's map, its age
        self.offroad = OffroadMapper(camera, self.K0, self.levels, cfg, self._mask_lvl)
        self._gain = 1.0  # brightness gain B -> A of the last linearisation
        self._fine: FineLevel | None = None  # the last fit's finest level (`point_pull`)
        self._s2_hist: list[float] = []  # noise scales of the recent good fits
        self._road_prev: np.ndarray | None = None  # given road mask of the previous frame
        self._offroad_given: list[np.ndarray] | None = None  # its exclusions, per level
        # the road's seed pixels at the mask level (`estimator.egomotion.road_appearance`)
        self._look_seed = (
            mask_level.roi_idx[seed_indices(mask_level.roi_rays, self.K0)]
            if cfg.road_appearance
            else None
        )

    def compensate(
        self, image_prev: np.ndarray, dt_s: float, x: np.ndarray | None = None
    ) -> np.ndarray:
        """(H, W) float32 previous frame warped onto the current one with x (default x̂).

        Uses `estimator.egomotion.compensation.FrameCompensator` (per-camera maps built once).
        Pixels whose road ray is not seen in the previous frame are 0.
        """
        if self._compensator is None:  # built on first use: per-pixel maps of the camera
            self._compensator = FrameCompensator(self.camera, self.mount)
        x = self.ekf.x if x is None else x
        warped, ok = self._compensator.warp(image_prev, x, dt_s)
        return np.where(ok, warped, 0.0).astype(np.float32)

    def point_pull(self, x: np.ndarray) -> PointPull | None:
        """The last pair's finest-level inliers relinearised at the state x (9,) (a diagnostic:
        given the true state of a rendered drive, what each point asks of it).

        Each inlier's residual and row of C at x (`constraints.linearise`, the fit's
        brightness gain refitted there) with the fit's noise weighting (``adaptive_noise``,
        ``independent_points``); the step is eq. 17-18's from x with the prior's covariance
        P⁻ but not its mean: ``(P⁻⁻¹ + Cᵀ R⁻¹ C)⁻¹ Cᵀ R⁻¹ Δz``, split point by point. None
        when the last frame had no usable fit (the first frame, a bad frame, a failure).
        """
        x = check_state(x, "point_pull x")
        if self._fine is None:
            return None
        f, cfg, ekf = self._fine, self.cfg, self.ekf
        inlier = f.labels == INLIER
        idx, dz, C, R, _ = linearise(
            cfg, self.camera, self.K0, x, f.pts, f.B, f.dt, inlier, self._mask_scale
        )
        use = inlier[idx]
        idx, dz, C, R = idx[use], dz[use], C[use], R[use]
        if cfg.adaptive_noise:
            R = R * min(max(f.s2, 0.25), 100.0)
        if cfg.independent_points > 0 and len(idx) > cfg.independent_points:
            R = R * (len(idx) / cfg.independent_points)
        CR = C / R[:, None]
        # eq. 18 from x: H⁻¹ Cᵢᵀ Δzᵢ / Rᵢ per point (rows; H symmetric)
        H = ekf.P_prior_inv + C.T @ CR
        dx = (CR * dz[:, None]) @ np.linalg.inv(H)
        return PointPull(points_px=f.points_px[idx], dx=dx)

    # -- internals ----------------------------------------------------------------
    def _frame(self, gray: np.ndarray, t_s: float) -> Frame:
        """The frame's pyramid (`build_frame`) and, with ``road_appearance``, its map of
        what does not look like the road at the mask level."""
        quality = frame_quality(gray, self._roi_sample, self.cfg)
        frame = build_frame(gray, t_s, self.cfg, quality)
        if self._look_seed is not None and not quality:
            hm, wm = self.levels[self._mask_lvl].shape
            # the colour frame `step` was given (its gray when called without one)
            img = np.asarray(gray if self._image_new is None else self._image_new)
            if img.ndim == 3 and img.shape[2] == 1:
                img = img[:, :, 0]
            if img.dtype != np.uint8:
                img = np.clip(np.nan_to_num(img.astype(np.float32)), 0, 255).astype(np.uint8)
            small = cv2.resize(img, (wm, hm), interpolation=cv2.INTER_AREA)
            frame.offroad_look = offroad_by_appearance(small, self._look_seed)
        return frame

    def _first_frame(self, gray: np.ndarray, t_s: float, can: float) -> None:
        self._prev = self._frame(gray, t_s)
        self._road_prev = self._road_mask_new

    def _measure(
        self,
        gray: np.ndarray,
        t_s: float,
        dt: float,
        flags: list[str],
        reasons: list[str],
        compensate: bool | None,
    ) -> dict[str, Any]:
        prev, frame = self._prev, self._frame(gray, t_s)
        self._prev = frame
        self._fine = None  # set by a usable fit of this pair (`point_pull`)
        # the pair's points come from the previous frame: its road mask, per level
        self._offroad_given = given_offroad(self.cfg, self.levels, self._road_prev)
        self._road_prev = self._road_mask_new
        extra: dict[str, Any] = {}
        bad = [
            f"{which} {r}"
            for which, r in (("previous", prev.reason), ("current", frame.reason))
            if r
        ]
        if bad:
            flags.append("bad-frame")
            reasons.extend(bad)
        else:
            extra = self._estimate(prev, frame, dt, flags, reasons)
        if compensate if compensate is not None else self.cfg.compensate:
            extra["compensated"] = self.compensate(prev.gray, dt)
        return extra

    def _coarse_to_fine(
        self,
        A: Frame,
        B: Frame,
        dt: float,
        excluded: list[np.ndarray] | None,
        wide_level: int | None = None,
        from_wide: bool = False,
    ) -> Fit:
        """One coarse-to-fine pass (`coarse_to_fine.coarse_to_fine`) from the filter's
        prior; keeps its last brightness gain."""
        pair = Pair(A, B, dt, self._offroad_given)
        res, self._gain = coarse_to_fine(
            self._setup, self.ekf, pair, excluded, self._gain, wide_level, from_wide
        )
        return res

    def _failure(self, res: Fit, n_view: int = 0) -> tuple[str, str] | None:
        """(flag, reason) when the fit res is unusable, else None (`fit_failure`)."""
        return fit_failure(
            self.cfg, res, self._s2_hist, self.ekf, self._v_can, self.R_car_cam, n_view
        )

    def _estimate(
        self, A: Frame, B: Frame, dt: float, flags: list[str], reasons: list[str]
    ) -> dict[str, Any]:
        """The pair's fit (the module's steps); returns the record's point fields."""
        cfg, ekf = self.cfg, self.ekf
        look = A.offroad_look
        prev_map = self._offroad
        excl = (
            excluded(cfg, self.levels, self._mask_scale, prev_map, look)
            if cfg.offroad_mask
            else None
        )
        self._offroad = None
        res = self._coarse_to_fine(A, B, dt, excl)
        failure = self._failure(res)
        if (
            cfg.offroad_mask
            and cfg.own_map
            and prev_map is None
            and (failure is None or failure[0] == "poor-fit")
        ):
            # before the first good fit (the prior is the CAN's alone) with
            # ``first_map_residuals`` off: the plane-parallax marks alone
            residuals = cfg.first_map_residuals or bool(self._s2_hist)
            own = self.offroad.map(
                B, A, ekf.x, dt, self._gain, res["noise_scale"], True, residuals=residuals
            )
            own_excl = excluded(cfg, self.levels, self._mask_scale, own, look)
            res, failure, kept = own_map_refit(
                ekf, res, failure, lambda: self._coarse_to_fine(A, B, dt, own_excl), self._failure
            )
            if kept:
                flags.append("own-map")
                excl = own_excl
        if excl is not None and failure is not None and res["n_points"] < cfg.min_points:
            # the off-road map left too few points at the finest level (the coarse ones
            # may have fitted without it, `coarse_without_map`): a road is not textureless
            # because of a map, which a poor fit of the previous pair can make too wide;
            # fit without it
            flags.append("offroad-map-dropped")
            excl = None
            res = self._coarse_to_fine(A, B, dt, excl)
            failure = self._failure(res)
        if failure is None and cfg.yaw_jump_sigmas > 0:
            res, refitted = yaw_refit(
                cfg,
                ekf,
                self.R_car_cam[2],
                self._setup.yaw_dir,
                res,
                lambda: self._coarse_to_fine(A, B, dt, excl),
                self._failure,
            )
            if refitted:
                flags.append("yaw-jump")
        surprising = failure is None and unusual_noise(cfg, self._s2_hist, res["noise_scale"])
        if cfg.manoeuvre_retry and (
            surprising or (failure is not None and failure[0] in RETRIED_FAILURES)
        ):
            res, retried = manoeuvre_retry(
                cfg,
                ekf,
                manoeuvre_cov(cfg, self.R_car_cam, self.mount.lever_arm_m),
                res,
                failure is not None,
                lambda wide_level, from_wide: self._coarse_to_fine(
                    A, B, dt, excl, wide_level, from_wide
                ),
                self._failure,
            )
            if retried:
                flags.append("manoeuvre")  # a fit, not a fallback: the record is not degraded
                failure = None
        self._conclude(A, B, dt, res, failure, flags, reasons)
        res.pop("done_levels")
        fine = res.pop("fine")
        self._fine = fine if failure is None else None
        return res

    def _conclude(
        self,
        A: Frame,
        B: Frame,
        dt: float,
        res: Fit,
        failure: tuple[str, str] | None,
        flags: list[str],
        reasons: list[str],
    ) -> None:
        """The pair's outcome: a failure keeps the prior (flagged); a usual fit maps what
        is off the road for the next pair (else the last usual map is carried); the noise
        history, the off-road mapper's chain and the hold of A follow the fit."""
        cfg, ekf = self.cfg, self.ekf
        unusual = unusual_noise(cfg, self._s2_hist, res["noise_scale"])  # before it joins
        first_fit = failure is None and not self._s2_hist  # (it holds every good fit's)
        if failure is None:
            self._s2_hist = (self._s2_hist + [res["noise_scale"]])[-15:]
        if failure:
            flags.append(failure[0])
            reasons.append(failure[1])
            ekf.set_prior(ekf.x_prior, ekf.P_prior)
        elif cfg.offroad_mask and not unusual:
            # only a fit at the usual noise level says what is off the road: the
            # residuals of a poorer one would keep the next pair off the road itself
            self._offroad = self.offroad.map(A, B, ekf.x, dt, self._gain, res["noise_scale"])
            self._carried = self._offroad, 0
        if failure is None:
            self.offroad.remember(A, B, ekf.x, dt, self._gain)
        else:
            self.offroad.forget()
        if self._offroad is None and self._carried is not None:
            self._offroad, self._carried = carry_map(cfg, self._carried)
            if self._offroad is not None:
                flags.append("map-carried")
        if first_fit and not cfg.first_fit_A:
            ekf.hold_A()
            flags.append("A-held")
        elif failure is None and not cfg.fit_A:
            ekf.hold_A()  # A is the integral of the rates: the fit's tilt is dropped
