"""Settings of the direct estimator (`estimator.egomotion.direct`): `DirectConfig`, the camera-kind
defaults (``KIND_DEFAULTS``) and the checked construction from a mapping (`make_config`,
shared by every estimator's settings: a YAML ``estimator:`` block reaches them here).

Each setting carries its unit and, where a value was chosen by measurement, the drives
and figures that chose it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.egomotion.iekf import FilterConfig

# [m] the ego car's body below the beltline (length, width, height), centred on the car
# origin: a mid-size car, 5.0 x 1.94 m, beltline 0.80 m with the hood rising to 0.88 m
# (the car the simulator draws; a 1.0 m box hid half the road from a camera on the
# window at 1.2 m)
EGO_BODY_BOX_M = (5.0, 1.94, 0.88)


# ------------------------------------------------------------------ config
@dataclass(frozen=True)
class DirectConfig:
    """Settings of `DirectEstimator` (units beside each value)."""

    levels: int = 4  # [-] pyramid levels (0 = full resolution)
    iterations: tuple[int, ...] = (5, 4, 3, 2)  # [-] max IEKF iterations per level, coarse->fine
    max_points: int = 1500  # [-] points per level (most informative candidates, `selection`)
    grad_threshold: float = 2.0  # [DN/px] gradient magnitude of a candidate point (level px)
    nms: bool = True  # [-] keep only 3x3 local maxima of the gradient magnitude
    selection: str = "information"  # [-] rank candidates by "information" (`select_points`:
    # expected brightness change under the prior's uncertainty over the noise) or "gradient"
    select_cells: int = 16  # [-] points are spread over a grid of cells x cells (equal quotas)
    static_test: bool = True  # [-] drop points that stay put while the road moves (ego
    # body, mount), `DirectEstimator._static_points`
    offroad_mask: bool = True  # [-] skip points where the previous pair's compensation left a
    # residual (objects above the road, other vehicles, the ego body), `OffroadMapper.map`
    own_map: bool = True  # [-] a pair without a map from the previous pair (the first
    # pair; after a failed or unusual fit) maps its first frame from its own fit and fits
    # again without those pixels (`OffroadMapper.map` backward)
    map_carry: int = 0  # [-] pairs over which the off-road map of the last usual fit is
    # carried (dilated by ``map_carry_px`` per pair) when a fit is unusual or fails, rather
    # than no map and a map from the next pair's own fit: a vehicle close behind that
    # fills the view makes the fits unusual, and an own map from such a fit leaves the
    # vehicle in (rectilinear merge, frames 90-106: yaw rate to 12.6 deg/s, true 0)
    map_carry_px: int = 3  # [px at the mask level] dilation of a carried map per pair: the
    # structure it marks moves
    first_map_residuals: bool = True  # [-] the own map before the first good fit (the
    # first pair's: its prior is the CAN's alone) marks large residuals too, not only the
    # plane-parallax test's structure. Where the prior still pulls that fit, its residual
    # marks take out the road that disagrees with the prior, and the refit follows the
    # prior further (`test_pinhole_first_map_is_the_parallax_tests_alone`)
    first_fit_A: bool = True  # [-] the first fit's A is kept. False: A stays at the prior's
    # mean with the stationary std of its process (`IteratedEKF.hold_A`, flag ``A-held``)
    # and only later pairs, mapped and integrated over time, move it: a camera whose first
    # pair misreads A (a pinhole with far structure in view and no map yet) starts from
    # the mount instead of a wrong angle that the filter then carries for seconds
    fit_A: bool = True  # [-] every fit's A is kept. False: after every fit A goes back to
    # the prior's (`IteratedEKF.hold_A`): it is then the integral of the measured roll and
    # pitch rates (``A_from_W``), which a camera tells well, and not the fit's tilt of the
    # road plane, which a narrow view tells poorly (a tilt of 0.1 deg changes a pinhole's
    # road flow by ~0.2 %, less than the motion blur's pull on it)
    mask_level: int = 0  # [-] pyramid level of the off-road mask. Full resolution: a
    # guard-rail post is a few pixels wide, and at level 1 the road pixels around its foot
    # kept their place among the points (merge-omni-near: 17 % of the inliers, 58 % of
    # the speed information, speed +3.1 %; at level 0: 8 %, 9 %, +0.8 %)
    coarse_without_map: bool = True  # [-] a coarse level (l > 0) that the off-road mask,
    # dilated by its support (``mask_support_px`` x 2^l), leaves with fewer than
    # ``min_points`` selects its points without it: the coarse levels widen the basin of
    # the fit. Measured on the full suite: roundabout-omni-near yaw 0.69 -> 0.30 deg/s
    # (frame 99, a steering step from 78 to 21 deg/s: the retry had only levels 1 and 0
    # and stayed at 76), merge-omni 1.11/1.76 -> 1.03/1.42 %
    mask_motion_px: float = 0.5  # [px at the mask level] residual normal motion that marks
    # a pixel as off-road
    parallax_level: int | None = None  # [-] pyramid level of the plane-parallax test (its
    # marks upsampled to the mask level); None: the mask level
    parallax_lambdas: tuple[float, ...] = (1.08, 1.15, 1.3, 1.6)  # [-] plane-parallax
    # hypotheses of the off-road mask: a static point at height z above the road moves like
    # the plane K = lambda K0, lambda = h / (h - z) (0.15, 0.25, 0.45, 0.73 m for h = 1.95
    # m); () off. 1.08 is a kerb and a sidewalk: fitted as road they bias the yaw rate in
    # turns (racetrack-omni-near: -0.33 deg/s; -0.01 with the true road mask) and the
    # speed. Measured with it (full suite): racetrack 1.65/2.05 -> 1.36/1.90 %, yaw
    # 0.52/0.60 -> 0.46/0.57 deg/s; roundabout-near 1.30 -> 1.11 %, yaw 0.30 -> 0.15
    parallax_baseline_m: float = 0.5  # [m] the plane-parallax test compares B with an
    # older frame when the pair's own travel is shorter (up to ``parallax_baseline_frames``
    # pairs back, their fitted motions composed per plane): slow, a kerb's lambda moves a
    # pixel less than ``parallax_min_px`` farther than the road over one pair, and its top
    # edge (a strong gradient) stays among the points. Held-out intersection s2 at 1-2 m/s:
    # 266 inliers per frame see surfaces 0.1 m or more above the road, 35 % of the speed
    # information; fitted alone (exact geometry, true poses) they say +0.10 m/s, the points
    # the estimator chose +0.05, all road pixels +0.000. Measured on the 16 omni drives of
    # the `full` and `heldout` suites (0 is the pair itself; 0.3 / 0.5 / 0.7 / 1.0 m):
    # speed RMSE summed 18.77 -> 17.87 / 17.64 / 17.93 / 20.56 %; at 0.5: held-out
    # intersection s2 2.33 -> 1.86 %, s1 1.33 -> 1.17, library intersection 1.24 / 1.63 ->
    # 1.09 / 1.45, roundabout-far 1.27 -> 1.06 % (yaw 0.34 -> 0.21 deg/s), racetrack
    # 1.27 / 1.62 -> 1.30 / 1.71 %, held-out racetrack s1 1.02 -> 1.09; drives faster than
    # 7.5 m/s unchanged. 1.0: the roundabouts' composed turns misalign (far 1.27 -> 2.49 %)
    parallax_baseline_frames: int = 6  # [-] most frame pairs the baseline spans (4 / 10:
    # summed 17.77 / 17.71 %); their frames' images at the parallax level are kept
    parallax_ratio: float = 0.7  # [-] a pixel is off-road when some lambda leaves less than
    # this fraction of the road's windowed residual energy
    parallax_window_px: float = 1.5  # [px at the mask level] Gaussian window of the energies
    # (sigma; truncated at 3 sigma)
    parallax_min_px: float = 0.25  # [px at the mask level] a hypothesis is only tested where it
    # moves the pixel this much farther than the road does. 0.25 (was 0.5): a kerb's lambda
    # 1.08 moves a far pixel a few tenths of a pixel off the road's motion; measured on the
    # full suite (omni near/far): racetrack 1.43/1.93 -> 1.34/1.67 %, yaw 0.45/0.56 ->
    # 0.38/0.52 deg/s; roundabout-far 1.65 -> 1.28 %, A 0.070 -> 0.050 deg; held-out
    # intersection s2 3.06 -> 2.49 %; the rest within 0.03 % and 0.03 deg/s. Kerb pixels
    # marked (racetrack-omni-far): 43 -> 50 %, road pixels away from them 8.3 -> 9.3 %
    raised_memory: float = 0.7  # [-] memory of the raised-structure evidence (per frame;
    # 0: off): the share of textured pixels that the parallax test marks, per cell of level
    # ``raised_level``, averaged over frames (exponentially, this weight on the past) along
    # the road motion; cells at ``raised_share`` or more are marked on all their textured
    # pixels (`OffroadMapper._raised_cells`). Kerbs and sidewalks pass the test in about half their
    # pixels per frame, the road in a tenth: a frame's marks alone leave half a kerb among
    # the points. Measured (racetrack-omni-far, 60 frames): kerb pixels marked 50 -> 63 %,
    # road 9.3 -> 12.3 %; full suite (omni near/far): racetrack yaw 0.38/0.52 -> 0.35/0.46
    # deg/s, intersection 1.30/1.85 -> 1.24/1.63 %, roundabout A 0.042/0.050 -> 0.034/0.031
    # deg, roundabout-far yaw 0.20 -> 0.39 (a steering step, frame 43), highway 0.61/0.73
    # -> 0.66/0.77 %; held-out intersection s2 2.49 -> 2.33 %
    raised_level: int = 2  # [-] pyramid level of the evidence cells (4x4 px at level 2)
    raised_share: float = 0.3  # [-] averaged share of marked textured pixels that marks a cell
    road_appearance: bool = False  # [-] also exclude what does not look like the road near
    # the car (`estimator.egomotion.road_appearance`, at the mask level): far guard-rails and kerb
    # islands whose parallax over a pair is within the noise; and do not measure a point
    # that lands where the second frame does not look like the road (a vehicle moved over
    # it). Omni: off (its figures meet the targets without it; not measured with it).
    # Rectilinear, alone (13 drives of `full` + `heldout-rect`): inliers above the road
    # 12-18 % -> 1-3 %, speed RMSE mean 1.60 -> 1.43 %, yaw 0.55 -> 0.60 deg/s (steering steps
    # missed), A 0.131 -> 0.138 deg (a roll-rate bias of +0.1..0.6 deg/s on the merges and
    # intersections), held-out merge s1 3.01 -> 5.62 % (a rail close beside the car leaves
    # a strip of road); with ``flow_noise_frac`` 0.03 see KIND_DEFAULTS
    road_appearance_levels: int = 1  # [-] finest pyramid levels whose points the appearance
    # map excludes: the coarse levels keep the far structure, whose image motion is mostly
    # the rotation's and which sets the yaw rate apart from the forward speed for a camera
    # looking sideways (excluded at every level: steering steps missed, rectilinear
    # roundabout yaw 0.43 -> 1.52 deg/s)
    mask_smear: float = 0.2  # [-] marked pixels are also smeared along +/- this fraction of
    # their image motion (motion blur spreads a structure along its motion)
    mask_support_px: float = 2.0  # [px at each level] dilation of the mask (a point's
    # support: presmoothing, gradient and pyramid kernels) when a level selects points
    coarse_fix_A: bool = True  # [-] coarse levels (l > 0) leave A to the finest level: its
    # plane-tilt effect is below their resolution and they would fit blur leakage with it
    search_levels: tuple[int, ...] = (2, 1, 0)  # [-] levels that start with a grid search over
    # the speed scale and the yaw rate (`_search`)
    search_points: int = 300  # [-] points used by the grid search (evenly spread subset)
    search_sigmas: float = 3.0  # [-] half-width of the search in prior std
    search_steps: int = 3  # [-] most grid steps on each side of x̂, per direction (beyond:
    # coarser steps; the next level searches again)
    search_step_px: float = 1.5  # [level px] grid step (90th percentile point motion)
    search_truncation: float = 9.0  # [-] residual² / sigma_intensity² at which a point's
    # search cost saturates
    line_search: bool = True  # [-] halve an iteration's step when it raised the cost
    max_halvings: int = 3  # [-] halvings per level
    manoeuvre_retry: bool = True  # [-] when the road did not align from the prior, retry
    # with the manoeuvre covariance added to the prior (`_estimate`)
    retry_noise_ratio: float = 3.0  # [-] a fit whose noise scale s² exceeds this many times
    # the median of the recent fits is retried too
    manoeuvre_W_sigma_rps: float = 1.0  # [rad/s] added std of the yaw rate for the retry
    manoeuvre_W_plane_sigma_rps: float = 0.2  # [rad/s] added std of the roll and pitch rates
    # for the retry: a manoeuvre turns the car about the road normal; its body's roll and
    # pitch rates stay those of the vibration (a few deg/s). 1.0 (as the yaw rate):
    # merge-omni-near frame 121, a retry took a roll rate of -27 deg/s (true -1.3).
    # Measured against 1.0 on the 10 omni library drives: merge-omni-near 1.13 -> 1.09 %,
    # yaw 0.38 -> 0.29 deg/s; roundabout-omni-far 1.37 -> 1.27 %, 0.39 -> 0.34; the rest
    # within 0.02 % and 0.01 deg/s. Rectilinear (13 drives) mixed, mean unchanged: racetrack
    # 1.58 -> 2.25 %, held-out roundabout s2 2.14 -> 1.59 %, merge s1 yaw 1.18 -> 1.73
    retry_gain: float = 3.0  # [-] a retry replaces a fit that did not fail only when its
    # noise scale s² is this many times lower: a surprising fit (a truck drives into the
    # view) is often the right motion, and the retry's wide prior finds a worse one whose
    # residuals are only somewhat lower (merge-omni-far frame 123: -10 deg/s for 0, at 1.8x)
    manoeuvre_search_levels: tuple[int, ...] = (2, 1, 0)  # [-] the retry runs one pass per level
    # listed, each with one wide grid search at that level first, and keeps the best fit
    manoeuvre_fine_passes: bool = True  # [-] a wide level below the coarsest also makes a pass
    # that iterates only from that level down: the coarse levels' cost may prefer a wrong
    # basin (held-out rectilinear roundabout s2 frame 39, a -5.6 -> -88.7 deg/s step: level
    # 2's median residual 0.76 at the truth, 0.53 at the fit of -55). The passes are ranked
    # by their finest level's noise scale, as before
    manoeuvre_iterations: tuple[int, ...] = (5, 4, 10, 10)  # [-] max IEKF iterations per level
    # (coarse->fine) of the retry's passes: they start from a grid point a grid step or more
    # from the fit, which 3 and 2 iterations at the fine levels do not reach (the step's pass
    # stopped at -66 deg/s; with 10, -86). ``step_tol`` ends a level that converged. With
    # ``manoeuvre_fine_passes``, on the 13 rectilinear drives: held-out roundabout s2 2.61 ->
    # 1.45 %, 2.76 -> 0.82 deg/s, library roundabout 0.65 -> 0.56 deg/s, library merge A
    # 0.072 -> 0.053 deg, the rest within 0.01; the 16 omni drives within 0.03 deg/s and
    # 0.005 deg but held-out intersection-omni-near s2 1.69 -> 1.85 %, racetrack-omni-far
    # 1.49 -> 1.56 %. The retry's finest levels only (levels 0 and 1 at 10), or 10 from each
    # pass's wide level down: roundabout s2 1.77 / 1.01 deg/s
    manoeuvre_local_search: bool = True  # [-] the retry's levels finer than its wide level
    # start with a local grid search, ``search_steps`` steps of ``search_step_px`` each side
    # of x̂ (`_search` with local): the coarser level's fit may be several of the finer
    # level's pixels off along the speed-yaw valley, which Gauss-Newton crawls at about a
    # pixel per iteration (held-out rectilinear roundabout s2 frame 39: levels 1 and 0 moved
    # the yaw rate -40.6 -> -79.6 deg/s in 20 iterations, truth -88.7; with it -86.3). On
    # the 13 rectilinear drives: held-out roundabout s2 0.82 -> 0.43 deg/s, 1.45 -> 1.07 %,
    # library roundabout 0.56 -> 0.51, the rest unchanged; omni: merge-omni-near 0.99 ->
    # 1.21 %, merge-omni-far 1.13 -> 1.16 % (A 0.040 -> 0.045 deg), the other 14 unchanged
    seen_inlier_fraction: float = 0.5  # [-] a fit whose inliers are at least this fraction
    # of the finest-level points it sees in B (at the usual noise level), and which sees at
    # least ``min_inlier_fraction`` of the points in view under the prior, has its inliers
    # counted against the points it sees: those its motion turns out of view are
    # unmeasured, not outliers. 0: against all (`_failure`). Held-out rectilinear merge s1,
    # frames 148-149, a -100 deg/s swerve at 20 m/s that turns the road ahead behind the
    # car body: the retry fitted -99.8 deg/s, 391 of the 481 points it saw inliers (the
    # prior saw 1759; 440 is the quarter) at s² 0.23, and failed "few inliers": yaw RMSE
    # 9.53 -> 0.30 deg/s. A wild motion that leaves a tenth of the road in view still fails
    # however well that tenth fits
    manoeuvre_search_steps: int = 12  # [-] grid steps per side of the retry's wide search
    manoeuvre_search_points: int = 1200  # [-] points of the retry's wide search: its wide
    # grid holds many shallow minima that 300 points do not rank reliably
    yaw_jump_sigmas: float = 3.0  # [-] a fit that moved the yaw rate more than this many std
    # of the shift the filter expects (prior minus posterior variance) says the random walk
    # of eq. 19 missed a change of turn rate: refit with the yaw prior widened (`_yaw_refit`);
    # <= 0: never. Omni with 2: the 640-px library and held-out drives the same or better
    # only when unusual fits go to the manoeuvre retry instead (roundabout-omni-far 1.27 ->
    # 1.09 %, yaw 0.34 -> 0.18 deg/s; with them refitted, roundabout-omni-near yaw 0.16 ->
    # 0.75: frames 43 and 99, steps of 33 and 57 deg/s refitted short), but the smoke
    # suite's 320-px roundabouts worse even so (5.21 / 5.60 -> 5.56 / 6.35 %)
    yaw_jump_widen: float = 2.0  # [-] the refit's added yaw std, in units of the shift seen
    yaw_jump_rounds: int = 3  # [-] refits at most: a refit that moved the yaw rate well
    # beyond its widened std (a step far larger than the first fit's shift said: rectilinear
    # roundabout frame 43, -83 -> -53 deg/s, first fit -81.3, refit at 3.6 deg/s -61.4)
    # is refitted with the std its own shift asks for
    manoeuvre_V_sigma_mps: tuple[float, float, float] = (0.5, 3.0, 0.5)  # [m/s] added std
    # of V (forward, lateral, vertical in car axes) for the retry: a manoeuvre is a turn
    # and a side slip; the forward speed stays the CAN's to tell (a wide forward std lets
    # a sudden yaw be traded for speed at low speed)
    manoeuvre_slip_sigma_mps: float = 0.5  # [m/s] sideways speed of the rear axle for the
    # retry when the mount knows it (``rear_axle_x_m``): the rest of the sideways speed
    # follows the yaw rate
    presmooth_sigma_px: float = 0.7  # [px] Gaussian blur of the full-resolution frame
    sigma_intensity: float = 2.0  # [DN] measurement noise of one brightness sample
    sigma_flow_px: float = 0.2  # [px] model/interpolation noise, as a flow error (level px)
    flow_noise_frac: float = 0.0  # [-] model noise that grows with a point's image motion,
    # as a flow error of this fraction of it: near road seen from a camera low on the car
    # changes its look between frames (perspective scaling of motion-blurred texture), and
    # with the raised structure out of the points (``road_appearance``) it held a roll-rate
    # bias of 0.1-0.6 deg/s on the rectilinear merges and intersections
    offroad_depth_sigma: float = 1.0  # [-] std of the plane scale lambda of a point that a
    # given road mask says is off the road: its depth is unknown, so it constrains the
    # rotation and hardly the speed (`_linearise`)
    far_depth_m: float = 0.0  # [m] road points farther than this (horizontal distance of
    # their road hit) have an unknown plane scale, as points off a given road mask (std
    # ``offroad_depth_sigma`` of the speed direction joins their noise, `_linearise`): they
    # tell the rotation, hardly the speed. Far away the plane-parallax test cannot tell a
    # guard rail's top from the road (its lambda moves a pixel less than
    # ``parallax_min_px`` farther over a pair), and a rail fitted as road biases the yaw
    # rate in turns. 0: off; see KIND_DEFAULTS
    far_depth_levels: int = 1  # [-] finest pyramid levels where ``far_depth_m`` applies: the
    # coarse levels keep the far points' depth, which sets a steering step's yaw rate
    # apart from a side slip (at every level, the library rectilinear roundabout's -80
    # deg/s step at frame 42 was fitted at -56: yaw RMSE 2.45 deg/s; levels 0-1: 0.76)
    independent_points: int = 100  # [-] the information of more inliers is counted as that of
    # this many independent ones (R scaled by n / independent_points); 0: every point counts
    outliers: str = "snooping"  # "snooping" (eq. 20-21), "huber", "tukey" or "none"
    snoop_threshold: float = 9.0  # [-] Mahalanobis² above which a point is an outlier
    robust_k: float = 2.5  # [sigma] Huber / Tukey tuning constant
    adaptive_noise: bool = True  # [-] scale R by the robust (median) residual level
    max_noise_scale: float = 10.0  # [-] finest-level s² above which the fit is "poor" (times
    # the median s² of the recent good fits when that is above 1: a camera's usual level)
    step_tol: float = 0.05  # [-] stop a level when the step's Mahalanobis norm is below
    gain_compensation: bool = True  # [-] fit a global brightness gain B -> A each iteration
    max_range_m: float = 30.0  # [m] farthest road point used (horizontal, from the camera)
    max_flow_px: float = 64.0  # [px] road points that the prior mean moves farther than this
    # over the frame pair (full resolution) are not selected: near road seen by a camera low
    # on the car changes its look between frames beyond brightness constancy (motion blur
    # of exposure x image speed, perspective scaling); `too_fast`. <= 0: no limit
    ego_box_m: tuple[float, float, float] | None = EGO_BODY_BOX_M  # [m] body below the
    # beltline (length, width, height), centred on the car origin: rays through it are masked
    ego_margin_m: float = 0.1  # [m] margin around ego_box_m
    roi_erode_px: int = 3  # [px at each level] distance kept from image edges (body, horizon)
    min_points: int = 40  # [-] fewer selected points (or inliers) at a level: level skipped
    min_inlier_fraction: float = 0.25  # [-] fewer inliers at the finest level: degraded
    dark_level: float = 12.0  # [DN] mean brightness below which a frame is "dark"
    saturated_level: float = 250.0  # [DN] brightness counted as saturated
    saturated_fraction: float = 0.5  # [-] saturated share of the ROI that flags a frame
    can_missing_inflation: float = 4.0  # [-] variance factor on V when the CAN speed is lost
    flat_field: bool = False  # [-] divide the camera's vignetting (its file's photometric
    # calibration) out of each frame; see KIND_DEFAULTS
    compensate: bool = False  # [-] return the motion-compensated previous frame
    filter: FilterConfig = field(default_factory=FilterConfig)

    def __post_init__(self) -> None:
        if self.levels < 1:
            raise ValueError(f"direct.levels must be >= 1, got {self.levels}")
        if self.yaw_jump_rounds < 1:
            raise ValueError(
                f"direct.yaw_jump_rounds must be >= 1 (no refit: yaw_jump_sigmas 0), "
                f"got {self.yaw_jump_rounds}"
            )
        for name in ("iterations", "manoeuvre_iterations"):
            if len(getattr(self, name)) != self.levels:
                raise ValueError(
                    f"direct.{name} needs one count per level ({self.levels}), "
                    f"got {getattr(self, name)!r}"
                )
        if self.selection not in ("information", "gradient"):
            raise ValueError(
                f"direct.selection must be 'information' or 'gradient', got {self.selection!r}"
            )
        if not (math.isfinite(self.parallax_baseline_m) and self.parallax_baseline_m >= 0):
            raise ValueError(
                f"direct.parallax_baseline_m must be >= 0 [m], got {self.parallax_baseline_m!r}"
            )
        if not (math.isfinite(self.far_depth_m) and self.far_depth_m >= 0):
            raise ValueError(
                f"direct.far_depth_m must be finite and >= 0 [m] (0: off), got {self.far_depth_m!r}"
            )
        if self.parallax_baseline_frames < 1:
            raise ValueError(
                f"direct.parallax_baseline_frames must be >= 1, got {self.parallax_baseline_frames}"
            )
        if self.outliers not in ("snooping", "huber", "tukey", "none"):
            raise ValueError(
                f"direct.outliers must be 'snooping', 'huber', 'tukey' or 'none', "
                f"got {self.outliers!r}"
            )


# Settings that differ by camera kind. A pinhole sees a narrow wedge of road, where
# a yaw rotation and a pitch offset of the camera move the image almost alike:
# it needs every textured pixel (no NMS, low threshold) and the far road.
KIND_DEFAULTS: dict[str, dict[str, Any]] = {
    # the flat field (`flat_field`) measured on the 10 omni library drives (full suite,
    # renders of 2026-12-02): speed RMSE worse on 7 of 10 by 0.02-0.15 points (highway-omni-near
    # 0.66 -> 0.70 %, roundabout-omni-far 1.27 -> 1.42 %, merge-omni-far A 0.034 -> 0.046 deg),
    # better on 3 by 0.02-0.04 (roundabout-omni-near A 0.035 -> 0.025 deg); the smoke suite
    # flagged highway-omni-far at 320 px (0.26 -> 0.37 m/s). With the flat field's noise
    # (1 / gain²) in R: worse still (roundabout-omni-near 0.83 -> 1.28 %). The omni camera
    # sees its road in a ring about the image centre, which is the vignetting's: off
    "omni": {},
    "pinhole": {
        # the road darkening as it crosses the image (the rectilinear camera sees it move
        # off-centre) biased the roll rate by +0.13 deg/s and A by as much (library
        # intersection A 0.102 -> 0.041 deg with it alone); see the README
        "flat_field": True,
        # measured: rectilinear merge 6.2 % -> 12.7 %, intersection 10.0 -> 12.3 % with the
        # full-resolution mask (its textured road is far, its pixels fine enough at level 1)
        "mask_level": 1,
        # measured with it (after the grid search's gain fix): rectilinear merge yaw 0.88 ->
        # 2.41 deg/s, speed 4.38 -> 4.55 %; the other four drives within 0.03 %
        "coarse_without_map": False,
        # measured with 1.08 too (after the gain fix): rectilinear intersection 1.82 ->
        # 3.02 %, merge 4.38 -> 5.26 %, racetrack 6.29 -> 7.91 %, roundabout 4.23 -> 5.65 %
        "parallax_lambdas": (1.15, 1.3, 1.6),
        # measured with 0.25: rectilinear highway 0.40 -> 0.67 %, merge 4.38 -> 5.86 %,
        # roundabout yaw 0.84 -> 3.10 deg/s
        "parallax_min_px": 0.5,
        # measured with 0.5 m (13 rectilinear drives): held-out roundabout s1 A 0.041 -> 0.345
        # deg, yaw 0.43 -> 7.12 deg/s, library roundabout yaw 0.43 -> 5.12, held-out
        # intersection s1 0.45 -> 2.48 %: its narrow view's composed motions misalign
        "parallax_baseline_m": 0.0,
        # measured with 0.7: rectilinear merge 4.38 -> 4.75 %, roundabout yaw 0.84 -> 2.73,
        # racetrack yaw 2.20 -> 3.00 deg/s
        "raised_memory": 0.0,
        "max_range_m": 60.0,
        # the far strip of road (20-60 m, rows ~140-160 of 480) holds guard rails that the
        # parallax test cannot resolve. Measured on the 13 rectilinear drives (`full` +
        # `heldout-rect`, renders of 2026-12-03), off -> 20 m: yaw RMSE 0.506 / 0.513 / 0.434
        # -> 0.436 / 0.439 / 0.311 deg/s on the roundabouts (library, held-out s1, s2; their
        # bias -0.30 / -0.26 / -0.27 -> -0.18 / -0.14 / -0.14), highway 0.42 -> 0.18, merge
        # s2 0.51 -> 0.34; mean over the 13 0.370 -> 0.317 deg/s; racetracks 0.37 / 0.45 /
        # 0.35 -> 0.40 / 0.42 / 0.37. Speed within 0.2 points (merge s1 1.72 -> 1.90 %). A
        # the same but on the merges: library 0.053 -> 0.060 deg (frames 91-105, a vehicle
        # close behind: the far points' depth carried the pitch), held-out s1 0.076 -> 0.078.
        # The distance, chosen on the library highway, merge and racetrack with the option at
        # every level: 15 / 20 / 25 m, yaw 0.43 / 0.17 / 0.25, 0.17 / 0.17 / 0.22, 0.39 / 0.37 /
        # 0.37 deg/s; merge A 0.058 / 0.055 / 0.081 deg
        "far_depth_m": 20.0,
        "nms": False,
        # every textured pixel. Measured on the 13 rectilinear drives of the `full` and
        # `heldout-rect` suites, with 6000 / 30 (the 6000 strongest gradients: lane lines,
        # kerbs and the far strip's edges, arcs along the path in a turn) -> these three:
        # speed RMSE mean 3.54 -> 1.90 % (better on 11 of 13), yaw 1.34 -> 0.93 deg/s
        # (better on 9), A 0.139 -> 0.170 deg (the library merge 0.21 -> 0.63: a vehicle
        # close behind, frames 90-108, pulls the yaw to 13 deg/s; 0.132 -> 0.133 without it)
        "max_points": 20000,
        # the first pair's residual marks followed the CAN's +8 % (synthetic pairs, seeds
        # 0-2: 0.74 / 2.01 / 1.38 % before; with max_points 20000 and its residual marks
        # 1.33 / 1.10 / 0.96 %, without them 0.55 / 0.09 / 0.15 %)
        "first_map_residuals": False,
        # 2 sigma (omni: 3), on the 13 rectilinear drives: speed RMSE mean 1.71 -> 1.60 %,
        # yaw 0.68 -> 0.55 deg/s, every drive the same or better (held-out intersection s1
        # 1.46 -> 0.23: a one-frame steering step to -20.8 deg/s that the fit met at -3.4, a
        # 2.3-sigma shift; racetrack 2.25 -> 1.47 %); with the CAN x 1.001 yaw 0.76 -> 0.61.
        # Sending the unusual fits to the manoeuvre retry instead (as omni would need at 2)
        # loses the steering steps the refit finds: roundabout yaw 0.43 -> 2.03 deg/s
        "yaw_jump_sigmas": 2.0,
        # a vehicle close behind fills the view (library merge, frames 90-106): speed 3.96 ->
        # 1.28 %, yaw 3.98 -> 0.53 deg/s, A 0.63 -> 0.12 deg; the other 12 rectilinear
        # drives unchanged. Omni keeps its own maps (0): merge-omni-near A 0.031 -> 0.063
        # deg, merge-omni-far 1.07 -> 1.13 %, the other eight unchanged
        "map_carry": 2,
        # the road by its look, and noise growing with the image motion. Measured together on
        # the 13 rectilinear drives (`full` + `heldout-rect`), from 1.60 % / 0.55 deg/s / 0.131
        # deg: speed 1.08 % (all 13 within 2 %; held-out intersection s2 2.98 -> 0.77, merge s1
        # 3.01 -> 1.91), A 0.108 deg (5 within 0.1, from 4), yaw 1.08 deg/s: 0.09-0.55 on 12
        # drives (roundabouts 0.34-0.45, racetracks 0.38-0.55) but 9.84 on held-out merge s1,
        # whose last two frames (a -100 deg/s swerve, flagged poor-fit) the manoeuvre retry
        # no longer catches (default 1.66). Either alone is worse: road_appearance alone 1.43 /
        # 0.60 / 0.138; flow_noise_frac 0.03 alone 2.78 % / 2.44 / 0.356 (merges unstable).
        # flow_noise_frac 0.05: 1.15 % (roundabout 2.39) / 1.09 / 0.099 (7 within 0.1)
        "road_appearance": True,
        "flow_noise_frac": 0.03,
        "grad_threshold": 2.0,
        "selection": "gradient",
        "select_cells": 1,
        # every pixel, no NMS: neighbours share much of their error. 30 with 6000 points;
        # 100 with 20000 keeps about one independent point per 200 (30: speed RMSE mean 2.64
        # %, yaw 1.30 deg/s on the 13 drives). Mean NEES per drive with 100: speed 0.37-4.7
        # (median 0.80), yaw rate 0.46-8.0 (median 2.8: overconfident on the yaw rate)
        "independent_points": 100,
        # the filter of a camera that hardly sees A (with A_from_W off, its A error is the
        # CAN-only one): A is the integral of the measured roll/pitch rates, so their
        # bias is learnt and left out (their running mean over 2 s) and A reverts to the
        # mount in 0.5 s. Measured with the flat field on the 13 rectilinear drives: see
        # the README. A first pair's A prior of 0.3 deg instead of 1 (the vibration's
        # amplitude) gave about the same (library A 0.061 -> 0.057 deg) but a worse
        # single cold pair (test_recovers_true_motion_from_biased_prior 0.83 -> 1.03 %)
        #
        # A from the rates alone (``fit_A`` off), with the car's kinematics as
        # pseudo-measurements (the rear axle slides sideways by 0.05 m/s at most, the camera
        # moves along the road normal by 0.1 m/s at most): on the one-lane strip a roll rate
        # moves the points much as a sideways or vertical speed does (the roll rate's error
        # went with theirs, -10 deg/s per m/s). Measured on the 13 rectilinear drives with
        # ``yaw_jump_rounds`` 3, from A 0.040-0.095 deg (library merge 0.074, held-out merge
        # s1 0.095): A 0.040-0.067 (library 0.048-0.060, mean 0.054), speed 0.38-1.14 %,
        # roundabout / racetrack yaw 0.28-0.45 deg/s (the simulator's truth of both
        # kinematic speeds is 0; a real car's rear axle slips more in hard cornering, its
        # slip angle growing with the lateral acceleration: loosen it for such recordings,
        # `omnibench estimate --set filter.nonholonomic_sigma_mps=0.2`). The merges' A is
        # chaotic in these settings (vertical std 0.05 / 0.2: library merge 0.062 / 0.078,
        # held-out merge s1 0.072 / 0.082, and a library roundabout yaw 1.68 at 0.2;
        # sideways 0.1: 0.063 / 0.074; the vertical one off: 0.080 / 0.089); each alone is
        # worse (A from the rates alone: held-out merge s1 0.086; the kinematics alone:
        # 0.079 and library merge speed 2.17 %). Omni keeps its defaults, which meet every
        # figure: with the kinematics (0.1 / 0.05) its library drives the same or slightly
        # better (A 0.053 -> 0.048 deg on highway-omni-near) but held-out intersection s2's
        # speed 1.85 -> 2.05 %
        "fit_A": False,
        "filter": {
            "rate_bias_tau_s": 2.0,
            "A_tau_s": 0.5,
            "nonholonomic_sigma_mps": 0.05,
            "vertical_speed_sigma_mps": 0.1,
        },
        # the first fit has no off-road map: on the library roundabout its A was 0.36 deg
        # off the truth (A = 0 is 0.28 off; the far guard rail's depth is the most
        # sensitive to pitch), and the filter carried that error for about 3 s
        # (A RMSE 0.108 deg over the first 3 s, 0.038 after). Held at the mount (0.05 deg,
        # the A process's stationary std), on the 13 rectilinear drives: A RMSE mean 0.058
        # -> 0.050 deg (within 0.058 on 6 -> 10 of 13, within 0.1 on 12 -> 13), speed 0.83
        # -> 0.84 %, yaw within 0.5 deg/s on all six roundabouts and racetracks (0.35-0.49).
        # Held-out merge s1's yaw 2.42 -> 9.74 deg/s: its last pair (a -100 deg/s swerve) the
        # retry fits at -103 with 173 of 811 points inliers (few-inliers), where before it
        # fitted -78 with 244. With 0.1 / 0.15 / 0.25 deg instead: A 0.052 / 0.051 / 0.051,
        # but roundabout or racetrack yaw up to 1.01 / 1.02 / 3.07 deg/s (a steering step
        # that the yaw refit then misses); the images' A relearnt over the first 3 / 6 pairs
        # (A's prior back to 1 deg): 0.057 / 0.069 on the library 5 (0.056 before)
        "first_fit_A": False,
        # a manoeuvre may change the speed abruptly too (a collision in highway-env moves
        # the car by its impact within a frame): held-out racetrack seed 1, frame 111, 8.4 ->
        # 4.1 m/s and 12 -> 124 deg/s within a frame; the retry's speed search reached 6.5
        # m/s with 0.5. Measured with it on the 13 rectilinear drives: see the README
        "manoeuvre_V_sigma_mps": (2.0, 3.0, 0.5),
    },
}


def default_config(kind: str, **overrides: Any) -> DirectConfig:
    """`DirectConfig` for a camera kind (``KIND_DEFAULTS``) with ``overrides`` applied."""
    if kind not in KIND_DEFAULTS:
        raise ValueError(f"unknown camera kind {kind!r}; known: {', '.join(KIND_DEFAULTS)}")
    return make_config(DirectConfig, _merged(KIND_DEFAULTS[kind], overrides), "direct")


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``over``, nested mappings (``filter``) key by key."""
    out = dict(base)
    for key, value in over.items():
        both = isinstance(value, dict) and isinstance(out.get(key), dict)
        out[key] = _merged(out[key], value) if both else value
    return out


