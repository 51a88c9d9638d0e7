"""Vehicle detection after ego-motion compensation (paper section 5).

The paper compensates the previous frame with the road homography and
thresholds the normalized frame difference (eq. 22): whatever is not on the
road plane lights up. On rendered drives that alone does not find vehicles:

- a vehicle driving at about the ego car's speed is nearly still in the image,
  so after road compensation it shows only the small residual of the road flow
  at its pixels (|ND| ~0.4 median on its pixels, omni-near, 18 m ahead);
- static roadside structure with height (guard-rail posts, poles, trees) has a
  large parallax after road compensation (|ND| up to 2.5-3.9, p99-p99.9);
- thin rendered features (lane marks, rail edges) alias on the pixel grid.

So this module tests, at every pixel, which *motion hypothesis* explains the
change from an earlier frame best ("independent motion OR height"):

- a point at height z above the road, static, moves in the image like the
  plane parallel to the road at height z. With ``lambda = h / (h - z)`` (h the
  viewpoint's height) its homography is ``H_lambda = R + lambda D K^T`` (eq.
  3-4 with the translation scaled by lambda): the road is lambda = 1, and every
  static point below the horizon has ``lambda >= 1`` (`static_lambdas`);
- a point fixed to the ego car (another vehicle driving alongside at the same
  speed) moves only with the camera's vibration: lambda = 0, with the rotation
  R stripped of the car's yaw (`moving_lambdas`); more generally a vehicle
  driving forward at ground speed v_g has ``lambda = (1 - v_g/v_ego) h/(h - z)``,
  which is < 1 for every forward-moving vehicle faster than ~(1 - (h - z)/h) v_ego.

For each hypothesis the earlier frame is warped onto the current one
(`estimator.egomotion.compensation`); ``E_lambda = <(I - I_lambda)^2>`` is the
Gaussian-windowed residual energy. The score

    m = max_j (min_static E - E_j) / (S_j + k + <|g|^2> sigma^2)

over the moving hypotheses j is positive where a moving hypothesis explains the
pixel better than every static one. ``S_j = <(I_1 - I_j)^2>`` is how different
the road's and hypothesis j's predictions are there (where the texture is the
same either way, e.g. streaks along the flow, nothing can be decided), ``k`` a
noise floor [grey level^2] and ``<|g|^2> sigma^2`` the residual that a
misregistration of sigma px leaves on an edge (aliasing of the render,
interpolation, ego-motion error). It is like eq. 22's normalisation, for a pair
of hypotheses instead of one. A hypothesis between the car and the road (0 <
lambda_j < 1) is scored only where S_j reaches that floor: elsewhere its
prediction is the road's within noise, and dividing by a small S_j would turn
noise and disocclusions into motion. In the small-motion limit ``E_lambda ~ (lambda -
lambda*)^2 S_0`` for a point at lambda*, so ``m_j ~ ((1 - lambda*)^2 - (lambda* -
lambda_j)^2) / (1 - lambda_j)^2``: 1 on hypothesis j, -1 on the road, and above
the threshold of 0.5 for every lambda* < 0.81 with the hypotheses 0, 0.25, 0.5
and 0.75 (one hypothesis at 0 alone would stop at lambda* < 0.25). The score is
computed at the working scale and one coarser pyramid level (a vehicle close
by moves tens of pixels: the coarse level keeps the hypotheses apart).

Then, as in the paper: threshold, flat-plane transform into the plan view
(`estimator.surround.planview`), morphological closing with a 1 x N mask along the car's
direction of motion (N = 5.0 m: two blobs within 5 m in that direction are one
vehicle), blobs (connected components), nearby blobs clustered, and the blob
point nearest the camera taken as on the road (the obstacle map): its
road-plane position by inverse perspective. The nearest point is that of the
blob's parts that reach a vehicle's height (`VehicleDetector._tall_parts`); a
blob without such a part (low structure, e.g. guard-rail posts closed into a
strip) is no candidate.

Obstacle map where the road is hidden: a blob whose nearest point sees a pixel next to
the car-body mask (the body's silhouette where one is given,
`estimator.camera.models.CameraModel.with_body_mask`; else the omni camera's body cone,
~7.3 m of road) does not show where the vehicle meets the road, only its bearings. Such
a detection is flagged ``hidden``; the arc along which the blob's tall parts meet the edge gives
its bearings, and a car-sized box along the ego car's heading that spans them gives
its range (`estimator.surround.hidden`: the nearer, the wider; without a fit, at
``hidden_range_frac`` of the edge's range on the arc's middle); the tracker refines
it (bearing-only update).

``method="learned"`` marks the pixels with a fitted classifier instead of the score's
threshold: the energies of every hypothesis, the separations S_j, the floor, the scores
and their neighbourhood, the road range and the local brightness and contrast, at both
levels (`estimator.surround.pixel_classifier`; fitted to rendered drives' id images by
`scenarios.train_pixels`). Everything after the mask is the same.

``method="paper"`` runs the paper's section 5 as written instead, as a baseline:
eq. 22 thresholded, plan view, 1 x N closing, blobs, nearest point.

Ego car (nearly) stopped (displacement over the baseline below
``still_displacement_m``): every hypothesis is then almost the same warp, S ~ 0
and m decides nothing, while a crossing vehicle is explained by none of them.
There, as in eq. 22, a pixel that no static hypothesis explains is moving:
``r = min_static E / (k + <|g|^2> sigma^2) > still_threshold``.

Not detected: vehicles the ego car overtakes fast, lambda* > 0.81 (driving at less
than about a fifth of its speed; docs/DESIGN.md, "the motion score: a pair of
hypotheses at a time"); vehicles that do not move over the
ground when the ego car does not either (nothing distinguishes them from static
structure in two frames) and, while the ego car moves, vehicles whose motion is not
forward along the road (crossing traffic): those must show a larger-than-static
parallax (lambda > max static) or be tracked; see `estimator.surround.analyzer`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.egomotion.compensation import FrameCompensator
from estimator.egomotion.homography import homography_parts
from estimator.frame_times import StageClock
from estimator.geometry import skew
from estimator.surround.boxfit import Box
from estimator.surround.hidden import hidden_box
from estimator.surround.outline import lower_outline, nearest_on_outline
from estimator.surround.pixel_classifier import (
    BUILTIN_MODEL,
    Energies,
    PixelClassifier,
    gather,
    level_features,
    pixel_features,
)
from estimator.surround.planview import PlanView, pixel_road_xy
from estimator.surround.window import gauss_window, gradient_sq

DEFAULT_DETECTOR = "hypotheses"  # `DetectorConfig.method` by default
DETECTOR_METHODS = (DEFAULT_DETECTOR, "learned", "paper")  # `DetectorConfig.method`


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of `VehicleDetector` (units beside each value).

    "px" are pixels of the full-resolution image unless stated otherwise.
    """

    # "hypotheses": the motion-hypothesis test below (the default); "learned": the same
    # evidence decided per pixel by a fitted classifier (`estimator.surround.pixel_classifier`)
    # instead of the score's threshold; "paper": the paper's
    # section 5 as written, eq. 22 thresholded, plan view, 1 x N closing, blobs, nearest
    # point (no height test, no refinement, no hidden-ground handling), a baseline
    method: str = DEFAULT_DETECTOR
    # temporal baseline and working resolution
    baseline_frames: int = 2  # [frames] the current frame is compared with the one n before
    scale: int = 2  # [-] working resolution = full / scale (1 or 2; pyrDown)
    # eq. 22 (kept for display: `DetectionFrame.normalized_difference`)
    nd_kernel_px: int = 7  # K: Gaussian averaging window of eq. 22 [px]
    nd_k: float = 50.0  # k: regulariser of eq. 22 [grey level^2]
    nd_threshold_px: float = 0.5  # [px] |eq. 22| (a normal flow) above which "paper" marks motion
    # motion hypotheses: lambda = h / (h - z) for static points at height z (road: 1)
    # static points at 0 .. ~1.3 m in steps of a quarter of the road's image motion
    # (finer steps near the road: periodic structure such as guard-rail posts must not
    # fit the moving hypothesis better than every static one by aliasing)
    static_lambdas: tuple[float, ...] = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)  # [-] incl. 1.0
    # moving points: fixed to the car (0) and driving forward slower than the ego car
    # (0 < lambda < 1: overtaken vehicles), in steps of a quarter of the road's motion
    moving_lambdas: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75)  # [-] must include 0.0
    window_px: float = 10.0  # [px] Gaussian window (K) of the residual energies
    energy_k: float = 40.0  # [grey level^2] noise floor of the score's denominator
    registration_sigma_px: float = 1.4  # [px] misregistration allowed on edges (aliasing)
    score_threshold: float = 0.5  # [-] m above which a pixel is independently moving
    # "learned": the classifier's file ("" the built-in one), p(vehicle) above which a pixel
    # is marked, and the neighbourhood whose score it sees [px, working scale]
    pixel_model: str = ""
    pixel_threshold: float = 0.7  # [-], 0..1
    context_px: int = 7  # [px], odd; as when the classifier was fitted
    border_margin_px: int = 12  # [px] margin inside the field of view's outer rim left out
    # margin along the inner edge (the car-body mask): at the body cone's edge 1 px is
    # ~0.25 m of road: a wide margin there hides the ground point of every vehicle nearby
    inner_margin_px: int = 4  # [px]
    coarse_level: bool = True  # [-] also score one pyramid level coarser
    # ego car (nearly) stopped: the static and co-moving hypotheses coincide (S ~ 0) and
    # m decides nothing; then a pixel that no static hypothesis explains is moving (the
    # paper's compensated difference, eq. 22): r = min_static E / (k + <|g|^2> sigma^2)
    still_displacement_m: float = 0.5  # [m] ego displacement over the baseline below this
    still_threshold: float = 1.0  # [-] r above which a pixel moves (ego stopped)
    # plan view and blobs
    plan_range_m: float = 45.0  # half-size of the plan view [m]
    m_per_px: float = 0.2  # plan-view resolution [m/px]
    gap_m: float = 5.0  # N: closing length along the direction of motion [m]
    min_blob_m2: float = 0.5  # smallest blob kept [m^2]
    cluster_m: float = 1.5  # blobs closer than this are one vehicle [m]
    max_range_m: float = 25.0  # detections farther than this are dropped [m]
    min_range_m: float = 0.0  # detections nearer than this are dropped [m]
    # obstacle map where the ground is hidden (car-body mask)
    # [m] a vehicle's moving part reaches at least this apparent height, 0.3..1.0 (the
    # motion test marks a vehicle at half the ego car's speed up to ~0.8 m only)
    min_height_m: float = 0.5
    # a blob is hidden when its nearest point sees a pixel this close to the analysed area's
    # inner edge (inner_margin_px off the car-body mask): ~0.6 m of road at the cone's edge
    hidden_margin_px: int = 3  # [px], 0..10
    hidden_range_frac: float = 0.6  # [-] without an arc to fit: placed at this fraction of it
    # a hidden vehicle is a box of this size along the ego car's heading, placed so that it
    # spans the bearings its blob spans at the edge (`estimator.surround.hidden`)
    hidden_box_m: tuple[float, float] = (4.7, 1.9)  # [m] (length, width) of a typical car
    # the motion mask reaches beyond a vehicle by about its window: each end of the arc
    # is moved in by this much, in image pixels along the edge
    hidden_arc_shrink_px: float = 25.0  # [px], 0..60
    # full-resolution refinement of the nearest point (the blob's lowest moving edge)
    refine: bool = True  # [-] refine each blob's nearest point at full resolution
    refine_radius_px: int = 24  # [px] half-size of the search window around the coarse point
    refine_threshold: float = 0.3  # [-] score m (3 x 3 window) of a moving edge pixel
    refine_weak_threshold: float = 0.1  # [-] m of an edge pixel linked to a moving one
    refine_min_gradient: float = 6.0  # [grey level/px] edge of the current frame
    refine_back_m: float = 3.0  # [m] the refined point may be this much nearer than the coarse
    # an edge that the road explains against the frame one step back is road the vehicle
    # uncovered before that frame (lane marks), not the vehicle's edge: left out
    refine_road_veto: bool = True  # [-]
    # the vehicle's lower contour (nearest moving edge per bearing bin) is fitted with
    # lines (its faces toward the camera) and the fit's nearest point taken: one pixel
    # is ~0.4 m of range at 15 m, about what a face seen nearly end-on changes in range
    # (rear face at 15 m, 11 deg: 0.5 m over its 2 m), so the argmin of single pixels
    # lands anywhere along that face (measured: ~1 m from its nearest corner)
    refine_bearing_bin_rad: float = 0.005  # [rad] bearing bin of the contour (~1 px at 15 m)
    refine_split_m: float = 0.75  # [m] contour split into faces beyond this from a chord
    # a vehicle's lowest visible edge is its body's lower edge, not the road: its ray
    # meets the road (h / (h - z_c)) farther than the vehicle (about 9 % at z_c = 0.16 m,
    # the simulator's cars; road cars: ~0.1-0.2 m); the obstacle-map range is scaled back
    vehicle_clearance_m: float = 0.15  # [m] z_c; 0 to take the nearest point on the road

    def __post_init__(self) -> None:
        if self.method not in DETECTOR_METHODS:
            raise ValueError(
                f"DetectorConfig.method must be one of {DETECTOR_METHODS}, got {self.method!r}"
            )
        if self.baseline_frames < 1 or self.scale not in (1, 2):
            raise ValueError(
                f"DetectorConfig: baseline_frames >= 1 and scale in (1, 2), got "
                f"{self.baseline_frames}, {self.scale}"
            )
        if 1.0 not in self.static_lambdas or 0.0 not in self.moving_lambdas:
            raise ValueError(
                "DetectorConfig: static_lambdas must contain 1.0 (the road) and "
                "moving_lambdas 0.0 (fixed to the car)"
            )
        if not 0.0 < self.pixel_threshold < 1.0:
            raise ValueError(
                f"DetectorConfig.pixel_threshold must be in (0, 1), got {self.pixel_threshold}"
            )
        if min(self.static_lambdas) < 1.0 or max(self.moving_lambdas) >= 1.0:
            raise ValueError("DetectorConfig: static lambdas are >= 1, moving ones < 1")


