"""Baseline estimators with the interface of `DirectEstimator`, and the registry.

- `CanOnlyEstimator` ("can-only"): the prior alone, i.e. dead reckoning: V from
  the CAN speed along the car's x axis, W and A time-updated (W stays at its
  last value, 0 here; A decays to the nominal mount).
- `FeatureEstimator` ("features"): corners (``cv2.goodFeaturesToTrack``) in the
  road region of interest of the previous frame, tracked by pyramidal
  Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``, forward-backward checked) into the
  current frame warped back onto the previous one with the prior's homography
  (so that LK's translation-only window meets little distortion; the tracked
  positions are mapped forward through the same warp), then the same planar
  motion model fitted
  to the tracks: RANSAC over minimal sets (Gauss-Newton from the prior on
  ``ransac_sample`` tracks), then ``scipy.optimize.least_squares`` of the
  reprojection error in pixels over all RANSAC inliers with the prior
  (time update + CAN) as a soft term. The result and its covariance replace the
  filter's state, so the next time update starts from it.

`make_estimator(name, camera, mount, **cfg)` builds one by name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import EGO_BODY_BOX_M, default_config, make_config
from estimator.egomotion.ego_estimator import INLIER, OUTLIER, EgoMotionEstimator
from estimator.egomotion.homography import N_STATE, homography
from estimator.egomotion.iekf import FilterConfig
from estimator.egomotion.levels import road_roi
from estimator.egomotion.motion_model import warp_jacobian, warp_pixels
from estimator.plugins import check_estimator_class, is_plugin_name, load_class


# ------------------------------------------------------------------ CAN only
@dataclass(frozen=True)
class CanOnlyConfig:
    """Settings of `CanOnlyEstimator`."""

    can_missing_inflation: float = 4.0  # [-] variance factor on V when the CAN speed is lost
    filter: FilterConfig = field(default_factory=FilterConfig)


class CanOnlyEstimator(EgoMotionEstimator):
    """Dead reckoning: the filter's prior (time update + CAN speed), no image measurement."""

    name = "can-only"

    def __init__(
        self, camera: CameraModel, mount: CameraMount, config: CanOnlyConfig | None = None
    ) -> None:
        self.cfg = config or CanOnlyConfig()
        super().__init__(camera, mount, self.cfg.filter, self.cfg.can_missing_inflation)


# ------------------------------------------------------------------ features
@dataclass(frozen=True)
class FeatureConfig:
    """Settings of `FeatureEstimator` (units beside each value)."""

    max_corners: int = 400  # [-] corners detected in the previous frame
    quality_level: float = 0.005  # [-] cv2.goodFeaturesToTrack relative corner quality
    min_distance_px: float = 8.0  # [px] between corners
    lk_window_px: int = 21  # [px] Lucas-Kanade window side
    lk_levels: int = 3  # [-] LK pyramid levels above the full resolution
    fb_max_px: float = 0.5  # [px] forward-backward tracking error accepted
    sigma_px: float = 0.3  # [px] std of a track's end point
    ransac_iterations: int = 40  # [-]
    ransac_sample: int = 5  # [-] tracks per minimal set (2 equations each; prior completes)
    inlier_px: float = 1.0  # [px] reprojection error of a RANSAC inlier
    min_tracks: int = 15  # [-] fewer inliers: degraded, prior kept
    max_range_m: float = 30.0  # [m] farthest road point used
    ego_box_m: tuple[float, float, float] | None = EGO_BODY_BOX_M  # [m] see DirectConfig
    ego_margin_m: float = 0.1  # [m]
    roi_erode_px: int = 6  # [px] distance kept from image edges (body, horizon)
    seed: int = 0  # RANSAC sampling
    can_missing_inflation: float = 4.0  # [-] variance factor on V when the CAN speed is lost
    filter: FilterConfig = field(default_factory=FilterConfig)


def roi_mask(
    camera: CameraModel,
    mount: CameraMount,
    max_range_m: float,
    ego_box_m: tuple[float, float, float] | None,
    ego_margin_m: float,
    erode_px: int,
) -> np.ndarray:
    """(H, W) uint8 road region of interest (255 inside) at full resolution."""
    rays = camera.pixel_rays().astype(np.float64).reshape(-1, 3)
    valid = camera.valid_mask().reshape(-1)
    seen, in_range = road_roi(mount, np.nan_to_num(rays), max_range_m, ego_box_m, ego_margin_m)
    clean = (valid & seen).reshape(camera.height, camera.width).astype(np.uint8)
    clean = cv2.erode(clean, np.ones((3, 3), np.uint8), iterations=erode_px)
    return ((clean > 0) & in_range.reshape(clean.shape)).astype(np.uint8) * 255


