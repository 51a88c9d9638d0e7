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
    `_parallax_marks`): the next pair, where B is A, takes no points there
    (`_offroad_map`, at full resolution for omni cameras: a post is a few pixels wide)
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
    stays at the mount with its process's stationary std (flag ``A-held``)

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

`EgoMotionEstimator` (base of all estimators, also `estimator.baselines`) does
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

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import cv2
import numpy as np

from estimator.camera import CameraModel
from estimator.compensation import FrameCompensator
from estimator.geometry import road_distance_m
from estimator.homography import (
    A_SLICE,
    N_STATE,
    V_SLICE,
    W_SLICE,
    check_state,
    dh_dx,
    homographies,
    homography,
    make_state,
)
from estimator.iekf import (
    FilterConfig,
    IteratedEKF,
    data_snooping,
    robust_weights,
    yaw_direction,
)
from estimator.motion_model import constraint_rows, map_rays, warp_jacobian
from estimator.mount import CameraMount
from estimator.road_appearance import offroad_by_appearance, seed_indices
from estimator.roi_strip import RoiStrip, roi_strip, strip_blur_image

UNUSED, INLIER, OUTLIER = 0, 1, 2  # point labels (paper Fig. 4b: black, gray, white)

# Rows of (N, k) arrays are gathered with np.take(a, i, 0) rather than a[i]: the same
# values, 3-6x faster in numpy 2 (59k rays: 0.08 vs 0.47 ms).

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
    # residual (objects above the road, other vehicles, the ego body), `_offroad_map`
    own_map: bool = True  # [-] a pair without a map from the previous pair (the first
    # pair; after a failed or unusual fit) maps its first frame from its own fit and fits
    # again without those pixels (`_offroad_map` backward)
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
    # pixels (`_raised_cells`). Kerbs and sidewalks pass the test in about half their
    # pixels per frame, the road in a tenth: a frame's marks alone leave half a kerb among
    # the points. Measured (racetrack-omni-far, 60 frames): kerb pixels marked 50 -> 63 %,
    # road 9.3 -> 12.3 %; full suite (omni near/far): racetrack yaw 0.38/0.52 -> 0.35/0.46
    # deg/s, intersection 1.30/1.85 -> 1.24/1.63 %, roundabout A 0.042/0.050 -> 0.034/0.031
    # deg, roundabout-far yaw 0.20 -> 0.39 (a steering step, frame 43), highway 0.61/0.73
    # -> 0.66/0.77 %; held-out intersection s2 2.49 -> 2.33 %
    raised_level: int = 2  # [-] pyramid level of the evidence cells (4x4 px at level 2)
    raised_share: float = 0.3  # [-] averaged share of marked textured pixels that marks a cell
    road_appearance: bool = False  # [-] also exclude what does not look like the road near
    # the car (`estimator.road_appearance`, at the mask level): far guard-rails and kerb
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
        "filter": {"rate_bias_tau_s": 2.0, "A_tau_s": 0.5},
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


class _FineLevel(NamedTuple):
    """What a fit kept of its finest level for `DirectEstimator.point_pull`: its points'
    pixels (N, 2) in frame A [px], rays (N, 3), A's brightness (N,), the pair's second
    frame, the given road mask's off-road flags (N,) or None, A's level pixels (N, 2) for
    ``flow_noise_frac`` or None, dt [s], labels (N,) and the noise scale s²."""

    level: _Level
    points_px: np.ndarray
    rays: np.ndarray
    a_val: np.ndarray
    B: _Frame
    off: np.ndarray | None
    w_a: np.ndarray | None
    dt: float
    labels: np.ndarray
    s2: float


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


# ------------------------------------------------------- small-array reductions
# np.median, np.percentile and np.nan_to_num spend 20-100 µs a call on argument
# handling; the estimator calls them ~20 times a frame on a few hundred to a few
# thousand values. These give numpy 2's values (the same order statistics, the same
# arithmetic; tests/estimator/test_direct.py compares them) without that overhead.


def fast_median(a: np.ndarray) -> float:
    """``float(np.median(a))`` of a 1-D float array (NaN if a holds one or is empty)."""
    n = a.shape[0]
    if n == 0:
        return math.nan
    k = n // 2
    if n % 2:
        part = np.partition(a, (k, n - 1))
        m = part[k]  # np.median: the mean of one value
    else:
        part = np.partition(a, (k - 1, k, n - 1))
        m = (part[k - 1] + part[k]) / 2  # np.median: the mean of the middle two
    return float(part[n - 1] if np.isnan(part[n - 1]) else m)


def fast_percentile(a: np.ndarray, q: float) -> float:
    """``float(np.percentile(a, q))`` of a non-empty 1-D float array (numpy's default
    "linear" method: the order statistics around ``(n - 1) q / 100``, interpolated
    as numpy's ``_lerp`` does)."""
    n = a.shape[0]
    v = (n - 1) * (q / 100)
    lo = math.floor(v)
    hi = lo + 1
    if v >= n - 1:  # numpy: the last order statistic (its index -1)
        lo = hi = -1
    gamma = v - lo
    part = np.partition(a, sorted({lo % n, hi % n, n - 1}))
    if np.isnan(part[n - 1]):
        return float(part[n - 1])
    x0, x1 = part[lo], part[hi]
    diff = x1 - x0
    return float(x1 - diff * (1 - gamma) if gamma >= 0.5 else x0 + diff * gamma)