@dataclass
class Detection:
    """A detected vehicle: nearest road point (x fwd, y left) [m] in the ego road frame.

    hidden: the blob reaches the inner edge of the seen road (car-body mask), so
    only the bearing of the point is measured; x_m, y_m are on that bearing at an
    assumed range (see `DetectorConfig.hidden_range_frac`).
    score: motion score m at the blob's nearest point (working scale) [-].
    """

    x_m: float
    y_m: float
    area_m2: float
    bbox_plan: tuple[int, int, int, int]  # (col, row, width, height) in the plan view
    pixel: tuple[float, float] = (float("nan"), float("nan"))  # camera pixel of the point
    hidden: bool = False
    bearing_rad: float = float("nan")  # [rad] atan2(y, x) of the nearest point
    score: float = float("nan")
    height_m: float = float("nan")  # [m] apparent height h (1 - d_near / d_far) of the blob
    # the vehicle's box: a hidden one's from its bearings (`hidden_box`); a refined one's is
    # fitted to outline_xy once it is a vehicle's detection (`SurroundAnalyzer`); None: none
    box: Box | None = None
    outline_xy: np.ndarray | None = None  # (M, 2) [m] the lower outline the box was fitted to
    # the state of the track this candidate updated or started, after the frame's tracking
    # (`SurroundAnalyzer`, one of its `TRACK_STATES`); "": none (no tracker, or a birth refused)
    track_state: str = ""