class FeatureEstimator(EgoMotionEstimator):
    """Feature tracks + robust fit of the planar motion model (module docstring)."""

    name = "features"

    def __init__(
        self, camera: CameraModel, mount: CameraMount, config: FeatureConfig | None = None
    ) -> None:
        self.cfg = cfg = config or FeatureConfig()
        super().__init__(camera, mount, cfg.filter, cfg.can_missing_inflation)
        self.mask = roi_mask(
            camera, mount, cfg.max_range_m, cfg.ego_box_m, cfg.ego_margin_m, cfg.roi_erode_px
        )
        self._prev: np.ndarray | None = None
        self._road_prev: np.ndarray | None = None  # given road mask of the previous frame
        self._pixel_rays: np.ndarray | None = None
        self._rng = np.random.default_rng(cfg.seed)

    def _first_frame(self, gray: np.ndarray, t_s: float, can: float) -> None:
        self._prev = _to_u8(gray)
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
        cfg, cam, ekf = self.cfg, self.camera, self.ekf
        img_a, img_b = self._prev, _to_u8(gray)
        self._prev = img_b
        mask = self.mask  # corners of A: in the ROI, and on A's given road mask if any
        if self._road_prev is not None:
            mask = np.where(self._road_prev, mask, 0).astype(np.uint8)
        self._road_prev = self._road_mask_new
        corners = cv2.goodFeaturesToTrack(
            img_a, cfg.max_corners, cfg.quality_level, cfg.min_distance_px, mask=mask
        )
        if corners is None or len(corners) < cfg.min_tracks:
            return self._fail(
                flags,
                reasons,
                "no-features",
                f"fewer than {cfg.min_tracks} corners in the road ROI",
            )
        w_a = corners.reshape(-1, 2).astype(np.float64)
        rays = cam.unproject(w_a)
        # B warped onto A with the prior: B'(w) = B(w_b(w; x⁻)); track A -> B'
        H = homography(ekf.x, self.K0, dt)
        if self._pixel_rays is None:
            self._pixel_rays = cam.pixel_rays().astype(np.float64).reshape(-1, 3)
        m = np.nan_to_num(warp_pixels(cam, self._pixel_rays, H), nan=-10.0).astype(np.float32)
        img_b_on_a = cv2.remap(
            img_b,
            m.reshape(cam.height, cam.width, 2),
            None,
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
        )
        w_tr = _track(img_a, img_b_on_a, w_a, w_a, cfg)
        w_b = warp_pixels(cam, cam.unproject(np.nan_to_num(w_tr)), H)
        good = np.all(np.isfinite(w_tr), axis=1) & np.all(np.isfinite(w_b), axis=1)
        w_a, rays, w_b = w_a[good], rays[good], w_b[good]
        if len(w_a) < cfg.min_tracks:
            return self._fail(
                flags, reasons, "no-tracks", f"only {len(w_a)} corners tracked (< {cfg.min_tracks})"
            )
        L_prior = np.linalg.cholesky(ekf.P_prior_inv).T  # |L (x - x⁻)|² = prior cost
        inl = self._ransac(rays, w_b, dt, L_prior)
        labels = np.where(inl, INLIER, OUTLIER).astype(np.int8)
        extra = {
            "n_points": len(w_a),
            "n_inliers": int(inl.sum()),
            "points_px": w_a,
            "point_labels": labels,
            "iterations": (1,),
        }
        if inl.sum() < cfg.min_tracks:
            self._fail(
                flags,
                reasons,
                "few-inliers",
                f"only {int(inl.sum())} of {len(w_a)} tracks fit the road motion",
            )
            return extra
        x, P = self._fit(rays[inl], w_b[inl], dt, L_prior)
        ekf.x, ekf.P = x, P
        return extra

    def _residual(
        self, x: np.ndarray, rays: np.ndarray, w_b: np.ndarray, dt: float, L_prior: np.ndarray
    ) -> np.ndarray:
        w = warp_pixels(self.camera, rays, homography(x, self.K0, dt))
        r = np.nan_to_num((w - w_b) / self.cfg.sigma_px, nan=1e3).ravel()
        return np.r_[r, L_prior @ (x - self.ekf.x_prior)]

    def _jacobian(
        self, x: np.ndarray, rays: np.ndarray, w_b: np.ndarray, dt: float, L_prior: np.ndarray
    ) -> np.ndarray:
        _, J = warp_jacobian(self.camera, rays, x, self.K0, dt)
        J = np.nan_to_num(J / self.cfg.sigma_px).reshape(-1, N_STATE)
        return np.vstack([J, L_prior])

    def _ransac(
        self, rays: np.ndarray, w_b: np.ndarray, dt: float, L_prior: np.ndarray
    ) -> np.ndarray:
        """(N,) bool inliers of the best minimal-set hypothesis (2 Gauss-Newton steps each)."""
        cfg, cam = self.cfg, self.camera
        n = len(rays)
        x0 = self.ekf.x_prior
        best, best_count = np.zeros(n, bool), -1
        hypotheses = [None] + [
            self._rng.choice(n, min(cfg.ransac_sample, n), replace=False)
            for _ in range(cfg.ransac_iterations)
        ]
        for sample in hypotheses:
            x = x0.copy()
            if sample is not None:
                for _ in range(2):
                    r = self._residual(x, rays[sample], w_b[sample], dt, L_prior)
                    J = self._jacobian(x, rays[sample], w_b[sample], dt, L_prior)
                    x = x - np.linalg.lstsq(J, r, rcond=None)[0]
            err = np.linalg.norm(warp_pixels(cam, rays, homography(x, self.K0, dt)) - w_b, axis=1)
            inl = np.nan_to_num(err, nan=np.inf) < cfg.inlier_px
            if inl.sum() > best_count:
                best, best_count = inl, int(inl.sum())
        return best

    def _fit(
        self, rays: np.ndarray, w_b: np.ndarray, dt: float, L_prior: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """MAP fit over x (reprojection error [px] + prior) and its covariance (9, 9)."""
        sol = least_squares(
            self._residual,
            self.ekf.x_prior,
            jac=self._jacobian,
            args=(rays, w_b, dt, L_prior),
            method="lm",
        )
        J = sol.jac
        P = np.linalg.inv(J.T @ J)
        return sol.x, 0.5 * (P + P.T)

    def _fail(self, flags: list[str], reasons: list[str], flag: str, why: str) -> dict[str, Any]:
        flags.append(flag)
        reasons.append(f"{why}: prior kept")
        return {}


def _to_u8(gray: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


def _track(
    img_a: np.ndarray, img_b: np.ndarray, w_a: np.ndarray, w_pred: np.ndarray, cfg: FeatureConfig
) -> np.ndarray:
    """(N, 2) LK positions in B of points w_a of A (NaN: lost or forward-backward > max)."""
    pa = w_a.astype(np.float32).reshape(-1, 1, 2)
    pb0 = w_pred.astype(np.float32).reshape(-1, 1, 2)
    win = (cfg.lk_window_px, cfg.lk_window_px)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    pb, st, _ = cv2.calcOpticalFlowPyrLK(
        img_a,
        img_b,
        pa,
        pb0.copy(),
        winSize=win,
        maxLevel=cfg.lk_levels,
        criteria=crit,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    pa2, st2, _ = cv2.calcOpticalFlowPyrLK(
        img_b,
        img_a,
        pb,
        pa.copy(),
        winSize=win,
        maxLevel=cfg.lk_levels,
        criteria=crit,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    fb = np.linalg.norm((pa2 - pa).reshape(-1, 2), axis=1)
    ok = (st.ravel() == 1) & (st2.ravel() == 1) & (fb < cfg.fb_max_px)
    out = pb.reshape(-1, 2).astype(np.float64)
    out[~ok] = np.nan
    return out


# ------------------------------------------------------------------ registry
ESTIMATORS: dict[str, type[EgoMotionEstimator]] = {
    DirectEstimator.name: DirectEstimator,
    CanOnlyEstimator.name: CanOnlyEstimator,
    FeatureEstimator.name: FeatureEstimator,
}
_CONFIGS: dict[str, type] = {"can-only": CanOnlyConfig, "features": FeatureConfig}


def check_estimator(name: str) -> str:
    """``name`` if it is a known estimator or a plug-in that follows the protocol
    (`estimator.plugins`); ValueError naming it and what is wrong otherwise."""
    if name in ESTIMATORS:
        return name
    if is_plugin_name(name):
        check_estimator_class(load_class(name), name)
        return name
    raise ValueError(
        f"unknown estimator {name!r}; choose one of {', '.join(ESTIMATORS)} or a plug-in "
        "package.module:ClassName"
    )


def make_estimator(
    name: str, camera: CameraModel, mount: CameraMount, **cfg: Any
) -> EgoMotionEstimator:
    """Estimator ``name`` ("direct", "can-only", "features" or a plug-in,
    `estimator.plugins`) with config overrides ``cfg`` (a plug-in's keyword settings).

    Overrides are the fields of the estimator's config dataclass (nested
    ``filter={...}`` for `FilterConfig`); "direct" starts from the camera kind's
    defaults (`estimator.egomotion.direct_config.default_config`).
    """
    check_estimator(name)
    if name not in ESTIMATORS:  # a plug-in
        return load_class(name)(camera, mount, **cfg)
    if name == "direct":
        return DirectEstimator(camera, mount, default_config(camera.kind, **cfg))
    return ESTIMATORS[name](camera, mount, make_config(_CONFIGS[name], cfg, name))