def make_config(cls: type, overrides: dict[str, Any], where: str) -> Any:
    """Dataclass ``cls`` with ``overrides`` applied; nested dataclasses take dicts.

    An unknown key raises ValueError with its dotted path (``direct.filter.bad``).
    """
    names = {f.name: f for f in dataclasses.fields(cls)}
    kw: dict[str, Any] = {}
    for key, value in overrides.items():
        if key not in names:
            raise ValueError(f"unknown setting {where}.{key}; known: {', '.join(sorted(names))}")
        default = names[key].default
        if default is dataclasses.MISSING and names[key].default_factory is not dataclasses.MISSING:
            default = names[key].default_factory()
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = make_config(type(default), value, f"{where}.{key}")
        elif isinstance(default, tuple) and isinstance(value, list):
            value = tuple(value)
        _check_type(value, default, f"{where}.{key}")
        kw[key] = value
    return cls(**kw)


def _check_type(value: Any, default: Any, where: str) -> None:
    """ValueError when value cannot stand for a setting whose default is ``default``: a
    flag takes true / false, a number a number, a word a word (other settings unchecked)."""
    if isinstance(default, bool):
        ok = isinstance(value, bool | np.bool_)
    elif isinstance(default, int | float):
        ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
            value, bool | np.bool_
        )
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        return
    if not ok:
        raise ValueError(
            f"setting {where} takes a {type(default).__name__} (default {default!r}), got {value!r}"
        )