class DetectionFrame:
    """Everything one frame of detection produced (kept for visualisation).

    detections: the vehicles reported (set by `estimator.surround.analyzer`: candidates
    that belong to a vehicle track); candidates: every blob of the frame.
    normalized_difference: (H, W) float32 eq. 22 on the road-compensated pair;
    motion_mask: (H, W) bool, pixels whose motion score passed (both computed at
    the working scale, when first read, and brought to full size); plan_mask:
    (S, S) uint8 after closing; score: (h, w) float32 motion score m at the
    working scale.
    """

    def __init__(
        self,
        detections: list[Detection],
        normalized_difference: np.ndarray | Callable[[], np.ndarray],
        motion_mask: np.ndarray,
        plan_mask: np.ndarray | None = None,
        candidates: list[Detection] | None = None,
        score: np.ndarray | None = None,
        full_size: tuple[int, int] | None = None,
    ) -> None:
        self.detections = detections
        self.candidates = candidates if candidates is not None else list(detections)
        self.plan_mask = plan_mask
        self.score = score
        self._nd, self._mask, self._size = normalized_difference, motion_mask, full_size

    @property
    def normalized_difference(self) -> np.ndarray:
        if callable(self._nd):  # computed when first read (it is only drawn)
            self._nd = self._nd()
        if self._size is not None and self._nd.shape[::-1] != self._size:
            self._nd = cv2.resize(self._nd, self._size, interpolation=cv2.INTER_LINEAR)
        return self._nd

    @property
    def motion_mask(self) -> np.ndarray:
        if self._size is not None and self._mask.shape[::-1] != self._size:
            self._mask = (
                cv2.resize(self._mask.astype(np.uint8), self._size, interpolation=cv2.INTER_NEAREST)
                > 0
            )
        return self._mask