def nan_to_num_fast(a: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(a)`` (NaN -> 0, +/-inf -> the largest finite values); a itself
    (not a copy) when it is all finite, the usual case."""
    return a if np.isfinite(a).all() else np.nan_to_num(a)


# ---------------------------------------------------------- region of interest
def ego_body_hit(
    rays_car: np.ndarray, origin_car: np.ndarray, box_m: tuple[float, float, float], margin_m: float
) -> np.ndarray:
    """(N,) bool: rays (N, 3) from origin (3,) (car frame) that enter the ego body box.

    The box is ``|x| <= L/2 + margin``, ``|y| <= W/2 + margin``, ``0 <= z <= H + margin``.
    A ray from a viewpoint inside the box is never counted as blocked (slab test).
    """
    L, Wd, Ht = box_m
    lo = np.array([-L / 2 - margin_m, -Wd / 2 - margin_m, 0.0])
    hi = np.array([L / 2 + margin_m, Wd / 2 + margin_m, Ht + margin_m])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / rays_car
        t1 = (lo - origin_car) * inv
        t2 = (hi - origin_car) * inv
    t1 = np.nan_to_num(t1, nan=-np.inf)
    t2 = np.nan_to_num(t2, nan=np.inf)
    t_near = np.max(np.minimum(t1, t2), axis=1)
    t_far = np.min(np.maximum(t1, t2), axis=1)
    return (t_near <= t_far) & (t_near > 0.0)


def road_roi(
    mount: CameraMount,
    rays: np.ndarray,
    max_range_m: float,
    ego_box_m: tuple[float, float, float] | None,
    ego_margin_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Road masks of rays (N, 3) of the nominal camera: (seen (N,) bool, in_range (N,) bool).

    seen: below the horizon (``K0^T r > 0``) and not through the ego body;
    in_range: the road hit is within ``max_range_m`` (horizontal distance from
    the viewpoint). Only ``seen`` has image edges at its border (body, horizon).
    """
    kr = rays @ mount.K0
    seen = np.isfinite(kr) & (kr > 1e-6)
    with np.errstate(invalid="ignore"):
        in_range = seen & (road_distance_m(rays, mount.K0) <= max_range_m)
    if ego_box_m is not None:
        rays_car = rays @ mount.R_car_cam.T
        seen &= ~ego_body_hit(
            rays_car, np.asarray(mount.position_m, float), ego_box_m, ego_margin_m
        )
    return seen, in_range


@dataclass
class _Level:
    """What depends only on the camera at one pyramid level.

    scale: 2^l; shape: (H_l, W_l); roi_idx: (M,) flat indices of candidate pixels;
    roi_w: (M, 2) their full-resolution pixels; roi_rays: (M, 3) their rays;
    valid_b: (H_l, W_l) uint8 mask of pixels where B may be sampled;
    sel_J: (M, 2, 9) float32 dw/dx of each candidate at the nominal state (V = 1 m/s
    forward, W = A = 0) per unit dt (V, W columns) and per metre of travel (A columns),
    for ranking candidates (`select_points`); to_mask: (M,) flat index of each candidate
    in the off-road mask grid (set by `DirectEstimator`); roi_rays32: roi_rays in float32
    (the dense off-road map).
    """

    scale: int
    shape: tuple[int, int]
    roi_idx: np.ndarray
    roi_w: np.ndarray
    roi_rays: np.ndarray
    valid_b: np.ndarray
    sel_J: np.ndarray
    to_mask: np.ndarray | None = None
    roi_rays32: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.roi_rays32 = self.roi_rays.astype(np.float32)


_Motion = list[tuple[np.ndarray, float]]  # frame pairs (x (9,), dt [s]), oldest first


def _composed(motion: _Motion, K: np.ndarray) -> np.ndarray:
    """(3, 3) homography of the plane K over consecutive pairs (at least one): each pair's
    eq. 3, the latest applied last (plane-induced homographies of one plane compose); one
    pair's is its own."""
    x0, dt0 = motion[0]
    H = homography(x0, K, dt0)
    for x, dt in motion[1:]:
        H = homography(x, K, dt) @ H
    return H


def _union(a: np.ndarray | None, b: np.ndarray | None) -> np.ndarray | None:
    """a | b of two (H, W) uint8 maps, either None (absent)."""
    if a is None or b is None:
        return a if b is None else b
    return a | b


def _level_shapes(height: int, width: int, levels: int) -> list[tuple[int, int]]:
    shapes = [(height, width)]
    for _ in range(1, levels):
        h, w = shapes[-1]
        shapes.append(((h + 1) // 2, (w + 1) // 2))
    return shapes


def build_levels(camera: CameraModel, mount: CameraMount, cfg: DirectConfig) -> list[_Level]:
    """Per-level ROI, rays of candidate pixels and sampling masks (once per camera).

    The image-edge masks (valid rays, road side of the horizon, outside the ego
    body) are eroded by ``roi_erode_px`` (plus 2 sigma of the pre-smoothing at
    level 0): no point or sample then reads pixels across those edges.
    """
    valid_full = camera.valid_mask()
    out = []
    kernel = np.ones((3, 3), np.uint8)
    for lvl, (h, w) in enumerate(_level_shapes(camera.height, camera.width, cfg.levels)):
        s = 2**lvl
        v, u = np.mgrid[0:h, 0:w]
        uf, vf = (u * s).ravel(), (v * s).ravel()
        inside = (uf < camera.width) & (vf < camera.height)
        valid = np.zeros(h * w, bool)
        valid[inside] = valid_full[vf[inside], uf[inside]]
        w_full = np.stack([uf, vf], 1).astype(np.float64)
        cand = np.flatnonzero(valid)
        rays = camera.unproject(w_full[cand])
        seen, in_range = road_roi(mount, rays, cfg.max_range_m, cfg.ego_box_m, cfg.ego_margin_m)
        erode = cfg.roi_erode_px + (math.ceil(2 * cfg.presmooth_sigma_px) if lvl == 0 else 0)
        clean = np.zeros(h * w, np.uint8)
        clean[cand[seen]] = 1
        clean = cv2.erode(clean.reshape(h, w), kernel, iterations=erode)
        keep = in_range & (clean.ravel()[cand] > 0)
        out.append(
            _Level(
                s,
                (h, w),
                cand[keep],
                w_full[cand[keep]],
                rays[keep],
                clean,
                selection_jacobian(camera, mount, rays[keep]),
            )
        )
    return out


def selection_jacobian(camera: CameraModel, mount: CameraMount, rays: np.ndarray) -> np.ndarray:
    """(N, 2, 9) float32 dw/dx of rays (N, 3) at the nominal state, per unit dt and travel.

    The state is V = 1 m/s along the car's x axis, W = A = 0, over a short dt: the V
    and W columns are then per second of dt, the A columns per metre of travel (the
    plane-tilt effect of A scales with the translation). Scale them by dt and by
    speed * dt (`_column_scale`) for the current frame pair.
    """
    dt = 1e-3
    x = make_state(mount.R_car_cam.T @ np.array([1.0, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    _, J = warp_jacobian(camera, rays, x, mount.K0, dt)
    return np.nan_to_num(J / dt).astype(np.float32)


def _column_scale(dt_s: float, speed_mps: float) -> np.ndarray:
    """(9,) factors turning `selection_jacobian` into dw/dx for this dt and speed."""
    f = np.full(N_STATE, dt_s)
    f[A_SLICE] = dt_s * max(abs(speed_mps), 0.5)
    return f


# ------------------------------------------------------------------ frames
@dataclass
class _Frame:
    """A frame's pyramid: per level (H_l, W_l) float32 images [I, dI/du, dI/dv] (level px),
    gradient magnitude and its 3x3 local maxima; reason: why the frame is unusable ("" if ok);
    roi: `roi_gradients` of the levels read so far."""

    t_s: float
    stacks: list[tuple[np.ndarray, ...]]  # (I, dI/du, dI/dv); (I,) or () in a `_slim` frame
    mags: list[np.ndarray]
    local_max: list[np.ndarray | None]
    gray: np.ndarray
    reason: str
    roi: dict[int, tuple[Any, np.ndarray, np.ndarray | None]] = field(default_factory=dict)
    offroad_look: np.ndarray | None = None  # (H_m, W_m) uint8: not road by its look


@functools.cache
def gaussian_kernel(sigma: float, ksize: int = 0) -> np.ndarray:
    """(k, 1) float32 kernel of ``cv2.GaussianBlur(img, (ksize, ksize), sigma)`` on a
    float32 image (ksize 0: OpenCV's choice for float images, ``round(8 sigma + 1) | 1``).
    Cached: read-only."""
    k = ksize if ksize > 0 else round(sigma * 4 * 2 + 1) | 1
    kernel = cv2.getGaussianKernel(k, sigma, cv2.CV_32F)
    kernel.setflags(write=False)
    return kernel


def gaussian_blur(img: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``cv2.GaussianBlur`` of a float32 image with a `gaussian_kernel`: the separable filter
    it runs (the same values, also at the borders: BORDER_REFLECT_101 both), without its
    per-call set-up (measured 565 -> 470 us on a 545 x 545 image)."""
    return cv2.sepFilter2D(img, -1, kernel, kernel)


def build_frame(gray: np.ndarray, t_s: float, cfg: DirectConfig, reason: str) -> _Frame:
    """Pyramid, gradients and NMS maxima of a frame (computed once, used as B then A)."""
    img = gray
    if cfg.presmooth_sigma_px > 0:
        img = gaussian_blur(gray, gaussian_kernel(cfg.presmooth_sigma_px))
    stacks, mags, lmax = [], [], []
    for lvl in range(cfg.levels):
        if lvl > 0:
            img = cv2.pyrDown(img)
        gu = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
        gv = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
        mag = cv2.magnitude(gu, gv)
        stacks.append((img, gu, gv))
        mags.append(mag)
        lmax.append(mag >= cv2.dilate(mag, np.ones((3, 3), np.uint8)) if cfg.nms else None)
    return _Frame(t_s, stacks, mags, lmax, gray, reason)


def roi_gradients(frame: _Frame, level: _Level, lvl: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(M,) gradient magnitude and (M,) bool 3x3 maxima (None without NMS) of a frame at
    the level's candidates (``level.roi_idx``). Gathered once per frame and level: a frame
    is read as B (`_road_residuals`), then as A by every pass of the next pair."""
    hit = frame.roi.get(lvl)
    if hit is None or hit[0] is not level:
        lmax = frame.local_max[lvl]
        hit = (
            level,
            frame.mags[lvl].ravel()[level.roi_idx],
            None if lmax is None else lmax.ravel()[level.roi_idx],
        )
        frame.roi[lvl] = hit
    return hit[1], hit[2]


def sample_points(images: tuple[np.ndarray, ...], w_level: np.ndarray) -> np.ndarray:
    """(N, C) bilinear samples of C (H, W) float32 images at (N, 2) level pixels (u, v)."""
    n = len(w_level)
    out = np.empty((n, len(images)), np.float32)
    if n == 0:
        return out
    cols = 4096  # cv2.remap maps must be smaller than 32767 in each dimension
    rows = -(-n // cols)
    if rows > 1:
        m = np.zeros((rows * cols, 2), np.float32)
        m[:n] = w_level
        m = m.reshape(rows, cols, 2)
    else:
        m = np.ascontiguousarray(w_level, np.float32).reshape(1, n, 2)
    for c, img in enumerate(images):
        out[:, c] = cv2.remap(
            img, m, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        ).reshape(-1)[:n]
    return out


def _in_level(w: np.ndarray, P: np.ndarray, K0: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(N,) bool: level pixels w (N, 2) inside the level image whose rays P (N, 3) are on
    the road's side (``K0ᵀ P > 0``); w is set to -1 elsewhere (no NaN left). A NaN pixel
    (no image) fails the comparisons."""
    hl, wl = shape
    u, v = w[:, 0], w[:, 1]
    ok = (P @ np.asarray(K0, P.dtype) > 0) & (u >= 0) & (u <= wl - 1) & (v >= 0) & (v <= hl - 1)
    w[np.flatnonzero(~ok)] = -1.0  # (by index: a boolean mask is read in full, ~3x slower)
    return ok


def _valid_at(valid: np.ndarray, w: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N,) bool: ok where the mask valid (H, W) is set at the nearest pixel of w (N, 2).
    w is inside the image where ok and -1 elsewhere (`_in_level`): no clipping needed (a
    -1 row reads some pixel, and ok is False there)."""
    r = np.rint(w).astype(np.intp)
    return ok & (valid.ravel()[r[:, 1] * valid.shape[1] + r[:, 0]] > 0)


def select_points(
    level: _Level,
    frame: _Frame,
    lvl: int,
    cfg: DirectConfig,
    P: np.ndarray | None = None,
    col_scale: np.ndarray | None = None,
    exclude: np.ndarray | None = None,
    x: np.ndarray | None = None,
) -> np.ndarray:
    """Indices into level.roi_idx of the selected points of frame A at a level.

    Candidates: gradient magnitude above ``grad_threshold`` (level px), 3x3 maxima
    with ``nms``, not ``exclude`` (M,) bool (off-road mask), and, given the state x (9,)
    and col_scale, not moved more than ``max_flow_px`` by it (`too_fast`). At most ``max_points``
    are kept, spread over a grid of ``select_cells``² cells (`_spread_top`), ranked:

    - ``selection="information"`` (with the prior covariance P (9, 9)): by how much the
      prior's uncertainty moves the point's brightness, relative to its noise. With
      ``c = gᵀ dw/dx`` (dw/dx from ``level.sel_J`` times ``col_scale`` (9,)) and
      ``P = L Lᵀ``, the whitened sensitivities ``u = Lᵀ c / sqrt(R)`` add up to eq. 20's
      ``c P cᵀ / R``; each of their 9 components is divided by its total over the
      candidates, so that a point informative about a direction few points see (A,
      the vertical speed) is not outranked by the many that see the speed;
    - ``"gradient"``: by gradient magnitude (the paper's choice).

    A gradient-strength ranking picks the strongest edges of the road ring: guard
    rails, posts, vehicles and the ego car's roof, not the road.
    """
    mag, lmax = roi_gradients(frame, level, lvl)
    keep = mag > cfg.grad_threshold
    if cfg.nms:
        keep &= lmax
    if exclude is not None:
        keep &= ~exclude
    sel = np.flatnonzero(keep)
    if x is not None and col_scale is not None and cfg.max_flow_px > 0:
        sel = sel[~too_fast(np.take(level.sel_J, sel, 0), x, col_scale, cfg.max_flow_px)]
    if len(sel) > cfg.max_points:
        if cfg.selection == "information" and P is not None and col_scale is not None:
            idx = level.roi_idx[sel]
            gu = frame.stacks[lvl][1].ravel()[idx].astype(np.float64)
            gv = frame.stacks[lvl][2].ravel()[idx].astype(np.float64)
            J = np.take(level.sel_J, sel, 0)
            s = 1.0 / level.scale  # level gradients -> per full-resolution pixel
            c = (gu[:, None] * J[:, 0] + gv[:, None] * J[:, 1]) * (col_scale * s)
            R = cfg.sigma_intensity**2 + cfg.sigma_flow_px**2 * mag[sel].astype(np.float64) ** 2
            # whitened sensitivities u = Lᵀ c / sqrt(R) (P = L Lᵀ): |u|² = c P cᵀ / R; each
            # direction's share of the total information, so that every direction counts
            u2 = np.square(c @ np.linalg.cholesky(P + 1e-18 * np.eye(N_STATE))) / R[:, None]
            score = np.sum(u2 / np.maximum(u2.sum(axis=0), 1e-300), axis=1)
        else:
            score = mag[sel]
        sel = np.sort(
            sel[_spread_top(np.take(level.roi_w, sel, 0), score, cfg.max_points, cfg.select_cells)]
        )
    return sel


def too_fast(
    sel_J: np.ndarray, x: np.ndarray, col_scale: np.ndarray, max_flow_px: float
) -> np.ndarray:
    """(N,) bool: points that state x (9,) moves more than max_flow_px (full-resolution
    px) over the pair, to first order: their selection Jacobian sel_J (N, 2, 9) times x
    scaled by `_column_scale` (col_scale)."""
    flow = sel_J @ (x * col_scale).astype(np.float32)  # (N, 2) [px]
    return np.einsum("ij,ij->i", flow, flow) > max_flow_px**2


def _spread_top(w: np.ndarray, score: np.ndarray, n: int, cells: int) -> np.ndarray:
    """Indices of n of the points w (N, 2) [full-res px]: the best scores of each cell of a
    cells x cells grid over their bounding box (equal quota per occupied cell), then the
    best of the rest. Spreading the points over the image keeps the state's directions
    that only differ across the field of view (e.g. a pinhole's yaw and pitch) apart."""
    if cells <= 1:
        return np.argpartition(-score, n - 1)[:n]
    lo, hi = w.min(axis=0), w.max(axis=0)
    ij = np.minimum(((w - lo) / np.maximum(hi - lo, 1e-9) * cells).astype(np.int64), cells - 1)
    cell = ij[:, 1] * cells + ij[:, 0]
    order = np.lexsort((-score, cell))  # by cell, best score first
    c_sorted = cell[order]
    first = np.searchsorted(c_sorted, c_sorted, side="left")
    rank = np.empty(len(w), np.int64)
    rank[order] = np.arange(len(w)) - first  # rank of each point within its cell
    quota = max(1, n // len(np.unique(cell)))
    take = rank < quota
    chosen = np.flatnonzero(take)
    if len(chosen) > n:
        return chosen[np.argpartition(-score[chosen], n - 1)[:n]]
    rest = np.flatnonzero(~take)
    k = n - len(chosen)
    if k > 0 and len(rest):
        rest = rest[np.argpartition(-score[rest], min(k, len(rest)) - 1)[:k]]
        chosen = np.concatenate([chosen, rest])
    return chosen


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


class DirectEstimator(EgoMotionEstimator):
    """Direct (gradient-based) IEKF ego-motion estimator of the paper (section 4).

    ``step(image, t_s, can_speed_mps) -> EgoMotionRecord``; the first call only
    initialises. Holds the previous frame's pyramid, the per-level camera
    precomputations (`_Level`) and the filter (`IteratedEKF`).
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
        self._prev: _Frame | None = None
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
        # (4, 1) fractions of a marked pixel's motion that `_smeared_marks` also marks
        self._smear_steps = np.linspace(-cfg.mask_smear, cfg.mask_smear, 5)[[0, 1, 3, 4], None]
        self._offroad: np.ndarray | None = None  # (H_m, W_m) uint8 of the previous frame
        self._carried: tuple[np.ndarray, int] | None = None  # last usual fit's map, its age
        self._parallax_strips: dict[tuple[int, int], RoiStrip] = {}  # `_parallax_strip`
        self._cell_maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}  # `_cells`
        # the last well-fitted consecutive pairs (first frame (`_slim`), x, dt, gain), oldest
        # first, and the last one's second frame: the baseline of `_parallax_baseline`
        self._chain: list[tuple[_Frame, np.ndarray, float, float]] = []
        self._chain_end: _Frame | None = None
        self._raised: np.ndarray | None = None  # (H_r, W_r) float32 evidence behind it
        self._gain = 1.0  # brightness gain B -> A of the last linearisation
        self._fine: _FineLevel | None = None  # the last fit's finest level (`point_pull`)
        self._s2_hist: list[float] = []  # noise scales of the recent good fits
        self._road_prev: np.ndarray | None = None  # given road mask of the previous frame
        self._offroad_given: list[np.ndarray] | None = None  # its exclusions, per level
        # the road's seed pixels at the mask level (`estimator.road_appearance`)
        self._look_seed = (
            mask_level.roi_idx[seed_indices(mask_level.roi_rays, self.K0)]
            if cfg.road_appearance
            else None
        )

    def compensate(
        self, image_prev: np.ndarray, dt_s: float, x: np.ndarray | None = None
    ) -> np.ndarray:
        """(H, W) float32 previous frame warped onto the current one with x (default x̂).

        Uses `estimator.compensation.FrameCompensator` (per-camera maps built once).
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
                f.level, 0, f.rays, f.a_val, f.B, f.dt, inlier, f.off, f.w_a
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
    def _frame(self, gray: np.ndarray, t_s: float) -> _Frame:
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
        level: _Level,
        lvl: int,
        rays: np.ndarray,
        a_val: np.ndarray,
        B: _Frame,
        dt: float,
        included: np.ndarray,
        off: np.ndarray | None = None,
        w_a: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Steps 1-3 at x̂: (idx (M,) points that land in B, Δz (M,), C (M, 9), R (M,)).

        w_a: (len(rays), 2) the points' level pixels in A, for ``flow_noise_frac``.

        off: (len(rays),) bool, points that a given road mask puts off the road: their
        plane scale lambda is unknown (std ``offroad_depth_sigma``); since D is linear in
        V, the residual's derivative w.r.t. lambda is the one w.r.t. the speed scale,
        ``C V``, and ``(sigma C V)²`` joins R: they tell the rotation, hardly the speed.
        """
        cfg, cam, x = self.cfg, self.camera, self.ekf.x
        s = float(level.scale)
        # step 1: warp the points into B with x̂ (eq. 3, 6-10)
        P_b = map_rays(rays, homography(x, self.K0, dt))
        w_b = cam.project(P_b) / s  # level pixels
        inside = _in_level(w_b, P_b, self.K0, level.shape)
        idx = np.flatnonzero(_valid_at(level.valid_b, w_b, inside))
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
        self, A: _Frame, B: _Frame, dt: float, flags: list[str], reasons: list[str]
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
        raised, self._raised = self._raised, None
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
            own = self._offroad_map(B, A, dt, res["noise_scale"], True, residuals=residuals)
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
            self._offroad = self._offroad_map(A, B, dt, res["noise_scale"], raised=raised)
            self._carried = self._offroad, 0
        if failure is None and cfg.parallax_baseline_m > 0:
            keep = cfg.parallax_baseline_frames - 1
            entry = (self._slim(A), ekf.x.copy(), dt, self._gain)
            self._chain = (self._chain_to(A) + [entry])[-keep:] if keep else []
            self._chain_end = B
        elif failure is not None:
            self._chain, self._chain_end = [], None
        if self._offroad is None and self._carried is not None:
            self._offroad = self._carry_map(flags)
        if first_fit and not cfg.first_fit_A:
            ekf.hold_A()
            flags.append("A-held")
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
        A: _Frame,
        B: _Frame,
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
        """
        cfg, ekf = self.cfg, self.ekf
        shift, sd = self._yaw_shift()
        if abs(shift) <= cfg.yaw_jump_sigmas * max(sd, 1e-9):
            return res
        first = res, ekf.x.copy(), ekf.P.copy()
        x_prior, P_prior = ekf.x_prior.copy(), ekf.P_prior.copy()
        wide = P_prior + self._yaw_cov(cfg.yaw_jump_widen * abs(shift))
        ekf.set_prior(x_prior, wide)
        r = self._coarse_to_fine(A, B, dt, excl)
        if self._failure(r, res["n_points"]) is None:
            flags.append("yaw-jump")
            return r
        ekf.set_prior(x_prior, P_prior)  # (resets x̂ to the prior mean: before the fit)
        res, ekf.x, ekf.P = first
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
        A: _Frame,
        B: _Frame,
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
        col_scale = _column_scale(dt, speed)
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
                idx, dz, C, R = self._linearise(level, lvl, rays, a_val, B, dt, included, off, w_a)
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
                fine = _FineLevel(level, pts_out, rays, a_val, B, off, w_a, dt, labels, s2)
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
        A: _Frame,
        B: _Frame,
        dt: float,
        excluded: list[np.ndarray] | None,
        col_scale: np.ndarray,
    ) -> tuple[_Level, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
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
        level: _Level,
        lvl: int,
        rays: np.ndarray,
        a_val: np.ndarray,
        B: _Frame,
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
        ok = _in_level(w_b, P_b, self.K0, level.shape)
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
        self, level: _Level, lvl: int, sel: np.ndarray, A: _Frame, B: _Frame, dt: float
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

    def _plane_pixels(
        self, rays32: np.ndarray, K: np.ndarray, motion: _Motion, backward: bool, s: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where the plane K under the motion (frame pairs (x, dt), oldest first: the pair's
        own ``[(x̂, dt)]``, or those from an older frame, `_parallax_baseline`) puts rays32
        (N, 3) float32 of the frame being marked in the other frame (H⁻¹: second frame to
        first; H when ``backward``): P (N, 3) and its level pixels (N, 2), in float32 (the
        dense off-road map: ~5x faster projections, ~1e-4 px)."""
        P, w = self._planes_pixels(rays32, [K], motion, backward, s)
        return P[0], w[0]

    def _planes_pixels(
        self,
        rays32: np.ndarray,
        Ks: list[np.ndarray],
        motion: _Motion,
        backward: bool,
        s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """`_plane_pixels` for several planes Ks at once: P (L, N, 3) and level pixels (L, N,
        2). The same values: the homographies one by one (`_composed`), their inverses,
        products and the projection batched (numpy runs the same LAPACK / BLAS call per
        plane; the projection is row by row)."""
        Hs = np.stack([_composed(motion, K) for K in Ks])
        Ms = Hs if backward else np.linalg.inv(Hs)
        P = np.asarray(rays32, np.float32) @ np.ascontiguousarray(Ms.transpose(0, 2, 1), np.float32)
        w = self.camera.project(P.reshape(-1, 3), np.float32) / np.float32(s)
        return P, w.reshape(len(Ks), -1, 2)

    def _parallax_strip(self, lvl: int, reach: int) -> RoiStrip:
        """The level's ROI packed for blurs of that reach (`roi_strip`), where
        `_parallax_marks` blurs. Computed once per level and reach."""
        key = (lvl, reach)
        if key not in self._parallax_strips:
            level = self.levels[lvl]
            self._parallax_strips[key] = roi_strip(level.roi_idx, level.shape, reach)
        return self._parallax_strips[key]

    def _parallax_marks(
        self,
        A: _Frame,
        B: _Frame,
        motion: _Motion,
        lvl: int,
        tex: np.ndarray,
        idx: np.ndarray,
        w_road: np.ndarray,
        b_val: np.ndarray,
        r_road: np.ndarray,
        ok: np.ndarray,
        noise: float,
        backward: bool = False,
        gain: float | None = None,
    ) -> np.ndarray:
        """(len(tex),) bool: textured pixels of B that a plane above the road explains better.

        From `_offroad_map`, per textured ROI pixel of B at level lvl: w_road (N, 2)
        where the road hypothesis finds it in A [level px], b_val (N,) its brightness in
        B, r_road (N,) the road's residual, ok (N,) usable.

        Plane + parallax: a static point at height z moves in the image like the plane
        ``K = lambda K0`` with ``lambda = h / (h - z)`` (eq. 3-4 with the plane moved up).
        For each ``parallax_lambdas`` hypothesis, A is warped onto B's textured ROI pixels
        and the Gaussian-windowed residual energy compared with the road's (lambda = 1):
        a pixel is marked where a raised plane leaves less than ``parallax_ratio`` of it
        and the road's energy is above the noise. Guard-rails, posts and kerbs far from
        the car move only a pixel or two more than the road there: each pixel's residual
        alone is within the noise, the comparison over a window is not.

        The residuals are sampled at B's gradient maxima (with ``nms``: a quarter of the
        textured pixels, where the next pair's points come from) and the windowed
        energies read at every textured pixel. A sample where a hypothesis moves the
        pixel less than ``parallax_min_px`` farther than the road does (low speed, near
        the focus of expansion: the two cannot be told apart) keeps the road's residual.
        """
        cfg = self.cfg
        level = self.levels[lvl]
        s = float(level.scale)
        _, lmax = roi_gradients(B, level, lvl)
        smp = np.flatnonzero(ok & lmax[tex] if lmax is not None else ok)
        rays = np.take(level.roi_rays32, tex[smp], 0)
        r2_road, w_road, b_val = np.square(r_road[smp]), np.take(w_road, smp, 0), b_val[smp]

        # The Gaussian window is truncated at 3 sigma (as OpenCV does for 8-bit images; 4
        # for float ones): 0.3 % of its weight, 2/3 of the taps. The images are zero outside
        # the ROI and read inside it: the blurs run on the ROI's pixels and a kernel's reach
        # around them (`roi_strip`): the same sums as on the whole level, on the omni
        # camera's ring ~0.36 of the pixels.
        half = math.ceil(3 * cfg.parallax_window_px)
        strip = self._parallax_strip(lvl, half)
        put, get = strip.copies[:, tex[smp]], strip.core[tex]
        window = gaussian_kernel(cfg.parallax_window_px, 2 * half + 1)
        canvas = np.zeros(strip.size + 1, np.float32)  # every blur sets the same pixels

        def blurred(values: np.ndarray) -> np.ndarray:  # (strip.size,), read once at the end
            return strip_blur_image(strip, put, values, window, canvas)

        # The windowed energies are blur(r²) / blur(1) over the samples; the blur is linear,
        # so "e_l < ratio e_road" is "blur(r²_l - ratio r²_road) < 0", and the road's energy
        # above the noise level s² sigma² is "blur(r²_road - noise² / thr) > 0": one blur
        # per hypothesis and one for the noise, none for the normalisation.
        loud = blurred(r2_road - noise**2 / cfg.snoop_threshold) > 0
        better = np.zeros(strip.size, bool)
        if gain is None:
            gain = 1.0 / self._gain if backward else self._gain
        # every hypothesis's warp and samples at once: (L, n) per plane lambda
        n_lam = len(cfg.parallax_lambdas)
        Ks = [lam * self.K0 for lam in cfg.parallax_lambdas]
        P_l, w_l = self._planes_pixels(rays, Ks, motion, backward, s)
        apart = np.sum(np.square(w_l - w_road), axis=2) > cfg.parallax_min_px**2
        use = _in_level(w_l.reshape(-1, 2), P_l.reshape(-1, 3), self.K0, level.shape)
        use = use.reshape(n_lam, -1) & apart
        a_l = sample_points(A.stacks[lvl][:1], w_l.reshape(-1, 2))[:, 0].astype(np.float64)
        for i, a_i in enumerate(a_l.reshape(n_lam, -1)):
            r2 = np.where(use[i], np.square(a_i - gain * b_val), r2_road)
            better |= blurred(r2 - cfg.parallax_ratio * r2_road) < 0
        return (better & loud)[get] & ok

    def _offroad_map(
        self,
        A: _Frame,
        B: _Frame,
        dt: float,
        s2: float,
        backward: bool = False,
        raised: np.ndarray | None = None,
        residuals: bool = True,
    ) -> np.ndarray:
        """(H_m, W_m) uint8: pixels of frame B that the estimated road motion does not explain.

        At the mask level, frame A is warped onto B's ROI pixels with x̂ (H⁻¹, as in
        `compensate`); a pixel is marked where its residual |r| exceeds what a normal
        motion of ``mask_motion_px`` (level px) and the noise explain: ``|r| > mask_motion_px
        |g| + sqrt(snoop_threshold s²) sigma_intensity`` (s² >= 1: the fit's noise level).
        Residuals below that are the data snooping's business (eq. 20-21); marking them
        would drop, frame after frame, the points that disagree with the estimate.
        Textured structures above the road (rails, posts, vehicles, the ego body) leave
        such residuals; the mask keeps their neighbourhood out of the next frame pair's
        points, where B is frame A (`select_points`): their pixels would blend, through
        the pyramid's smoothing, motion that is not the road's into road points. Motion
        blur spreads a structure along its image motion: marks are also smeared along
        +/- ``mask_smear`` of the pixel's motion. Structure above the road whose residual
        is within the noise pixel by pixel is caught by the plane-parallax test
        (`_parallax_marks`, ``parallax_lambdas``).

        backward: the pair's frames in reverse (B is then the pair's first frame, A its
        second): the map of the first frame from the pair's own fit (``own_map``).
        residuals: False: the plane-parallax marks alone (``first_map_residuals``).
        """
        cfg, lvl = self.cfg, self._mask_lvl
        hm, wm = self.levels[lvl].shape
        pair = [(self.ekf.x, dt)]
        tex, idx, g, w_a, ok, b_val, r_road = self._road_residuals(A, B, pair, lvl, backward)
        textured = tex, idx  # B's textured pixels at the mask level
        noise = math.sqrt(cfg.snoop_threshold * min(max(s2, 1.0), 100.0)) * cfg.sigma_intensity
        if residuals:
            bad = ok & (np.abs(r_road) > cfg.mask_motion_px * g + noise)
            out = self._smeared_marks(idx[bad], w_a[bad], (hm, wm))
        else:
            out = np.zeros((hm, wm), np.uint8)
        if cfg.parallax_lambdas:
            plvl = self._parallax_lvl()
            A_p, motion, gain = (A, pair, None) if backward else self._parallax_baseline(A, dt)
            w_road = w_a  # where the road puts B's textured pixels in A_p
            if plvl != lvl:  # the windowed test at a coarser level (cheaper), marks upsampled
                tex, idx, g, w_a, ok, b_val, r_road = self._road_residuals(
                    A_p, B, motion, plvl, backward, gain
                )
                w_road = w_a
            elif A_p is not A:
                # against an older frame: B's same textured pixels (gathered once); the marks'
                # smear stays the pair's own motion (w_a)
                _, _, _, w_road, ok, _, r_road = self._road_residuals(
                    A_p, B, motion, plvl, backward, gain, (tex, idx, g, b_val)
                )
            par = self._parallax_marks(
                A_p, B, motion, plvl, tex, idx, w_road, b_val, r_road, ok, noise, backward, gain
            )
            marks = self._smeared_marks(idx[par], w_a[par], self.levels[plvl].shape)
            if plvl != lvl:
                marks = cv2.resize(marks, (wm, hm), interpolation=cv2.INTER_NEAREST)
            if cfg.raised_memory > 0 and not backward:
                marks |= self._raised_cells(*textured, dt, marks, raised)
            out |= marks
        return out

    def _slim(self, frame: _Frame) -> _Frame:
        """The frame with only what the plane-parallax test reads of an older frame: its image
        at the parallax level (~1.6 MB at 640 px instead of the pyramid's ~10 MB)."""
        plvl = self._parallax_lvl()
        stacks = [st[:1] if lvl == plvl else () for lvl, st in enumerate(frame.stacks)]
        return _Frame(frame.t_s, stacks, [], [], np.empty(0, np.uint8), frame.reason)

    def _parallax_lvl(self) -> int:
        """Pyramid level of the plane-parallax test (``parallax_level``; None: the mask's)."""
        cfg = self.cfg
        return (
            self._mask_lvl
            if cfg.parallax_level is None
            else min(cfg.parallax_level, cfg.levels - 1)
        )

    def _chain_to(self, A: _Frame) -> list[tuple[_Frame, np.ndarray, float, float]]:
        """``_chain`` if its last pair ends at frame A (the pairs are consecutive), else []."""
        return self._chain if self._chain_end is A else []

    def _parallax_baseline(self, A: _Frame, dt: float) -> tuple[_Frame, _Motion, float | None]:
        """(frame, motion, gain) of the plane-parallax test of the pair (A, B): A itself, the
        pair's ``[(x̂, dt)]`` and None (the pair's gain) unless the pair travels less than
        ``parallax_baseline_m``; then the frame of the fewest earlier well-fitted
        consecutive pairs (`_chain_to`) that reach it, or all of them: the pairs' (x, dt)
        oldest first, this pair's x̂ last, and the product of their brightness gains."""
        cfg = self.cfg
        travel = float(np.linalg.norm(self.ekf.x[V_SLICE])) * dt
        chain = self._chain_to(A)
        if cfg.parallax_baseline_m <= 0 or not chain or travel >= cfg.parallax_baseline_m:
            return A, [(self.ekf.x, dt)], None
        n = 0  # earlier pairs taken
        while n < len(chain) and travel < cfg.parallax_baseline_m:
            n += 1
            travel += float(np.linalg.norm(chain[-n][1][V_SLICE])) * chain[-n][2]
        pairs = chain[-n:]
        motion = [(x, d) for _, x, d, _ in pairs] + [(self.ekf.x.copy(), dt)]
        gain = float(np.prod([g for *_, g in pairs])) * self._gain
        return pairs[0][0], motion, gain

    def _raised_cells(
        self,
        tex: np.ndarray,
        idx: np.ndarray,
        dt: float,
        marks: np.ndarray,
        raised: np.ndarray | None,
    ) -> np.ndarray:
        """(H_m, W_m) uint8: B's textured pixels (tex (N,): indices into the mask level's ROI,
        idx (N,) their pixels, from `_road_residuals`) in cells of level ``raised_level`` that the
        plane-parallax test has marked in at least ``raised_share`` of their textured pixels,
        on average over the recent frames; stores B's evidence (H_r, W_r) float32 for the
        next pair.

        The average of frame A (raised, None: none) is carried to B along the road motion
        (bilinear, at each ROI cell's position in A; a cell new to the view starts at 0) and
        updated where B's cell has texture: ``e = m e_A + (1 - m) share_B``, m =
        ``raised_memory``. A static structure keeps its cells; a moving vehicle's marks
        are carried beside it and fade (the residual test marks it frame by frame).
        """
        cfg, lvl = self.cfg, self._mask_lvl
        rl = min(max(cfg.raised_level, lvl), cfg.levels - 1)
        level = self.levels[rl]
        hr, wr = level.shape
        cell_of, cell_px = self._cells(lvl, rl)
        # the shares per cell: means over the cell's mask-level pixels
        cell = cell_of[tex]
        n_tex = np.bincount(cell, minlength=hr * wr).astype(np.float32) / cell_px
        marked = cell[marks.ravel()[idx].view(bool)]  # marks are 0 / 1
        n_mark = np.bincount(marked, minlength=hr * wr).astype(np.float32) / cell_px
        carried = np.zeros(hr * wr, np.float32)
        if raised is not None:
            pair = [(self.ekf.x, dt)]
            P_a, w_a = self._plane_pixels(
                level.roi_rays32, self.K0, pair, False, float(level.scale)
            )
            ok = _in_level(w_a, P_a, self.K0, level.shape)
            carried[level.roi_idx[ok]] = sample_points((raised,), w_a[ok])[:, 0]
        seen = n_tex > 0.05  # a cell with some texture updates its average
        share = n_mark / np.maximum(n_tex, 1e-6)
        m = np.float32(cfg.raised_memory)
        ev = np.where(seen, m * carried + (1 - m) * share, carried).astype(np.float32)
        self._raised = ev.reshape(hr, wr)
        out = np.zeros(marks.size, np.uint8)
        out[idx[(ev >= cfg.raised_share)[cell]]] = 1
        return out.reshape(marks.shape)

    def _cells(self, lvl: int, rl: int) -> tuple[np.ndarray, np.ndarray]:
        """(M,) flat index at level rl of the cell of each ROI pixel of level lvl (the block of
        2^(rl - lvl) x 2^(rl - lvl) pixels above it; the last row and column of cells take
        what a level of odd size leaves over) and (H_rl * W_rl,) float32 the number of level
        lvl pixels of each cell. Computed once per pair of levels."""
        key = (lvl, rl)
        if key not in self._cell_maps:
            (h, w), (hr, wr) = self.levels[lvl].shape, self.levels[rl].shape
            f = 2 ** (rl - lvl)
            rows = np.minimum(np.arange(h) // f, hr - 1)
            cols = np.minimum(np.arange(w) // f, wr - 1)
            cell = (rows[:, None] * wr + cols[None, :]).ravel()
            px = np.maximum(np.bincount(cell, minlength=hr * wr), 1).astype(np.float32)
            self._cell_maps[key] = cell[self.levels[lvl].roi_idx], px
        return self._cell_maps[key]

    def _road_residuals(
        self,
        A: _Frame,
        B: _Frame,
        motion: _Motion,
        lvl: int,
        backward: bool,
        gain: float | None = None,
        textured: tuple[np.ndarray, ...] | None = None,
    ) -> tuple[np.ndarray, ...]:
        """Frame A warped onto B's textured ROI pixels at level lvl with the road's motion
        (`_plane_pixels`); gain: A's brightness over B's (None: the pair's, ``_gain``);
        textured: (tex, idx, g, b_val) of an earlier call for B at this level (only A and
        the motion differ), else gathered here.

        Returns tex (N,) indices into the level's ROI candidates, idx (N,) their pixel
        indices, g (N,) B's gradient magnitude there, w_a (N, 2) where the road puts them in
        A [level px], ok (N,) usable, b_val (N,) B's brightness, r_road (N,) A - gain B.
        Only textured pixels of B can be points of the next pair (and a residual there says
        what B shows there is not the road); flat ones are left to the dilation.
        """
        cfg, level = self.cfg, self.levels[lvl]
        s = float(level.scale)
        if textured is None:
            g, _ = roi_gradients(B, level, lvl)
            tex = np.flatnonzero(g > cfg.grad_threshold)
            idx, g = level.roi_idx[tex], g[tex].astype(np.float64)
            b_val = B.stacks[lvl][0].ravel()[idx].astype(np.float64)
        else:
            tex, idx, g, b_val = textured
        if gain is None:
            gain = 1.0 / self._gain if backward else self._gain
        rays = np.take(level.roi_rays32, tex, 0)
        P_a, w_a = self._plane_pixels(rays, self.K0, motion, backward, s)
        ok = _valid_at(level.valid_b, w_a, _in_level(w_a, P_a, self.K0, level.shape))
        a_val = sample_points(A.stacks[lvl][:1], w_a)[:, 0].astype(np.float64)
        return tex, idx, g, w_a, ok, b_val, a_val - gain * b_val

    def _smeared_marks(
        self, idx: np.ndarray, w_a: np.ndarray, shape: tuple[int, int]
    ) -> np.ndarray:
        """(H, W) uint8 map of the pixels idx (M,) of a level of that shape, each also
        marked along +/- ``mask_smear`` of its image motion (from w_a (M, 2) in the other
        frame): motion blur smears a structure along its image motion."""
        hm, wm = shape
        out = np.zeros(hm * wm, np.uint8)
        out[idx] = 1
        if self.cfg.mask_smear > 0 and len(idx):
            vb, ub = np.divmod(idx, wm)
            t = self._smear_steps
            u = np.rint(ub + t * (ub - w_a[:, 0])).astype(np.intp)  # (4, M): t != 0 (idx is set)
            v = np.rint(vb + t * (vb - w_a[:, 1])).astype(np.intp)
            inb = (u >= 0) & (u < wm) & (v >= 0) & (v < hm)
            out[v[inb] * wm + u[inb]] = 1
        return out.reshape(hm, wm)
