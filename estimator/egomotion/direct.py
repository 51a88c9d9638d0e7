"""Direct ego-motion estimation from image gradients (paper section 4.2).

For each new frame B (previous frame A)::

    Gaussian pyramids of A and B; x̂ = x⁻, P = P⁻ (time update eq. 19 + CAN speed)
    for each level, coarsest to finest:
        0. select points of A (below), drop those that stay put while the road moves
           (ego body, mount: `_static_points`); on ``search_levels``, a grid search
           over the speed scale and the yaw rate puts x̂ within reach (`_search`)
        then several iterations of:
        1. warp B at the selected points of A with x̂ (motion model, one cv2.remap)
        2. spatial gradients of B there, temporal gradient g_t = B(w_b) - A(w_a)
        3. constraint rows C = g^T dw_b/dx, innovation Δz = -g_t (eq. 13-16)
        4. reclassify points by data snooping (eq. 20-21), R scaled by the robust
           residual level s² (median of Δz²/R, ``adaptive_noise``)
        5. IEKF update with the inliers (eq. 17-18); a step that raised the
           posterior cost is halved (``line_search``)
    a fit that moved the yaw rate far beyond what the prior allowed (a change of turn
    rate that the random walk of eq. 19 cannot follow) is refitted with the prior's yaw
    rate widened, so that the images and not the old rate tell it (`_yaw_refit`)
    a fit that fails, or whose residuals are far above the recent ones, is retried
    with the manoeuvre covariance added to the prior (abrupt turns, side slip): one
    pass per ``manoeuvre_search_levels`` level, each starting with one wide grid
    search at that level (and one more from each finer level that skips the coarser
    ones, `manoeuvre_fine_passes`), its finer levels refining locally
    (``manoeuvre_local_search``) and iterating up to ``manoeuvre_iterations``; the best
    fit of those kept. A fit's inliers are counted against the points it sees when its
    motion turns part of the road out of view (``seen_inlier_fraction``)
    a fit whose forward speed contradicts the CAN beyond its scale error (the images
    locked onto a wrong motion, e.g. a sudden yaw traded for speed) is a failure too
    the residual of A compensated onto B marks what the road motion does not explain
    (objects above the road, vehicles, the ego body), and so does a plane-parallax
    test (a plane above the road explains the pixels better: posts, rails, kerbs,
    `estimator.egomotion.offroad_map`): the next pair, where B is A, takes no points there
    (`OffroadMapper.map`, at full resolution for omni cameras: a post is a few pixels wide)
    after a failed or unusual fit the last usual fit's map is carried over, dilated,
    for ``map_carry`` pairs (flag ``map-carried``; the pinhole's setting: a vehicle
    close behind fills the view); a pair without a map from the previous pair (the
    first pair; after a failed or unusual fit, beyond the carry) maps A from its own
    fit (the same tests run backward) and fits again
    without those pixels (flag ``own-map``; kept only if it fits at least as well); a
    map that leaves the finest level too few points is dropped for the pair (flag
    ``offroad-map-dropped``): a road is not textureless because of a map; a coarse
    level it leaves too few selects without it (``coarse_without_map``)
    with ``first_fit_A`` off (the pinhole's setting), the first fit's A is dropped: A
    stays at the mount with its process's stationary std (flag ``A-held``); with
    ``fit_A`` off (the pinhole's setting too), so is every later fit's: A is then the
    integral of the measured roll/pitch rates

Points: pixels of A in the road region of interest (valid camera ray, hitting
the road below the horizon within ``max_range_m`` of the car, not through the
ego car's body, not in the off-road mask) whose gradient magnitude passes a
threshold, thinned by non-maximal suppression and capped at ``max_points``: the
most informative ones (``selection="information"``: the brightness change the
prior's uncertainty predicts, relative to the noise, each state direction
counting equally), spread over a grid of cells. Everything that depends only on
the camera (ROI masks, rays and nominal motion Jacobians of candidate pixels per
level, whole-image rays for motion compensation) is computed once.

Why these steps (measured on rendered drives, see the tests and the report of
this change): the road ring of an omni image is crowded with guard rails, posts,
vehicles and the ego car's roof, whose image motion is not the road's; at the
pyramid's coarse levels their blur leaks into road points. Points picked by
gradient strength sit on exactly those structures, and a coarse level biased by
them leaves the finest level in a wrong local minimum a few pixels away (the
brightness-constancy cost is not convex beyond about a pixel).

Pyramid levels are addressed in full-resolution pixels: ``cv2.pyrDown`` puts
level-l pixel (i, j) at full-resolution pixel (2^l i, 2^l j), so a point's ray
is ``camera.unproject`` of its full-resolution position and level gradients
are divided by 2^l. No downscaled camera is needed.

`EgoMotionEstimator` (base of all estimators, also `estimator.egomotion.baselines`) does
the input checks, the time update and the CAN prior, and builds the record. A
CAN speed that rules out the predicted speed (beyond its bounded scale error)
re-initialises the speed and the yaw rate (flag ``can-reset``).

Degraded inputs never raise (except a frame of the wrong size, or time not
increasing: caller errors) and never give a silent number: ``degraded=True``
with a reason and flags. A dark or saturated frame, a textureless road, too few
inliers, a poor fit (s² > ``max_noise_scale``: the road did not align, also
with the manoeuvre prior) or a fit that contradicts the CAN give the prior
(time update + CAN); a missing CAN speed (time-updated speed, V covariance
inflated) or a time gap (Q grows with dt) are flagged and the images still
measure.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.compensation import FrameCompensator
from estimator.egomotion.direct_config import DirectConfig, default_config
from estimator.egomotion.ego_estimator import (
    INLIER,
    OUTLIER,
    UNUSED,
    EgoMotionEstimator,
    PointPull,
    frame_quality,
)
from estimator.egomotion.fast_stats import fast_median, fast_percentile, nan_to_num_fast
from estimator.egomotion.homography import (
    A_SLICE,
    N_STATE,
    V_SLICE,
    W_SLICE,
    check_state,
    dh_dx,
    homographies,
    homography,
)
from estimator.egomotion.iekf import data_snooping, robust_weights, yaw_direction
from estimator.egomotion.levels import Level, build_levels
from estimator.egomotion.motion_model import constraint_rows, map_rays
from estimator.egomotion.offroad_map import OffroadMapper
from estimator.egomotion.point_selection import column_scale, select_points
from estimator.egomotion.pyramid import (
    Frame,
    build_frame,
    in_level,
    sample_points,
    valid_at,
)
from estimator.egomotion.road_appearance import offroad_by_appearance, seed_indices

# Rows of (N, k) arrays are gathered with np.take(a, i, 0) rather than a[i]: the same
# values, 3-6x faster in numpy 2 (59k rays: 0.08 vs 0.47 ms).


class _FineLevel(NamedTuple):
    """What a fit kept of its finest level for `DirectEstimator.point_pull`: its points'
    pixels (N, 2) in frame A [px], rays (N, 3), A's brightness (N,), the pair's second
    frame, the given road mask's off-road flags (N,) or None, A's level pixels (N, 2) for
    ``flow_noise_frac`` or None, the ``far_depth_m`` flags (N,) or None, dt [s], labels (N,)
    and the noise scale s²."""

    level: Level
    points_px: np.ndarray
    rays: np.ndarray
    a_val: np.ndarray
    B: Frame
    off: np.ndarray | None
    w_a: np.ndarray | None
    far: np.ndarray | None
    dt: float
    labels: np.ndarray
    s2: float


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """a | b of two (H, W) uint8 maps, either None (absent)."""
    if a is None or b is None:
        return a if b is None else b
    return a | b


class DirectEstimator(EgoMotionEstimator):
    """Direct (gradient-based) IEKF ego-motion estimator of the paper (section 4).

    ``step(image, t_s, can_speed_mps) -> EgoMotionRecord``; the first call only
    initialises. Holds the previous frame's pyramid, the per-level camera
    precomputations (`Level`) and the filter (`IteratedEKF`).
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
        grid = self.levels[self._mask_lvl]
        hm, wm = grid.shape
        sm = float(grid.scale)
        for level in self.levels:
            um = np.clip(np.rint(level.roi_w[:, 0] / sm), 0, wm - 1).astype(np.int64)
            vm = np.clip(np.rint(level.roi_w[:, 1] / sm), 0, hm - 1).astype(np.int64)
            level.to_mask = vm * wm + um
        self._offroad: np.ndarray | None = None  # (H_m, W_m) uint8 of the previous frame
        self._carried: tuple[np.ndarray, int] | None = None  # last usual fit's map, its age
        self.offroad = OffroadMapper(camera, self.K0, self.levels, cfg, self._mask_lvl)
        self._gain = 1.0  # brightness gain B -> A of the last linearisation
        self._fine: _FineLevel | None = None  # the last fit's finest level (`point_pull`)
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

        Each inlier's residual and row of C at x (`_linearise`, the fit's brightness gain
        refitted there) with the fit's noise weighting (``adaptive_noise``,
        ``independent_points``); the step is eq. 17-18's from x with the prior's covariance
        P⁻ but not its mean: ``(P⁻⁻¹ + Cᵀ R⁻¹ C)⁻¹ Cᵀ R⁻¹ Δz``, split point by point. None
        when the last frame had no usable fit (the first frame, a bad frame, a failure).
        """
        x = check_state(x, "point_pull x")
        if self._fine is None:
            return None
        f, cfg, ekf = self._fine, self.cfg, self.ekf
        inlier = f.labels == INLIER
        saved = ekf.x, self._gain
        ekf.x = x
        try:
            idx, dz, C, R = self._linearise(
                f.level, 0, f.rays, f.a_val, f.B, f.dt, inlier, f.off, f.w_a, f.far
            )
        finally:
            ekf.x, self._gain = saved
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
        self._offroad_given = self._given_offroad(self._road_prev)
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

    def _linearise(
        self,
        level: Level,
        lvl: int,
        rays: np.ndarray,
        a_val: np.ndarray,
        B: Frame,
        dt: float,
        included: np.ndarray,
        off: np.ndarray | None = None,
        w_a: np.ndarray | None = None,
        far: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Steps 1-3 at x̂: (idx (M,) points that land in B, Δz (M,), C (M, 9), R (M,)).

        w_a: (len(rays), 2) the points' level pixels in A, for ``flow_noise_frac``.

        off: (len(rays),) bool, points that a given road mask puts off the road: their
        plane scale lambda is unknown (std ``offroad_depth_sigma``); since D is linear in
        V, the residual's derivative w.r.t. lambda is the one w.r.t. the speed scale,
        ``C V``, and ``(sigma C V)²`` joins R: they tell the rotation, hardly the speed.
        far: (len(rays),) bool, the points whose plane scale is unknown because their road
        hit is far (`_far_points`): the same noise.
        """
        cfg, cam, x = self.cfg, self.camera, self.ekf.x
        s = float(level.scale)
        # step 1: warp the points into B with x̂ (eq. 3, 6-10)
        P_b = map_rays(rays, homography(x, self.K0, dt))
        w_b = cam.project(P_b) / s  # level pixels
        inside = in_level(w_b, P_b, self.K0, level.shape)
        idx = np.flatnonzero(valid_at(level.valid_b, w_b, inside))
        if B.offroad_look is not None and len(idx):
            # a point that lands where B does not look like the road (a vehicle moved over
            # it) is not measured: its brightness there is not the road's
            look = B.offroad_look
            f = s / float(self.levels[self._mask_lvl].scale)
            u = np.clip(np.rint(w_b[idx, 0] * f), 0, look.shape[1] - 1).astype(np.intp)
            v = np.clip(np.rint(w_b[idx, 1] * f), 0, look.shape[0] - 1).astype(np.intp)
            keep = look[v, u] == 0
            if off is not None:
                keep |= off[idx]
            idx = idx[keep]
        # step 2: brightness and spatial gradient of B at w_b, temporal gradient
        smp = sample_points(B.stacks[lvl], np.take(w_b, idx, 0))
        b_val, g = smp[:, 0].astype(np.float64), smp[:, 1:3].astype(np.float64)
        a_i = a_val[idx]
        gain = 1.0
        if cfg.gain_compensation and len(idx):
            use = included[idx] if included[idx].sum() >= cfg.min_points else slice(None)
            gain = float(np.dot(a_i[use], b_val[use]) / max(np.dot(b_val[use], b_val[use]), 1e-9))
        self._gain = gain
        # eq. 15: Δz = -g_t, g_t = B(w_b) - A(w_a) (B scaled by the brightness gain)
        dz = a_i - gain * b_val
        g *= gain
        g2 = g[:, 0] * g[:, 0] + g[:, 1] * g[:, 1]  # (the sum over axis 1, ~3x faster)
        R = cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * g2
        if cfg.flow_noise_frac > 0 and w_a is not None:
            flow = np.take(w_b, idx, 0) - np.take(w_a, idx, 0)  # [level px]
            R = R + cfg.flow_noise_frac**2 * np.sum(flow * flow, axis=1) * g2
        # step 3, eq. 14-16: C_i = g_i^T dw_b/dx (gradient per full-resolution pixel)
        C = constraint_rows(
            cam, np.take(rays, idx, 0), np.take(P_b, idx, 0), g / s, dh_dx(x, self.K0, dt)
        )
        if far is not None:
            off = far if off is None else off | far
        if off is not None and cfg.offroad_depth_sigma > 0:
            lam_var = np.square(cfg.offroad_depth_sigma * (C[:, V_SLICE] @ x[V_SLICE]))
            R = R + np.where(off[idx], lam_var, 0.0)
        return idx, dz, C, R

    def _classify(
        self, dz: np.ndarray, C: np.ndarray, R: np.ndarray, included: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Step 4: (use (M,) bool, R (M,) possibly rescaled/reweighted, noise scale s²).

        s² = median(Δz²/R) / 0.455 (the median of a chi² with 1 dof): about 1 when
        the residuals match R; ``adaptive_noise`` multiplies R by it (clipped).
        """
        cfg = self.cfg
        s2 = fast_median(dz * dz / R) / 0.455
        if cfg.adaptive_noise:
            R = R * min(max(s2, 0.25), 100.0)
        if cfg.outliers == "snooping":
            # eq. 20-21: each residual against its expected variance, reclassified
            use, _ = data_snooping(dz, C, self.ekf.P, R, included, cfg.snoop_threshold)
            return use, R, s2
        if cfg.outliers in ("huber", "tukey"):
            wgt = robust_weights(dz, np.sqrt(R), cfg.outliers, cfg.robust_k)
            return wgt > 0, R / np.maximum(wgt, 1e-12), s2
        return np.ones(len(dz), bool), R, s2

    def _estimate(
        self, A: Frame, B: Frame, dt: float, flags: list[str], reasons: list[str]
    ) -> dict[str, Any]:
        """Coarse-to-fine IEKF iterations (section 4.2); returns the record's point fields.

        When the road does not align from the prior (too few inliers or a poor fit) and
        ``manoeuvre_retry`` is set, the update is run again from the same prior mean
        with the manoeuvre covariance added (`_manoeuvre_cov`): an abrupt turn or
        side-slip that the random walk of eq. 19 cannot follow. The retry makes one pass
        per ``manoeuvre_search_levels`` level, each opening with a wide grid search at
        that level: a coarse level sees a large yaw jump within a few grid steps, a fine
        one has the points to rank the grid when the coarse levels have few (a far
        camera, a slow drive). The retry's best fit is kept only if it fits.
        """
        cfg, ekf = self.cfg, self.ekf
        look = A.offroad_look
        prev_map = self._offroad
        excl = self._excluded(prev_map, look) if cfg.offroad_mask else None
        self._offroad = None
        res = self._coarse_to_fine(A, B, dt, excl)
        failure = self._failure(res)
        if (
            cfg.offroad_mask
            and cfg.own_map
            and prev_map is None
            and (failure is None or failure[0] == "poor-fit")
        ):
            # no map from the previous pair (the first pair; after a failed or unusual fit):
            # map frame A from this pair's own fit, and fit again without those pixels. Its
            # noise scale may well be unusual: the raised structure the map would remove
            # is in it (waiting for a usual fit would lock the map out). A poor fit too: a
            # vehicle close behind fills the road with motion the road's model cannot fit
            # (rectilinear merge, frames 90-108)
            # before the first good fit (the prior is the CAN's alone) with
            # ``first_map_residuals`` off: the plane-parallax marks alone
            residuals = cfg.first_map_residuals or bool(self._s2_hist)
            own = self.offroad.map(
                B, A, ekf.x, dt, self._gain, res["noise_scale"], True, residuals=residuals
            )
            excl_first, excl = excl, self._excluded(own, look)
            first = res, self.ekf.x.copy(), self.ekf.P.copy(), failure
            res = self._coarse_to_fine(A, B, dt, excl)
            failure = self._failure(res)
            # the map takes out what did not fit: the refit must fit at least as well. A
            # worse one says the first fit was off and its map took the road itself out
            # (merge-omni-near frame 1: a fit at the CAN's +8 % marked 3/4 of the points,
            # the refit on the rest went to +32 % at a higher noise scale)
            if failure is None and res["noise_scale"] <= first[0]["noise_scale"]:
                flags.append("own-map")
            else:  # (the map left too few points, or a worse fit): the first fit, as it was
                excl = excl_first
                res, self.ekf.x, self.ekf.P, failure = first
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
            res = self._yaw_refit(A, B, dt, excl, res, flags)
        surprising = failure is None and self._unusual_noise(res["noise_scale"])
        if cfg.manoeuvre_retry and (
            surprising
            or (
                failure is not None
                and failure[0] in ("few-inliers", "poor-fit", "can-contradiction")
            )
        ):
            first = res, ekf.x.copy(), ekf.P.copy()
            x_prior, P_prior = ekf.x_prior.copy(), ekf.P_prior.copy()
            # one pass per level of the wide search (a coarse level sees farther, a fine one
            # has the points): the best fit of those that did not fail
            wide_prior = P_prior + self._manoeuvre_cov()
            best = None
            for wide_level in cfg.manoeuvre_search_levels:
                if not 0 <= wide_level < cfg.levels:
                    continue
                coarser = False  # the full pass iterated a level coarser than wide_level
                for from_wide in (False, True):
                    # a pass from the wide level itself is the full one again unless that
                    # iterated a coarser level (which may lack the points to)
                    if from_wide and not (cfg.manoeuvre_fine_passes and coarser):
                        break
                    ekf.set_prior(x_prior, wide_prior)
                    r = self._coarse_to_fine(A, B, dt, excl, wide_level, from_wide)
                    coarser = any(r["iterations"][: cfg.levels - 1 - wide_level])
                    if self._failure(r, first[0]["n_points"]) is None and (
                        best is None or r["noise_scale"] < best[0]["noise_scale"]
                    ):
                        best = r, ekf.x.copy(), ekf.P.copy()
            better = best is not None and (
                failure is not None
                or best[0]["noise_scale"] < first[0]["noise_scale"] / cfg.retry_gain
            )
            if better:
                ekf.set_prior(x_prior, wide_prior)  # the record's prior: the retry's
                res, ekf.x, ekf.P = best
                flags.append("manoeuvre")  # a fit, not a fallback: the record is not degraded
                failure = None
            else:
                ekf.set_prior(x_prior, P_prior)
                res, ekf.x, ekf.P = first
        unusual = self._unusual_noise(res["noise_scale"])  # before this fit joins the history
        first_fit = failure is None and not self._s2_hist  # (the history holds every good fit's)
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
            self._offroad = self._carry_map(flags)
        if first_fit and not cfg.first_fit_A:
            ekf.hold_A()
            flags.append("A-held")
        elif failure is None and not cfg.fit_A:
            ekf.hold_A()  # A is the integral of the rates: the fit's tilt is dropped
        res.pop("done_levels")
        fine = res.pop("fine")
        self._fine = fine if failure is None else None
        return res

    def _carry_map(self, flags: list[str]) -> np.ndarray | None:
        """The last usual fit's off-road map for the next pair, dilated by ``map_carry_px``
        per pair carried (flag ``map-carried``); None after ``map_carry`` pairs."""
        m, age = self._carried
        if age >= self.cfg.map_carry:
            self._carried = None
            return None
        r = self.cfg.map_carry_px
        m = cv2.dilate(m, np.ones((2 * r + 1, 2 * r + 1), np.uint8)) if r > 0 else m
        self._carried = m, age + 1
        flags.append("map-carried")
        return m

    def _unusual_noise(self, s2: float) -> bool:
        """A fit's noise scale s² more than ``retry_noise_ratio`` times the median of the
        recent good fits (False until there are 3 of them)."""
        if len(self._s2_hist) < 3:
            return False
        usual = fast_median(np.asarray(self._s2_hist))
        return s2 > self.cfg.retry_noise_ratio * max(usual, 0.25)

    def _yaw_shift(self) -> tuple[float, float]:
        """(shift, expected std) of the car's yaw rate from the prior to the fit [rad/s].

        The filter expects the update to move x̂ with covariance P⁻ - P⁺ (that of the
        innovation mapped by the gain); a larger shift says the prior was off.
        """
        ekf, n = self.ekf, self.R_car_cam[2]  # yaw rate = n . W
        shift = float(n @ (ekf.x[W_SLICE] - ekf.x_prior[W_SLICE]))
        dP = ekf.P_prior[W_SLICE, W_SLICE] - ekf.P[W_SLICE, W_SLICE]
        return shift, math.sqrt(max(float(n @ dP @ n), 0.0))

    def _yaw_refit(
        self,
        A: Frame,
        B: Frame,
        dt: float,
        excl: list[np.ndarray] | None,
        res: dict[str, Any],
        flags: list[str],
    ) -> dict[str, Any]:
        """Refit when the fit moved the yaw rate beyond what the prior allows.

        The random walk of eq. 19 keeps a steady turn rate steady; when the road says the
        rate changed by d, far beyond the prior's std, the posterior is a compromise that
        holds part of the old rate. The refit widens the prior's yaw rate by
        ``yaw_jump_widen`` x |d| (with the sideways speed it drags at the camera's lever
        arm) from the same prior mean: the images then tell the new rate. Kept when it
        does not fail; the prior widened is then the record's prior (flag ``yaw-jump``).
        A refit that moved the rate by more than half again its widened std (the step is
        larger than the first shift said) is refitted with the std its own shift asks
        for, up to ``yaw_jump_rounds`` refits, each kept when it does not fail (as the
        first refit is).
        """
        cfg, ekf = self.cfg, self.ekf
        shift, sd = self._yaw_shift()
        if abs(shift) <= cfg.yaw_jump_sigmas * max(sd, 1e-9):
            return res
        x_prior, P_prior = ekf.x_prior.copy(), ekf.P_prior.copy()
        n_view = res["n_points"]
        best = res, ekf.x.copy(), ekf.P.copy(), P_prior
        refitted = False
        sigma = cfg.yaw_jump_widen * abs(shift)
        for _ in range(cfg.yaw_jump_rounds):
            wide = P_prior + self._yaw_cov(sigma)
            ekf.set_prior(x_prior, wide)
            r = self._coarse_to_fine(A, B, dt, excl)
            if self._failure(r, n_view) is not None:
                break
            best, refitted = (r, ekf.x.copy(), ekf.P.copy(), wide), True
            shift = self._yaw_shift()[0]  # (from the same prior mean)
            if cfg.yaw_jump_widen * abs(shift) <= 1.5 * sigma:
                break
            sigma = cfg.yaw_jump_widen * abs(shift)
        res, x, P, prior_P = best
        # the record's prior: the widened one of the refit kept (the fit's own when none)
        ekf.set_prior(x_prior, prior_P)  # (resets x̂ to the prior mean: set it after)
        ekf.x, ekf.P = x, P
        if refitted:
            flags.append("yaw-jump")
        return res

    def _yaw_cov(self, sigma_rps: float) -> np.ndarray:
        """(9, 9) covariance of a change of the car's yaw rate with std sigma_rps (camera
        axes), with the sideways speed it moves the camera by at the lever arm."""
        g = yaw_direction(self.mount.lever_arm_m, self.R_car_cam)
        return sigma_rps**2 * np.outer(g, g)

    def _manoeuvre_cov(self) -> np.ndarray:
        """(9, 9) covariance added to the prior for the manoeuvre retry (camera axes)."""
        cfg, Rc, lever = self.cfg, self.R_car_cam, self.mount.lever_arm_m
        # car axes: roll and pitch rates (vibration), the yaw rate (the manoeuvre); with the
        # rear axle known (kinematic model), a turn also moves the viewpoint sideways by
        # lever x yaw rate (`yaw_direction`) and the slip at the axle is the small part,
        # manoeuvre_slip_sigma_mps
        sig_W = np.array([cfg.manoeuvre_W_plane_sigma_rps] * 2 + [cfg.manoeuvre_W_sigma_rps])
        G = np.zeros((N_STATE, 3))  # car-frame W -> state (W and the coupled V)
        G[W_SLICE, :2] = Rc.T[:, :2]
        G[:, 2] = yaw_direction(lever, Rc)
        Q = G @ np.diag(np.square(sig_W)) @ G.T
        var_V = np.square(np.array(cfg.manoeuvre_V_sigma_mps, float))
        if lever is not None:
            var_V[1] = cfg.manoeuvre_slip_sigma_mps**2
        Q[V_SLICE, V_SLICE] += Rc.T @ np.diag(var_V) @ Rc
        return Q

    def _failure(self, res: dict[str, Any], n_view: int = 0) -> tuple[str, str] | None:
        """(flag, reason) when the update is unusable (the prior is then kept), else None.

        n_view: for a refit or retry from a widened prior, the first fit's points (the road
        in view under the prior); the inliers are counted against the larger of it and the
        fit's own points. A wild motion that turns most of the road out of the image
        "fits" the few points left (rectilinear merge with filter.A_tau_s 0.5 and the CAN
        x 0.999, frame 102: a retry with 140 inliers of 482 points, ~5000 under the prior,
        yaw rate -138 deg/s, then held for six frames). A fit that keeps at least that
        fraction of them in view and fits most of what it sees (``seen_inlier_fraction``) is
        counted against what it sees instead: the rest is unmeasured.
        """
        cfg = self.cfg
        n_pts, n_in = max(res["n_points"], n_view), res["n_inliers"]
        n_seen = int(np.count_nonzero(res["point_labels"] != UNUSED))  # landed in B's view
        if (
            cfg.seen_inlier_fraction > 0
            and n_in >= cfg.seen_inlier_fraction * n_seen > 0
            and n_seen >= cfg.min_inlier_fraction * n_view
            and not self._unusual_noise(res["noise_scale"])
        ):
            n_pts = n_seen  # those out of its view are unmeasured, not outliers
        if res["done_levels"] == 0:
            return (
                "textureless",
                f"textureless road: fewer than {cfg.min_points} usable points "
                f"with gradient > {cfg.grad_threshold} DN/px",
            )
        if n_in < max(cfg.min_points, cfg.min_inlier_fraction * n_pts):
            return (
                "few-inliers",
                f"only {n_in} of {n_pts} finest-level points are inliers"
                + (" (as many were in view under the prior)" if n_view > res["n_points"] else "")
                + ": estimate unreliable, prior kept",
            )
        v_can = self._v_can
        if not math.isnan(v_can) and not self.ekf.can_consistent(v_can):
            speed = float((self.R_car_cam @ self.ekf.x[V_SLICE])[0])
            return (
                "can-contradiction",
                f"estimated speed {speed:.2f} m/s contradicts the CAN ({v_can:.2f} m/s) beyond "
                "its scale error: the images locked onto a wrong motion, prior kept",
            )
        usual = fast_median(np.asarray(self._s2_hist)) if len(self._s2_hist) >= 3 else 1.0
        if res["noise_scale"] > cfg.max_noise_scale * max(usual, 1.0):
            return (
                "poor-fit",
                f"residuals {math.sqrt(res['noise_scale']):.1f}x the expected noise at the "
                f"finest level ({math.sqrt(max(usual, 1.0)):.1f}x usually; motion outside "
                "the prior's reach?): estimate unreliable, prior kept",
            )
        return None

    def _coarse_to_fine(
        self,
        A: Frame,
        B: Frame,
        dt: float,
        excluded: list[np.ndarray] | None,
        wide_level: int | None = None,
        from_wide: bool = False,
    ) -> dict[str, Any]:
        """One coarse-to-fine pass of IEKF iterations from the filter's prior.

        excluded: per level, (M,) bool candidates that the off-road mask keeps out
        (`_excluded`), or None.
        wide_level: the manoeuvre retry's level of one wide grid search (``manoeuvre_search_*``)
        before the iterations, which then replaces the searches of ``search_levels``; its
        levels iterate up to ``manoeuvre_iterations``.
        from_wide: with wide_level, skip the levels coarser than it (`manoeuvre_fine_passes`).
        """
        cfg, ekf = self.cfg, self.ekf
        ekf.set_prior(ekf.x_prior, ekf.P_prior)
        iters: list[int] = []
        done_levels = 0
        pts_out, labels_out, info_out = np.zeros((0, 2)), np.zeros(0, np.int8), np.zeros(0)
        s2 = noise_scale = math.nan
        fine = None  # the finest level's points and frames, for `point_pull`
        speed = float((self.R_car_cam @ ekf.x_prior[V_SLICE])[0])
        col_scale = column_scale(dt, speed)
        retry = wide_level is not None
        its = cfg.manoeuvre_iterations if retry else cfg.iterations
        if retry:
            # the retry: one wide grid search at wide_level, from the prior; all levels then
            # iterate from there (a finer level's search over the retry's wide prior in a
            # few coarse steps would jump out of the basin the wide search found)
            level, sel, rays, a_val, _ = self._level_points(
                wide_level, A, B, dt, excluded, col_scale
            )
            if len(sel) >= cfg.min_points:
                self._search(
                    level,
                    wide_level,
                    rays,
                    a_val,
                    B,
                    dt,
                    cfg.manoeuvre_search_steps,
                    cfg.manoeuvre_search_points,
                )
        for lvl in reversed(range(cfg.levels)):
            if from_wide and retry and lvl > wide_level:
                iters.append(0)
                continue
            level, sel, rays, a_val, off = self._level_points(lvl, A, B, dt, excluded, col_scale)
            far = self._far_points(level, lvl, sel)
            w_a = np.take(level.roi_w, sel, 0) / float(level.scale) if cfg.flow_noise_frac else None
            labels = np.full(len(sel), UNUSED, np.int8)
            n_it = 0
            included = np.zeros(len(sel), bool)  # used in x̂ (eq. 21) or not (eq. 20)
            last = None
            # a level with fewer points than a fit needs is skipped before its linearisation
            # (whose brightness gain would come from those few points)
            n_max = its[cfg.levels - 1 - lvl] if len(sel) >= cfg.min_points else 0
            # the retry's levels iterate from its wide search, refined below it by a local one
            if retry:
                search = cfg.manoeuvre_local_search and lvl < wide_level
            else:
                search = lvl in cfg.search_levels
            if n_max and search:
                self._search(
                    level, lvl, rays, a_val, B, dt, cfg.search_steps, cfg.search_points, retry
                )
            s2_ref, best, halvings = math.nan, None, 0
            while n_it < n_max:
                idx, dz, C, R = self._linearise(
                    level, lvl, rays, a_val, B, dt, included, off, w_a, far
                )
                if len(idx) < cfg.min_points:
                    break
                last = idx, C, R  # the record's point information (audits) comes from it
                if cfg.line_search:
                    # posterior cost at x̂: truncated residuals (points that left B count as
                    # truncated) + prior term; a step that raised it is halved (backtracking)
                    if not math.isfinite(s2_ref):
                        s2_ref = min(max(fast_median(dz * dz / R) / 0.455, 0.25), 100.0)
                    e2 = np.minimum(dz * dz / (s2_ref * R), cfg.snoop_threshold)
                    d = ekf.x - ekf.x_prior
                    cost = float(e2.sum()) + cfg.snoop_threshold * (len(sel) - len(idx))
                    cost += float(d @ ekf.P_prior_inv @ d)
                    if best is not None and cost > best[0] and halvings < cfg.max_halvings:
                        ekf.x, ekf.P = 0.5 * (ekf.x + best[1]), best[2]
                        halvings += 1
                        continue
                    best = (cost, ekf.x.copy(), ekf.P.copy())
                use, R, s2 = self._classify(dz, C, R, included[idx])
                included[:] = False
                included[idx[use]] = True
                labels[:] = UNUSED
                labels[idx] = np.where(use, INLIER, OUTLIER)
                if use.sum() < cfg.min_points:
                    break
                P_old = ekf.P
                if lvl > 0 and cfg.coarse_fix_A:
                    C = C.copy()
                    C[:, A_SLICE] = 0.0
                n_use = int(use.sum())
                if cfg.independent_points > 0 and n_use > cfg.independent_points:
                    # neighbouring points share errors (smoothing, blur, resampling): count
                    # their information as that of `independent_points` independent ones
                    R = R * (n_use / cfg.independent_points)
                # step 5, eq. 17-18: IEKF measurement update with the inliers
                dx = ekf.update(C[use], dz[use], R[use])
                n_it += 1
                if float(dx @ np.linalg.solve(P_old, dx)) < cfg.step_tol**2:
                    break
            iters.append(n_it)
            done_levels += n_it > 0
            if lvl == 0:
                pts_out, labels_out, noise_scale = level.roi_w[sel], labels, s2
                fine = _FineLevel(level, pts_out, rays, a_val, B, off, w_a, far, dt, labels, s2)
                info_out = np.zeros(len(sel))
                if last is not None:  # the finest level's last linearisation
                    idx, C, R = last
                    info_out[idx] = (C[:, V_SLICE] @ self.R_car_cam[0]) ** 2 / R
        return {
            "noise_scale": noise_scale,
            "n_points": len(pts_out),
            "n_inliers": int(np.sum(labels_out == INLIER)),
            "iterations": tuple(iters),
            "points_px": pts_out,
            "point_labels": labels_out,
            "point_speed_info": info_out,
            "done_levels": done_levels,
            "fine": fine,
        }

    def _level_points(
        self,
        lvl: int,
        A: Frame,
        B: Frame,
        dt: float,
        excluded: list[np.ndarray] | None,
        col_scale: np.ndarray,
    ) -> tuple[Level, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(level, sel (M,) ROI indices, rays (M, 3), A's brightness (M,), off (M,) bool or
        None) of a level's points: selected outside the off-road mask (``excluded``), the
        static ones dropped; off: within their support of what a given road mask says is
        not road."""
        cfg = self.cfg
        level = self.levels[lvl]
        exclude = excluded[lvl] if excluded is not None else None
        sel = select_points(level, A, lvl, cfg, self.ekf.P_prior, col_scale, exclude, self.ekf.x)
        sel = sel[~self._static_points(level, lvl, sel, A, B, dt)]
        if cfg.coarse_without_map and lvl > 0 and exclude is not None and len(sel) < cfg.min_points:
            # the map, dilated by this level's support, covers the road: fit the level
            # without it (its raised structure included) rather than skip it
            sel = select_points(level, A, lvl, cfg, self.ekf.P_prior, col_scale, None, self.ekf.x)
            sel = sel[~self._static_points(level, lvl, sel, A, B, dt)]
        a_val = A.stacks[lvl][0].ravel()[level.roi_idx[sel]].astype(np.float64)
        off = self._offroad_given[lvl][sel] if self._offroad_given is not None else None
        return level, sel, np.take(level.roi_rays, sel, 0), a_val, off

    def _far_points(self, level: Level, lvl: int, sel: np.ndarray) -> np.ndarray | None:
        """(len(sel),) bool: the level's points sel whose road hit is farther than
        ``far_depth_m`` (their plane scale is unknown, `_linearise`), at the
        ``far_depth_levels`` finest levels; None elsewhere or when off."""
        cfg = self.cfg
        if cfg.far_depth_m <= 0 or lvl >= cfg.far_depth_levels:
            return None
        return level.road_dist_m[sel] > cfg.far_depth_m

    def _excluded(
        self, offroad: np.ndarray | None, look: np.ndarray | None = None
    ) -> list[np.ndarray] | None:
        """Per level, (M,) bool: candidates within their support (``mask_support_px``) of a
        pixel of the off-road mask (H_m, W_m), and at the ``road_appearance_levels`` finest
        levels of the appearance map look (H_m, W_m) too; None without either. Computed
        once per pair: every pass of the retry selects from it."""
        n_look = min(self.cfg.road_appearance_levels, len(self.levels)) if look is not None else 0
        if n_look == 0:
            return self._dilations(offroad)
        both = self._dilations(_union(offroad, look), stop=n_look)
        if offroad is None:
            return both + [np.zeros(len(level.roi_idx), bool) for level in self.levels[n_look:]]
        return both + self._dilations(offroad, start=n_look)

    def _dilations(
        self, offroad: np.ndarray | None, start: int = 0, stop: int | None = None
    ) -> list[np.ndarray] | None:
        """`_excluded` of one map (H_m, W_m) at levels start..stop-1 (stop None: all)."""
        if offroad is None:
            return None
        out, mask_scale = [], self.levels[self._mask_lvl].scale
        m, done = offroad, 0  # the mask dilated by radius `done` so far
        for level in self.levels[start:stop]:
            r = math.ceil(self.cfg.mask_support_px * level.scale / mask_scale)
            if r < done:  # (radii grow with the level; else start over)
                m, done = offroad, 0
            if r > done:
                # a square dilation of a square dilation is one by the summed radius (max
                # is exact): each level dilates the previous one by the radius it adds
                m = cv2.dilate(m, np.ones((2 * (r - done) + 1,) * 2, np.uint8))
                done = r
            out.append(m.ravel()[level.to_mask] > 0)
        return out

    def _given_offroad(self, road: np.ndarray | None) -> list[np.ndarray] | None:
        """Per level, (M,) bool: candidates within their support of a pixel that the given
        road mask (H, W) says is not road (their depth is unknown); None without a mask."""
        if road is None:
            return None
        off = (~road).astype(np.uint8) * 255
        r = math.ceil(self.cfg.mask_support_px)  # [level px]
        kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
        out = []
        for level in self.levels:
            s = int(level.scale)
            h, w = off.shape[0] // s, off.shape[1] // s
            # any non-road pixel in the level pixel's block (area mean > 0)
            m = (cv2.resize(off, (w, h), interpolation=cv2.INTER_AREA) > 0) if s > 1 else off
            m = cv2.dilate(m.astype(np.uint8), kernel) if r else m
            u = np.rint(level.roi_w[:, 0] / s).astype(np.int64).clip(0, w - 1)
            v = np.rint(level.roi_w[:, 1] / s).astype(np.int64).clip(0, h - 1)
            out.append(m[v, u] > 0)
        return out

    def _search(
        self,
        level: Level,
        lvl: int,
        rays: np.ndarray,
        a_val: np.ndarray,
        B: Frame,
        dt: float,
        max_steps: int,
        n_points: int,
        local: bool = False,
    ) -> None:
        """Grid search over the forward speed scale and the yaw rate before the iterations.

        The brightness-constancy cost is not convex beyond about a pixel (the texture's
        correlation length): Gauss-Newton from a prior that is a few pixels off (a biased
        CAN speed, an unexpected turn) stops in the nearest local minimum. The two
        directions the prior knows least, the speed scale and the yaw rate, are searched
        over +/- ``search_sigmas`` prior std around x̂ in steps that move the points by
        ``search_step_px`` pixels of this level (at most ``max_steps`` per side), within
        reach of the iterations that follow; x̂ moves to the
        grid point of lowest cost (truncated residuals plus the prior term).
        local: at most ``max_steps`` steps of ``search_step_px`` each side, however wide the
        prior (the manoeuvre retry's finer levels: a local refinement, not a new search).
        """
        cfg, ekf, cam = self.cfg, self.ekf, self.camera
        s = float(level.scale)
        x0 = ekf.x.copy()
        if len(rays) > n_points:  # an evenly spread subset is enough to rank the grid
            sub = np.linspace(0, len(rays) - 1, n_points).astype(int)
            rays, a_val = np.take(rays, sub, 0), a_val[sub]
        dirs = np.zeros((2, N_STATE))
        dirs[0, V_SLICE] = x0[V_SLICE]  # d x / d (relative speed scale)
        # d x / d (car yaw rate) [rad/s]; kinematic model: the viewpoint slides with it
        dirs[1] = yaw_direction(self.mount.lever_arm_m, self.R_car_cam)
        # prior std of the coefficient along each direction: sqrt(dᵀ P⁻ d) / |d|²
        dPd = np.einsum("ij,jk,ik->i", dirs, ekf.P_prior, dirs)
        sig = np.sqrt(np.maximum(dPd, 0.0)) / np.maximum(np.sum(dirs**2, axis=1), 1e-24)
        # the points at x0 and a small step along each direction, the three warps at once
        # (`homographies`, a batched `map_rays`: the same values as one by one)
        eps = [1e-3 / max(np.linalg.norm(d), 1e-12) for d in dirs]
        Hs = homographies(np.stack([x0, x0 + eps[0] * dirs[0], x0 + eps[1] * dirs[1]]), self.K0, dt)
        P3 = rays @ np.ascontiguousarray(Hs.transpose(0, 2, 1))  # (3, N, 3)
        w0, *w1s = cam.project(P3.reshape(-1, 3)).reshape(3, len(rays), 2)
        steps = []
        for j, w1 in enumerate(w1s):
            # level px per unit
            disp = nan_to_num_fast(np.linalg.norm(w1 - w0, axis=1)) / eps[j] / s
            d90 = fast_percentile(disp, 90) if len(disp) else 0.0
            half = cfg.search_sigmas * sig[j]
            if local and d90 > 0:
                half = min(half, max_steps * cfg.search_step_px / d90)
            if d90 <= 0 or half * d90 < cfg.search_step_px:
                steps.append(np.zeros(1))
                continue
            k = min(max_steps, math.ceil(half * d90 / cfg.search_step_px))
            steps.append(np.linspace(-half, half, 2 * k + 1))
        if all(len(st) == 1 for st in steps):
            return
        # all grid points at once: (G, 9) states -> (G, N) costs
        ga, gb = np.meshgrid(steps[0], steps[1], indexing="ij")
        X = x0 + ga.reshape(-1, 1) * dirs[0] + gb.reshape(-1, 1) * dirs[1]
        Hs = homographies(X, self.K0, dt)  # (G, 3, 3)
        # float32 (`CameraModel.project`): the grid is only ranked, ~1e-4 px is plenty
        P_b = (rays.astype(np.float32) @ Hs.transpose(0, 2, 1).astype(np.float32)).reshape(-1, 3)
        w_b = cam.project(P_b, np.float32) / np.float32(s)
        ok = in_level(w_b, P_b, self.K0, level.shape)
        b_val = sample_points(B.stacks[lvl][:1], w_b)[:, 0].astype(np.float64).reshape(len(X), -1)
        ok = ok.reshape(len(X), -1)
        # each grid point with its own brightness gain B -> A (as `_linearise` fits one):
        # with a stale gain, a motion that slides the image along a smooth brightness
        # gradient (vignetting, the road's shading) would pass for the exposure change
        # (rectilinear intersection, frame pair 1: a 1.3 % gain step read as -43 % speed)
        gain = np.ones(len(X))
        if cfg.gain_compensation:  # least squares a = gain b over the points in view
            b_ok = np.where(ok, b_val, 0.0)
            gain = np.sum(a_val * b_ok, axis=1) / np.maximum(np.sum(b_ok * b_ok, axis=1), 1e-9)
        r2 = (a_val - gain[:, None] * b_val) ** 2 / cfg.sigma_intensity**2
        r2 = np.where(ok, np.minimum(r2, cfg.search_truncation), cfg.search_truncation)
        D = X - ekf.x_prior
        cost = r2.sum(axis=1) + np.einsum("gi,ij,gj->g", D, ekf.P_prior_inv, D)
        ekf.x = X[int(np.argmin(cost))].copy()

    def _static_points(
        self, level: Level, lvl: int, sel: np.ndarray, A: Frame, B: Frame, dt: float
    ) -> np.ndarray:
        """(len(sel),) bool: points that stay put in the image while the road moves.

        Two hypotheses per point w_a: it is fixed to the camera (the ego body, the mount,
        dirt on the lens), then ``B(w_a) = A(w_a)``; or it moves with the road by
        ``dw = w_b(x̂) - w_a``, then B at w_a shows what A had at ``w_a - dw``: ``B(w_a) ~=
        A(w_a - dw)``. A point is "static" when B(w_a) matches A(w_a) within
        ``snoop_threshold`` times its noise R and is at least twice as far from the road
        hypothesis. Such points are dropped for the pair.
        """
        cfg = self.cfg
        if not cfg.static_test or len(sel) == 0:
            return np.zeros(len(sel), bool)
        idx = level.roi_idx[sel]
        s = float(level.scale)
        a_val = A.stacks[lvl][0].ravel()[idx].astype(np.float64)
        b_val = self._gain * B.stacks[lvl][0].ravel()[idx].astype(np.float64)
        P_b = map_rays(np.take(level.roi_rays, sel, 0), homography(self.ekf.x, self.K0, dt))
        w_a = np.take(level.roi_w, sel, 0) / s
        dw = nan_to_num_fast(self.camera.project(P_b) / s - w_a)
        a_moved = sample_points(A.stacks[lvl][:1], w_a - dw)[:, 0].astype(np.float64)
        g2 = A.mags[lvl].ravel()[idx].astype(np.float64) ** 2
        thr = cfg.snoop_threshold * (cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * g2)
        return ((b_val - a_val) ** 2 <= thr) & ((b_val - a_moved) ** 2 > 4.0 * thr)