def normalized_difference(
    current: np.ndarray,
    compensated_prev: np.ndarray,
    k: float,
    kernel_px: int,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Eq. 22 at every pixel: (H, W) float32, signed.

    current, compensated_prev: (H, W) grey images on the same pixel grid.
    """
    a = np.asarray(current, np.float32)
    b = np.asarray(compensated_prev, np.float32)
    mean = 0.5 * (a + b)
    gu = cv2.Sobel(mean, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gv = cv2.Sobel(mean, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    gt = a - b
    g2 = gu * gu + gv * gv
    num = gt * np.sqrt(g2)
    if valid is not None:
        num = np.where(valid, num, 0.0).astype(np.float32)
        g2 = np.where(valid, g2, 0.0).astype(np.float32)
    ksize = (kernel_px | 1, kernel_px | 1)
    sigma = kernel_px / 4.0
    # eq. 22: <g_t |g|> / (k + <g_u^2 + g_v^2>)
    return cv2.GaussianBlur(num, ksize, sigma) / (k + cv2.GaussianBlur(g2, ksize, sigma))


def hypothesis_homography(
    x: np.ndarray, K0: np.ndarray, n: np.ndarray, dt_s: float, lam: float
) -> np.ndarray:
    """(3, 3) ``H_lambda`` for one frame step: ``R + lambda D K^T`` (eq. 3-4).

    lam >= 1: a static point at height ``h (1 - 1/lam)`` (lam = 1: the road), with
    the camera's whole rotation R. lam < 1: a point moving with the car; its
    rotation is the camera's without the car's yaw (the component of W along the
    road normal n), i.e. the mount's vibration only.
    """
    return hypothesis_homographies(x, K0, n, dt_s, (lam,))[lam]


def hypothesis_homographies(
    x: np.ndarray, K0: np.ndarray, n: np.ndarray, dt_s: float, lams: Sequence[float]
) -> dict[float, np.ndarray]:
    """`hypothesis_homography` (3, 3) for each lambda of ``lams``: eq. 4's parts
    computed once for the step."""
    x = np.asarray(x, float)
    R, D, K = homography_parts(x, K0, dt_s)
    DK = np.outer(D, K)
    R_vib = None
    out = {}
    for lam in lams:
        if lam < 1.0:
            if R_vib is None:
                W = x[3:6]
                W_vib = W - (W @ n) * n
                R_vib = np.eye(3) - skew(W_vib) * dt_s
            out[lam] = R_vib + lam * DK
        else:
            out[lam] = R + lam * DK
    return out


class VehicleDetector:
    """Section 5 detector for one camera; lookups are built once."""

    def __init__(
        self,
        camera: CameraModel,
        mount: CameraMount,
        config: DetectorConfig | None = None,
        compensator: FrameCompensator | None = None,
    ) -> None:
        self.camera, self.mount = camera, mount
        self.cfg = cfg = config or DetectorConfig()
        self.comp = compensator or FrameCompensator(camera, mount)
        s = cfg.scale
        self.plan = PlanView.build(camera, mount, cfg.plan_range_m, cfg.m_per_px)
        # full-resolution field of view, with a margin (warps are not defined beyond it)
        # analysed area: the field of view less a margin (warps are not defined beyond
        # it, and the car body's edge, which moves with the camera, is smeared into its
        # neighbourhood by motion blur)
        self.valid = self._analysed_area(camera.valid_mask(), cfg)
        self.road_s = self.comp.road_mask(s)
        self.valid_s = (
            cv2.resize(
                self.valid.astype(np.uint8),
                self.road_s.shape[::-1],
                interpolation=cv2.INTER_NEAREST,
            )
            > 0
        )
        # plan cells -> pixels of the working scale
        self._pmx = ((self.plan.map_x + 0.5) / s - 0.5).astype(np.float32)
        self._pmy = ((self.plan.map_y + 0.5) / s - 0.5).astype(np.float32)
        self._pmx[self.plan.map_x < 0] = -1e4
        n = max(1, int(round(cfg.gap_m / cfg.m_per_px)))
        self._close_kernel = np.ones((n, 1), np.uint8)  # 1 x N along the direction of motion
        c = max(1, int(round(cfg.cluster_m / cfg.m_per_px)))
        self._cluster_kernel = np.ones((c, c), np.uint8)
        x, y = PlanView._grid(self.plan.range_m, self.plan.m_per_px, self.plan.size)
        self._plan_dist = np.hypot(x, y).astype(np.float32)
        self._plan_bearing = np.arctan2(y, x)
        self._inner = self._inner_edge()
        self._edge_px_per_rad = self._edge_pixel_density()  # (nb,) [px/rad] along the edge
        self._edge_cells = self._hidden_edge_cells()  # (S, S) bool: cells that see the edge
        self._n = self.comp.n
        self._lams = tuple(cfg.moving_lambdas) + tuple(cfg.static_lambdas)
        self._road_xy = pixel_road_xy(camera, mount)  # (H, W, 2) inverse perspective
        self._road_rng = np.hypot(self._road_xy[..., 0], self._road_xy[..., 1])
        self._rays = camera.pixel_rays()
        h = mount.height_m
        self._clearance_scale = (h - min(cfg.vehicle_clearance_m, 0.5 * h)) / h
        # the last `detect`'s seconds by stage: warps, score, blobs, refine
        self.clock = StageClock()
        # "learned": the pixel classifier and each working-scale pixel's log(1 + road range)
        self.classifier = (
            PixelClassifier.load(cfg.pixel_model or BUILTIN_MODEL)
            if cfg.method == "learned"
            else None
        )
        rng_s = cv2.resize(
            np.where(np.isfinite(self._road_rng), self._road_rng, 1e3).astype(np.float32),
            self.road_s.shape[::-1],
            interpolation=cv2.INTER_AREA,
        )
        self._log_range_s = np.log1p(np.minimum(rng_s, 1e3))
        # the last frame's (features (N, F) of its analysed pixels, in row-major order, and
        # those pixels (h, w) bool) when kept (fitting the classifier)
        self.keep_features = False
        self.last_features: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def analysed_area(self) -> np.ndarray:
        """(H, W) bool, full resolution: the pixels the motion test decides (the field of
        view less its margins, whose rays meet the road)."""
        return self.valid & self.comp.road

    @staticmethod
    def _analysed_area(valid: np.ndarray, cfg: DetectorConfig) -> np.ndarray:
        """(H, W) bool: the field of view less border_margin_px inside its outer rim and
        inner_margin_px around its holes (the car-body mask)."""
        v = np.asarray(valid, np.uint8)
        filled, hole = _fill_and_holes(v)
        outer = cv2.erode(
            filled, _square(cfg.border_margin_px), borderType=cv2.BORDER_CONSTANT, borderValue=0
        )
        inner = cv2.dilate(hole, _square(cfg.inner_margin_px))
        return (outer > 0) & (inner == 0) & (v > 0)

    def _inner_edge(self) -> np.ndarray:
        """(B,) range [m] of the nearest seen road cell per bearing bin (0.5 deg)."""
        nb = 720
        b = ((self._plan_bearing + np.pi) / (2 * np.pi) * nb).astype(int) % nb
        inner = np.full(nb, np.inf)
        seen = self.plan.seen.copy()
        u = np.clip(np.round(self.plan.map_x).astype(int), 0, self.valid.shape[1] - 1)
        v = np.clip(np.round(self.plan.map_y).astype(int), 0, self.valid.shape[0] - 1)
        seen &= self.valid[v, u]
        np.minimum.at(inner, b[seen], self._plan_dist[seen])
        return inner

    def _hidden_edge_cells(self) -> np.ndarray:
        """(S, S) bool: plan cells whose pixel lies within inner_margin_px +
        hidden_margin_px of the car-body mask (the holes of the field of view), where a
        blob's nearest point says that the vehicle goes on behind the body."""
        _, hole = _fill_and_holes(np.asarray(self.camera.valid_mask(), np.uint8))
        r = self.cfg.inner_margin_px + self.cfg.hidden_margin_px
        near = cv2.dilate(hole, _square(r)) > 0
        mx, my = self.plan.map_x, self.plan.map_y
        u = np.clip(np.round(mx).astype(int), 0, near.shape[1] - 1)
        w = np.clip(np.round(my).astype(int), 0, near.shape[0] - 1)
        return near[w, u] & (mx >= 0)

    def _edge_pixel_density(self) -> np.ndarray:
        """(nb,) image pixels per radian of bearing along the inner edge (per bin of
        `_inner`; 0 where the edge is not seen)."""
        nb = len(self._inner)
        beta = (np.arange(nb) + 0.5) / nb * 2 * np.pi - np.pi
        seen = np.isfinite(self._inner)
        r = np.where(seen, self._inner, 0.0)
        xy = r[:, None] * np.stack([np.cos(beta), np.sin(beta)], axis=1)
        cr = np.round(self.plan.to_pixel(xy)).astype(int)
        S = self.plan.size
        ok = seen & np.all((cr >= 0) & (cr < S), axis=1)
        cr = np.clip(cr, 0, S - 1)
        pix = np.stack(
            [self.plan.map_x[cr[:, 1], cr[:, 0]], self.plan.map_y[cr[:, 1], cr[:, 0]]], 1
        )
        ok &= pix[:, 0] >= 0
        step = np.linalg.norm(np.roll(pix, -1, axis=0) - np.roll(pix, 1, axis=0), axis=1)
        ok &= np.roll(ok, -1) & np.roll(ok, 1)
        dens = np.where(ok, step / (2 * (2 * np.pi / nb)), np.nan)
        # the edge is jagged bin to bin: a median over +-5 deg of bearing
        k = max(1, nb // 72)
        windows = np.stack([np.roll(dens, j) for j in range(-k, k + 1)], axis=1)
        with np.errstate(all="ignore"):
            smooth = np.nanmedian(windows, axis=1)
        return np.where(np.isfinite(smooth), smooth, 0.0)

    def _edge_bin(self, bearing_rad: float) -> int:
        """Index of the bearing's bin in `_inner` (and `_edge_px_per_rad`)."""
        nb = len(self._inner)
        return int((bearing_rad + np.pi) / (2 * np.pi) * nb) % nb

    def inner_edge_range(self, bearing_rad: float) -> float:
        return float(self._inner[self._edge_bin(bearing_rad)])

    # ------------------------------------------------------------------ images
    def prepare(self, gray: np.ndarray) -> np.ndarray:
        """(h, w) float32 image at the working scale from a full-resolution grey image."""
        g = np.asarray(gray, np.float32)
        return cv2.pyrDown(g) if self.cfg.scale == 2 else g

    def detect(
        self,
        current: np.ndarray,
        earlier: np.ndarray,
        steps: Sequence[tuple[np.ndarray, float]],
        current_full: np.ndarray | None = None,
        earlier_full: np.ndarray | None = None,
        vehicle_mask: np.ndarray | None = None,
        middle_full: np.ndarray | None = None,
    ) -> DetectionFrame:
        """Detect in ``current`` against ``earlier`` (both from `prepare`).

        steps: the per-frame (x (9,), dt [s]) from the earlier frame to the current
        one, oldest first (x: the paper's state, docs/CONVENTIONS.md).
        current_full, earlier_full: the same frames at full resolution (grey), for the
        refinement of the nearest points (skipped without them).
        vehicle_mask: (H, W) bool, full resolution: the pixels that see a vehicle, given
        instead of the motion test (a diagnostic: with the true mask, what the plan view,
        the obstacle map and the tracker reach with a perfect segmentation).
        middle_full: the frame one step before the current one (full resolution, grey;
        with two or more steps): the refinement's road veto (`_refine`).
        """
        cfg = self.cfg
        s = cfg.scale
        K0, n = self.comp.K0, self._n
        self.clock.start()
        # 1. warp the earlier frame with every hypothesis
        warped: dict[float, np.ndarray] = {}
        Hs: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        ok = self.road_s & self.valid_s
        paper = cfg.method == "paper"
        lams = (1.0,) if paper else self._lams
        per_step = [hypothesis_homographies(x, K0, n, dt, lams) for x, dt in steps]
        for lam in lams:
            H = np.eye(3)
            for Hk in per_step:
                H = Hk[lam] @ H
            key = lam in (0.0, 1.0)
            mx, my = self.comp.maps_h(H, s, exact_horizon=key)
            Hs[lam] = (mx, my)  # kept for the full-resolution refinement
            warped[lam] = cv2.remap(
                earlier, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0
            )
            if key:
                ok &= self.comp.sampled_in_view(mx, my, s)
        a = np.asarray(current, np.float32)
        self.clock.lap("warps")
        if paper:
            return self._detect_paper(a, warped[1.0], ok)
        # the road's map from the current frame to the one a step back (the road veto)
        middle = None
        if cfg.refine_road_veto and middle_full is not None and len(steps) > 1:
            x, dt = steps[-1]
            H1 = hypothesis_homography(x, K0, n, dt, 1.0)
            middle = (np.asarray(middle_full, np.float32), self.comp.maps_h(H1, s, True))
        # 2. motion score at the working scale and one level coarser
        K = cfg.window_px / s
        sigma = cfg.registration_sigma_px / s
        if vehicle_mask is not None:
            return self._detect_given(a, vehicle_mask, ok, current_full, earlier_full, Hs)
        learned = cfg.method == "learned"
        features = learned or self.keep_features
        # the pixel classifier's evidence: the energies the scores compute, kept
        fine_e, coarse_e = (Energies(), Energies()) if features else (None, None)
        score = self._score(a, warped, ok, K, cfg.energy_k, sigma, keep=fine_e)
        fine_score = score
        moving = (score > cfg.score_threshold) & ok
        # ego (nearly) stopped: no static hypothesis explains the pixel (eq. 22's test)
        disp_m = sum(float(np.linalg.norm(np.asarray(x, float)[:3])) * dt for x, dt in steps)
        still = np.zeros_like(ok)
        if disp_m < cfg.still_displacement_m:
            r = self._static_residual(a, warped, ok, K, cfg.energy_k, sigma)
            still = (r > cfg.still_threshold) & ok
            moving |= still
            score = np.maximum(score, r * (cfg.score_threshold / cfg.still_threshold))
        if cfg.coarse_level or features:
            ac = cv2.pyrDown(a)
            okc = (
                cv2.erode(
                    cv2.resize(
                        ok.astype(np.uint8),
                        (ac.shape[1], ac.shape[0]),
                        interpolation=cv2.INTER_NEAREST,
                    ),
                    np.ones((3, 3), np.uint8),
                )
                > 0
            )
            wc = {lam: cv2.pyrDown(w) for lam, w in warped.items()}
            sc = self._score(ac, wc, okc, max(3.0, K / 2), cfg.energy_k, sigma / 2, keep=coarse_e)
            up = cv2.resize(sc, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_LINEAR)
            if cfg.coarse_level:
                moving |= (up > cfg.score_threshold) & ok
                score = np.maximum(score, up)
        if features:
            planes = pixel_features(
                level_features(a, fine_e, K, cfg.energy_k, sigma),
                [
                    cv2.resize(f, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_LINEAR)
                    for f in level_features(ac, coarse_e, max(3.0, K / 2), cfg.energy_k, sigma / 2)
                ],
                fine_score,
                up,
                self._log_range_s,
                cfg.context_px,
            )
            index = np.flatnonzero(ok)
            X = gather(planes, index)  # (N, F): the analysed pixels' features
            self.last_features = (X, ok)
        if learned:
            # p > pixel_threshold, as log-odds
            cut = math.log(cfg.pixel_threshold / (1.0 - cfg.pixel_threshold))
            marked = np.zeros(ok.size, bool)
            marked[index] = self.classifier.logit(X) > cut
            moving = marked.reshape(ok.shape) | still
        self.clock.lap("score")
        # 3. plan view, closing along the motion, blobs, obstacle map
        plan, cands = self._candidates(moving, score, current_full, earlier_full, Hs, middle=middle)
        # 4. full-resolution pictures (display)
        w1 = warped[1.0]

        def nd() -> np.ndarray:  # eq. 22 on the road-compensated pair, for display
            return normalized_difference(a, w1, cfg.nd_k, max(3, cfg.nd_kernel_px // s), ok)

        return DetectionFrame(
            list(cands), nd, moving, plan, cands, score, (self.camera.width, self.camera.height)
        )

    def _detect_given(
        self,
        a: np.ndarray,
        vehicle_mask: np.ndarray,
        ok: np.ndarray,
        current_full: np.ndarray | None,
        earlier_full: np.ndarray | None,
        maps: dict[float, tuple[np.ndarray, np.ndarray]],
    ) -> DetectionFrame:
        """Steps 3-4 of `detect` on a given full-resolution vehicle mask (H, W) bool; the
        refinement takes the mask's own lower outline (every masked pixel is an edge that
        moves)."""
        full = np.asarray(vehicle_mask, bool)
        moving = (
            cv2.resize(full.astype(np.uint8), a.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
        ) & ok
        score = moving.astype(np.float32)
        plan, cands = self._candidates(moving, score, current_full, earlier_full, maps, full)
        return DetectionFrame(
            list(cands),
            lambda: score,
            moving,
            plan,
            cands,
            score,
            (self.camera.width, self.camera.height),
        )

    def _candidates(
        self,
        moving: np.ndarray,
        score: np.ndarray,
        current_full: np.ndarray | None,
        earlier_full: np.ndarray | None,
        maps: dict[float, tuple[np.ndarray, np.ndarray]],
        given: np.ndarray | None = None,
        middle: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> tuple[np.ndarray, list[Detection]]:
        """(plan mask after closing, candidates) of a working-scale motion mask: the plan
        view, its tall parts, the 1 x N closing, blobs, their scores, the full-resolution
        refinement (on a ``given`` vehicle mask's outline, if any; ``middle``: the frame a
        step back and the road's map to it, for the road veto) and the range filter."""
        plan = self._plan_mask(moving)
        tall = self._tall_parts(plan)
        plan = cv2.morphologyEx(plan, cv2.MORPH_CLOSE, self._close_kernel)
        cands = self._blobs(plan, tall)
        self._set_scores(cands, score)
        self.clock.lap("blobs")
        if self.cfg.refine and current_full is not None and earlier_full is not None:
            near = cv2.dilate(moving.astype(np.uint8), np.ones((3, 3), np.uint8))
            cur = np.asarray(current_full, np.float32)
            early = np.asarray(earlier_full, np.float32)
            for c in cands:
                if not c.hidden:
                    self._refine(c, cur, early, maps, near, given=given, middle=middle)
        cands = self._in_range_merged(cands)
        self.clock.lap("refine")
        return plan, cands

    def _detect_paper(self, a: np.ndarray, w1: np.ndarray, ok: np.ndarray) -> DetectionFrame:
        """Section 5 as the paper writes it: the road-compensated difference (eq. 22)
        thresholded, the flat-plane transform, a 1 x N closing, blobs, and each blob's
        point nearest the camera taken as on the road."""
        cfg = self.cfg
        ndv = normalized_difference(a, w1, cfg.nd_k, max(3, cfg.nd_kernel_px // cfg.scale), ok)
        moving = (np.abs(ndv) > cfg.nd_threshold_px) & ok
        plan = cv2.morphologyEx(self._plan_mask(moving), cv2.MORPH_CLOSE, self._close_kernel)
        cands = self._blobs(plan, None, obstacle_map_only=True)
        score = np.abs(ndv) * (cfg.score_threshold / cfg.nd_threshold_px)
        self._set_scores(cands, score)
        cands = self._in_range_merged(cands)
        return DetectionFrame(
            list(cands),
            lambda: ndv,
            moving,
            plan,
            cands,
            score,
            (self.camera.width, self.camera.height),
        )

    def _plan_mask(self, moving: np.ndarray) -> np.ndarray:
        """(S, S) uint8 plan view (flat-plane transform) of a working-scale motion mask."""
        return cv2.remap(
            moving.astype(np.uint8) * 255,
            self._pmx,
            self._pmy,
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )

    def _set_scores(self, cands: list[Detection], score: np.ndarray) -> None:
        """Each candidate's score: the working-scale score (h, w) at its nearest point."""
        s = self.cfg.scale
        for c in cands:
            qu = int(np.clip(round((c.pixel[0] + 0.5) / s - 0.5), 0, score.shape[1] - 1))
            qv = int(np.clip(round((c.pixel[1] + 0.5) / s - 0.5), 0, score.shape[0] - 1))
            c.score = float(score[qv, qu])

    def _in_range_merged(self, cands: list[Detection]) -> list[Detection]:
        """The candidates within min_range_m..max_range_m, those of one vehicle merged."""
        cfg = self.cfg
        near = [
            c for c in cands if cfg.min_range_m <= float(np.hypot(c.x_m, c.y_m)) <= cfg.max_range_m
        ]
        return self._merge_close(near)

    def _merge_close(self, cands: list[Detection]) -> list[Detection]:
        """One detection per vehicle: points within cluster_m (after refinement, two
        blobs of one vehicle can end on the same edge) are merged into the larger."""
        out: list[Detection] = []
        for c in sorted(cands, key=lambda d: -d.area_m2):
            for o in out:
                if math.hypot(c.x_m - o.x_m, c.y_m - o.y_m) <= self.cfg.cluster_m:
                    o.area_m2 += c.area_m2
                    break
            else:
                out.append(c)
        return out

    def _refine(
        self,
        det: Detection,
        cur: np.ndarray,
        early: np.ndarray,
        maps: dict[float, tuple[np.ndarray, np.ndarray]],
        near_moving: np.ndarray,
        given: np.ndarray | None = None,
        middle: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> None:
        """Move the detection to the nearest full-resolution edge that moves independently.

        The working-scale score is smoothed over ~10 px and, for a vehicle ahead,
        also lights up the road strip it uncovered since the earlier frame (the
        disocclusion, as long as the ego car's displacement over the baseline).
        Here, in a window around the coarse nearest point, the score is computed
        again at full resolution with a 3 x 3 window and kept only on edges of the
        current frame (the uncovered road has none). Of those pixels (not nearer
        than refine_back_m before the coarse point), the nearest per bearing bin form
        the vehicle's lower contour on the road; the nearest point of its line fit
        (`estimator.surround.outline.nearest_on_contour`) is the refined obstacle-map point.

        Road veto (``middle``: the frame one step back, grey, and the road's working-scale
        maps to it): the road a vehicle driving away uncovered over the baseline lights up
        with it, and its lane marks are edges of the current frame; but the part uncovered
        before the last step was seen in the frame a step back, where the road hypothesis
        explains it. An edge pixel whose 3 x 3 residual against that road-compensated frame
        is within the floor (k + <|g|^2> sigma^2) is left out: the refined point is the
        vehicle's own edge, or the detection stays unrefined (the tracker's swept
        measurement, `estimator.surround.tracking`).
        """
        cfg = self.cfg
        H_img, W_img = cur.shape
        u0, v0 = det.pixel
        if not (np.isfinite(u0) and np.isfinite(v0)):
            return
        R = cfg.refine_radius_px
        c0, c1 = max(0, int(u0) - R), min(W_img, int(u0) + R + 1)
        r0, r1 = max(0, int(v0) - R), min(H_img, int(v0) + R + 1)
        if c1 - c0 < 3 or r1 - r0 < 3:
            return
        a = cur[r0:r1, c0:c1]
        s = self.cfg.scale
        shape = a.shape
        # full-resolution maps of the window, interpolated from the working-scale ones
        # (a pixel q of scale s is the full-resolution pixel (q + 0.5) s - 0.5)
        vv, uu = np.mgrid[r0:r1, c0:c1].astype(np.float32)
        qu, qv = (uu + 0.5) / s - 0.5, (vv + 0.5) / s - 0.5
        warped = {lam: _warp_window(early, mxy, qu, qv, s) for lam, mxy in maps.items()}
        ok = np.ones(shape, bool)
        if given is not None:  # a given vehicle mask: its pixels are the moving edges
            m = given[r0:r1, c0:c1].astype(np.float32)
            edge = np.ones(shape, bool)
        else:
            m = self._score(a, warped, ok, 3.0, cfg.energy_k, cfg.registration_sigma_px, box=True)
            gu = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3) / 8.0
            gv = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3) / 8.0
            edge = (gu * gu + gv * gv) >= cfg.refine_min_gradient**2
        # within the working-scale moving region (dilated), and a road ray
        mov = (
            cv2.remap(
                near_moving,
                qu,
                qv,
                cv2.INTER_NEAREST,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0,
            )
            > 0
        )
        rng = self._road_rng[r0:r1, c0:c1]
        coarse = float(np.hypot(det.x_m, det.y_m))
        cand = edge & mov & np.isfinite(rng) & (rng >= coarse - cfg.refine_back_m)
        if middle is not None and given is None:
            road = _warp_window(middle[0], middle[1], qu, qv, s)
            cand &= ~self._road_explained(a, gu, gv, road)
        strong = cand & (m > cfg.refine_threshold)
        if not strong.any():
            return
        # hysteresis (as Canny's edge linking): weaker moving edge pixels connected to a
        # strong one belong to the same edge (a lower edge's end towards a face seen along
        # the flow, e.g. the rear corner of a car alongside, scores low: aperture problem);
        # they extend the contour only at bearings where no strong pixel is (road marks
        # and shadows linked to the vehicle's edge must not pull it nearer)
        weak = cand & (m > cfg.refine_weak_threshold)
        n_lab, lab = cv2.connectedComponents(weak.astype(np.uint8), connectivity=8)
        keep = np.zeros(n_lab, bool)
        keep[np.unique(lab[strong])] = True
        keep[0] = False
        sel = keep[lab]
        rows, cols = np.nonzero(sel)
        xy_px = self._road_xy[r0 + rows, c0 + cols].astype(float)
        outline, bins = lower_outline(xy_px, cfg.refine_bearing_bin_rad, ~strong[rows, cols])
        xy = nearest_on_outline(outline, bins, cfg.refine_split_m)
        # the camera pixel of the reported point: the contour pixel nearest to it
        i = int(np.argmin(np.hypot(*(xy_px - xy).T)))
        xy = xy * self._clearance_scale
        det.outline_xy = outline * self._clearance_scale  # the box: `SurroundAnalyzer`
        det.x_m, det.y_m = float(xy[0]), float(xy[1])
        det.pixel = (float(c0 + cols[i]), float(r0 + rows[i]))
        det.bearing_rad = float(np.arctan2(xy[1], xy[0]))

    def _road_explained(
        self, a: np.ndarray, gu: np.ndarray, gv: np.ndarray, road: np.ndarray
    ) -> np.ndarray:
        """(h, w) bool over a full-resolution window ``a`` (gradients gu, gv [grey
        level/px]): the road-compensated frame a step back, ``road`` (`_warp_window`),
        explains the pixel, ``<(a - I_road)^2> <= k + <|g|^2> sigma^2`` (3 x 3)."""
        cfg = self.cfg
        d = a - road
        residual = cv2.blur(d * d, (3, 3))
        floor = cfg.energy_k + cv2.blur(gu * gu + gv * gv, (3, 3)) * cfg.registration_sigma_px**2
        return residual <= floor

    @staticmethod
    def _energies(
        a: np.ndarray,
        warped: dict[float, np.ndarray],
        okf: np.ndarray,
        K: float,
        box: bool,
        keep: Energies | None = None,
    ) -> tuple[np.ndarray, np.ndarray, Callable]:
        """(min static E, <|g|^2>, the window average) over okf (float32 0/1 mask).

        E_lambda = <(a - I_lambda)^2> over the static hypotheses (lambda >= 1); <.>:
        Gaussian window K [px] (``box``: a K x K box). ``keep``: filled with each E_lambda
        and <|g|^2>.
        """
        kk = int(K)

        def avg(z: np.ndarray) -> np.ndarray:
            return cv2.blur(z, (kk, kk)) if box else gauss_window(z, K)

        E_sta = None
        for lam, w in warped.items():
            if lam >= 1.0:
                e = avg(_masked_sq(a, w, okf))
                if E_sta is None:  # (a copy where e is kept: the minimum is taken in place)
                    E_sta = e if keep is None else e.copy()
                else:
                    np.minimum(E_sta, e, out=E_sta)
                if keep is not None:
                    keep.E[lam] = e
        G2 = avg(gradient_sq(a) * okf)
        if keep is not None:
            keep.G2 = G2
        return E_sta, G2, avg

    @staticmethod
    def _score(
        a: np.ndarray,
        warped: dict[float, np.ndarray],
        ok: np.ndarray,
        K: float,
        k: float,
        sigma: float,
        box: bool = False,
        keep: Energies | None = None,
    ) -> np.ndarray:
        """m = max_j (min_static E - E_j) / (S_j + k + <|g|^2> sigma^2), 0 outside ok.

        j: the moving hypotheses; S_j = <(I_1 - I_j)^2>, how different the road's and
        hypothesis j's predictions are. A hypothesis between the car and the road
        (0 < lambda_j < 1) counts only where S_j >= k + <|g|^2> sigma^2: where it
        predicts what the road does within noise and misregistration, it decides nothing.
        <.>: Gaussian window K [px] (``box``: a K x K box). ``keep``: filled with every
        E_lambda, S_j and <|g|^2> (the pixel classifier's evidence).
        """
        okf = ok.astype(np.float32)
        E_sta, G2, avg = VehicleDetector._energies(a, warped, okf, K, box, keep)
        floor = k + G2 * (sigma * sigma)
        m = None
        for lam, w in warped.items():
            if lam >= 1.0:
                continue
            S_j = avg(_masked_sq(warped[1.0], w, okf))  # road against hypothesis j
            E_j = avg(_masked_sq(a, w, okf))
            if keep is not None:
                keep.E[lam], keep.S[lam] = E_j, S_j
            m_j = np.subtract(E_sta, E_j)
            np.divide(m_j, S_j + floor, out=m_j)
            if lam > 0.0:  # decided only where its prediction and the road's differ
                m_j[S_j < floor] = -1.0  # by more than the floor (noise, misregistration)
            m = m_j if m is None else np.maximum(m, m_j, out=m)
        m[~ok] = 0.0
        return m

    @staticmethod
    def _static_residual(
        a: np.ndarray,
        warped: dict[float, np.ndarray],
        ok: np.ndarray,
        K: float,
        k: float,
        sigma: float,
    ) -> np.ndarray:
        """r = min_static E / (k + <|g|^2> sigma^2), 0 outside ok (Gaussian window K [px])."""
        E_sta, G2, _ = VehicleDetector._energies(a, warped, ok.astype(np.float32), K, box=False)
        r = E_sta / (k + G2 * sigma * sigma)
        r[~ok] = 0.0
        return r

    def _label_extent(
        self, labels: np.ndarray, n: int, nz: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per label 0..n-1: nearest and farthest plan distance [m] and the flat index
        of the nearest cell (-1 for labels without cells). Works on the labelled
        cells only (few), not the whole plan; nz: their flat indices, ascending, if known
        (cells left out of nz are left out of the extents)."""
        if nz is None:
            nz = np.flatnonzero(labels)
        lab = labels.ravel()[nz]
        d = self._plan_dist.ravel()[nz]
        near = np.full(n, np.inf)
        far = np.zeros(n)
        cell = np.full(n, -1)
        if len(nz):
            order = np.argsort(lab, kind="stable")  # by label, cells in flat order within
            lab_o, d_o = lab[order], d[order]
            start = np.flatnonzero(np.r_[True, lab_o[1:] != lab_o[:-1]])
            lo = np.minimum.reduceat(d_o, start)
            near[lab_o[start]] = lo
            far[lab_o[start]] = np.maximum.reduceat(d_o, start)
            # each label's first cell (in flat order) at its nearest distance
            seg = np.repeat(np.arange(len(start)), np.diff(np.r_[start, len(d_o)]))
            at = np.flatnonzero(d_o == lo[seg])
            first = at[np.r_[True, seg[at][1:] != seg[at][:-1]]]
            cell[lab_o[first]] = nz[order[first]]
        return near, far, cell

    def _tall_parts(self, plan: np.ndarray) -> np.ndarray:
        """Plan mask (S, S) uint8 keeping the connected parts that reach min_height_m.

        In the flat-plane transform a point at height z seen at ground range d is
        drawn at ``d h / (h - z)``: a part spanning ranges d_near..d_far reaches the
        apparent height ``h (1 - d_near / d_far)``. Parts lower than a vehicle (posts,
        aliased road marks) are dropped before the closing, so that they neither
        join a vehicle's blob nor move its nearest point.
        """
        seen = plan > 0
        n, labels = cv2.connectedComponents(seen.view(np.uint8), connectivity=8)
        if n <= 1:
            return plan
        nz = np.flatnonzero(seen)  # (on bool: numpy's fast path, ~10x that on integers)
        near, far, _ = self._label_extent(labels, n, nz)
        height = self.mount.height_m * (1.0 - near / np.maximum(far, 1e-6))
        keep = height >= self.cfg.min_height_m
        out = np.zeros(plan.shape, np.uint8)
        out.ravel()[nz[keep[labels.ravel()[nz]]]] = 255
        return out

    def _blobs(
        self, plan: np.ndarray, tall: np.ndarray | None = None, obstacle_map_only: bool = False
    ) -> list[Detection]:
        """Candidates of the plan mask's blobs (clustered); obstacle_map_only: each blob's
        nearest cell as it is (no hidden-ground handling, no height test: the paper's)."""
        cfg = self.cfg
        # (areas, extents and boxes from the few cells of the blobs, not the whole plan view)
        seen = plan > 0
        n, labels = cv2.connectedComponents(seen.view(np.uint8), connectivity=8)
        cells = np.flatnonzero(seen)  # (on bool: numpy's fast path)
        cell_labels = labels.ravel()[cells]
        px_area = cfg.m_per_px**2
        keep = np.bincount(cell_labels, minlength=n) * px_area >= cfg.min_blob_m2
        keep[0] = False
        if not keep.any():
            return []
        nz = cells[keep[cell_labels]]  # the kept blobs' cells, ascending
        kept = np.zeros(plan.shape, np.uint8)
        kept.ravel()[nz] = 1
        # nearby blobs are clustered: components of the dilated mask
        grown = cv2.dilate(kept, self._cluster_kernel)
        m, groups = cv2.connectedComponents(grown, connectivity=8)
        flat = groups.ravel()  # read at the kept cells only (the growth is not a group's)
        counts = np.bincount(flat[nz], minlength=m)
        idx = np.arange(1, m)
        _, far, cell = self._label_extent(groups, m, nz)
        # nearest cell of each group, from its tall parts
        if tall is not None:
            _, _, cell_t = self._label_extent(groups, m, nz[tall.ravel()[nz] > 0])
            # a group without a part that reaches min_height_m is low structure only
            # (guard-rail posts closed into a strip along the road): not a vehicle
            cell = cell_t
        nz_lab = flat[nz]
        boxes = _label_boxes(nz, nz_lab, m, plan.shape[1])
        nz_edge = self._edge_cells.ravel()[nz]
        # cells of the group's tall parts (the vehicle, not low structure it was closed with)
        nz_tall = (tall.ravel()[nz] > 0) if tall is not None else np.ones(len(nz), bool)
        out: list[Detection] = []
        for g in idx:
            if counts[g] == 0 or cell[g] < 0:
                continue
            r, c = divmod(int(cell[g]), plan.shape[1])
            xy = self.plan.to_road(np.array([r]), np.array([c]))[0]
            rng = float(np.hypot(*xy))
            bearing = float(np.arctan2(xy[1], xy[0]))
            hidden = bool(self._edge_cells[r, c])
            box = None
            # apparent height: a point at height z, range d is drawn at d h / (h - z)
            height = self.mount.height_m * (1.0 - rng / max(far[g], rng))
            if obstacle_map_only:
                hidden, height = False, float("inf")
            if hidden:
                # the blob meets the inner edge along an arc: its middle is the bearing;
                # the arc of its tall parts where they reach the edge (low structure, e.g.
                # guard-rail posts closed into the blob, would pull it along the rail)
                edge_g = (nz_lab == g) & nz_edge
                tall_g = edge_g & nz_tall
                sel = nz[tall_g] if tall_g.any() else nz[edge_g]
                edge_r = self.inner_edge_range(bearing)
                xy = None
                if len(sel):
                    b = self._plan_bearing.ravel()[sel]
                    bearing = float(np.arctan2(np.sin(b).mean(), np.cos(b).mean()))
                    rel = np.angle(np.exp(1j * (b - bearing)))
                    edge_r = self.inner_edge_range(bearing)
                    dens = self._edge_px_per_rad[self._edge_bin(bearing)]
                    shrink = cfg.hidden_arc_shrink_px / dens if dens > 0 else 0.0
                    fit = hidden_box(
                        bearing + rel.min() + shrink,
                        bearing + rel.max() - shrink,
                        edge_r,
                        cfg.hidden_box_m,
                    )
                    if fit is not None:
                        xy = fit[2:]
                        L, W = cfg.hidden_box_m
                        box = Box(float(fit[0]), float(fit[1]), 0.0, L, W, float("nan"))
                if xy is None:
                    xy = (
                        cfg.hidden_range_frac
                        * edge_r
                        * np.array([np.cos(bearing), np.sin(bearing)])
                    )
                rng = float(np.hypot(*xy))
            # range: checked again on the final (refined) point
            if rng > cfg.max_range_m + 5.0 or height < cfg.min_height_m:
                continue
            bbox = tuple(int(v) for v in boxes[g])
            pix = (float(self.plan.map_x[r, c]), float(self.plan.map_y[r, c]))
            out.append(
                Detection(
                    float(xy[0]),
                    float(xy[1]),
                    float(counts[g] * px_area),
                    bbox,
                    pix,
                    bool(hidden),
                    bearing,
                    float("nan"),
                    float(height),
                    box,
                )
            )
        return out


def _masked_sq(a: np.ndarray, b: np.ndarray, okf: np.ndarray) -> np.ndarray:
    """(h, w) float32 ((a - b) okf)^2 for images a, b and a 0/1 mask okf (h, w), in one
    buffer."""
    d = np.subtract(a, b)
    d *= okf
    d *= d
    return d


def _warp_window(
    frame: np.ndarray,
    maps: tuple[np.ndarray, np.ndarray],
    qu: np.ndarray,
    qv: np.ndarray,
    scale: int,
) -> np.ndarray:
    """(h, w) float32: the full-resolution ``frame`` warped onto a window of the current
    frame whose pixels are (qu, qv) (h, w) at the working scale, by the working-scale
    ``maps`` (`FrameCompensator.maps_h`), interpolated to full resolution (a pixel q of
    scale s is the full-resolution pixel (q + 0.5) s - 0.5)."""
    mx, my = maps
    fx = cv2.remap(mx, qu, qv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    fy = cv2.remap(my, qu, qv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    for f in (fx, fy):  # to full-resolution pixels, (f + 0.5) scale - 0.5, in place
        f += 0.5
        f *= scale
        f -= 0.5
    return cv2.remap(frame, fx, fy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _fill_and_holes(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(filled, holes), (H, W) uint8 0/1, of a field of view (H, W) uint8 0/1: the view
    with its holes filled, and the holes alone (the car-body mask)."""
    filled = ndimage.binary_fill_holes(valid > 0).astype(np.uint8)
    return filled, filled & (1 - valid)


def _square(r_px: int) -> np.ndarray:
    """(2r + 1, 2r + 1) uint8 structuring element reaching r_px [px] (0 or more)."""
    return np.ones((2 * max(0, int(r_px)) + 1,) * 2, np.uint8)


def _label_boxes(cells: np.ndarray, labels: np.ndarray, n: int, width: int) -> np.ndarray:
    """(n, 4) int bounding box (x, y, w, h) [cells] of each label 0..n-1 from its cells'
    flat indices in a grid ``width`` wide (zeros for labels without cells)."""
    rows, cols = np.divmod(cells, width)
    lo_r, lo_c = np.full(n, np.iinfo(np.int64).max), np.full(n, np.iinfo(np.int64).max)
    hi_r, hi_c = np.full(n, -1), np.full(n, -1)
    np.minimum.at(lo_r, labels, rows)
    np.minimum.at(lo_c, labels, cols)
    np.maximum.at(hi_r, labels, rows)
    np.maximum.at(hi_c, labels, cols)
    seen = hi_r >= 0
    out = np.zeros((n, 4), np.int64)
    out[seen] = np.stack([lo_c, lo_r, hi_c - lo_c + 1, hi_r - lo_r + 1], axis=1)[seen]
    return out
