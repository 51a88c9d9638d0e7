"""Ground-truth metrics of vehicle detection, tracking and localisation (paper section 5).

Per frame the caller gives the ground-truth vehicles of the evaluation set (what
the detector could and should see, already filtered) as road-plane footprints in
the ego road frame (x forward, y left, origin on the road under the camera
viewpoint, docs/CONVENTIONS.md), and the hypotheses (id, x, y): track or
detection points in the same frame.

Matching ("nearest-point convention"). The detector reports a vehicle's ground
point nearest to the camera, which lies on the edge of its footprint. A
hypothesis matches a vehicle when its distance to the footprint polygon (0 inside)
is at most ``gate_m`` (`MetricsConfig`). Pairs beyond the gate never match.

- detection: per frame, optimal assignment (`scipy.optimize.linear_sum_assignment`,
  most pairs first, then least total distance) of hypotheses to vehicles under
  the gate. recall = matched / gt_count, precision = matched / hypothesis count.
- tracking: motmetrics (MOTA, IDF1, id switches) from a ``MOTAccumulator`` fed
  with the footprint distances, NaN beyond the gate. The matrix is built here
  with numpy: ``motmetrics.distances.norm2squared_matrix`` calls ``np.asfarray``,
  removed in NumPy 2 (docs/INSTALL.md).
- HOTA: ``trackeval.metrics.HOTA().eval_sequence`` on a data dict built here,
  similarity ``max(0, 1 - d / gate_m)`` (1 on or inside the footprint, 0 at the
  gate); reported as the mean of HOTA over its alpha thresholds 0.05 ... 0.95.
  A pair with similarity below alpha does not match at that alpha, so a
  hypothesis d from the footprint counts at the alphas <= 1 - d / gate_m.
- box HOTA (``hota_box``, ``deta_box``, ``assa_box``): the same, with similarity the
  IoU of plan-view axis-aligned boxes (`plan_box_xywh`): the vehicle's footprint's
  and the hypothesis' box's, computed as TrackEval's ``MotChallenge2DBox`` computes
  it (`box_iou_xywh`), so that TrackEval run on the MOT files of `scenarios.mot`
  reproduces it. Only hypotheses with a box take part (the others are left out, as
  they are of the MOT files).
- localisation: for each detection-matched pair, the distance from the
  hypothesis to the vehicle's footprint point nearest to the camera (the point
  the detector is supposed to report), not to the footprint (which is 0 inside).

Frames with no vehicle and no hypothesis are fine; a metric that has no
denominator (no vehicle at all, no hypothesis, no match) is NaN and its reason is
listed in ``nan_reasons``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import motmetrics as mm
import numpy as np
from pycocotools.cocoeval import Params as CocoParams
from scipy.optimize import linear_sum_assignment
from trackeval.metrics import HOTA

NAN = float("nan")


@dataclass(frozen=True)
class MetricsConfig:
    """Settings of `evaluate` (units beside each value)."""

    gate_m: float = 1.5  # [m] max distance from a hypothesis to a footprint to match
    camera_xy: tuple[float, float] = (0.0, 0.0)  # [m] camera foot in the ego road frame

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gate_m) and self.gate_m > 0):
            raise ValueError(f"MetricsConfig.gate_m must be finite and > 0, got {self.gate_m!r}")
        if len(self.camera_xy) != 2 or not all(math.isfinite(v) for v in self.camera_xy):
            raise ValueError(
                f"MetricsConfig.camera_xy must be 2 finite numbers, got {self.camera_xy}"
            )


EGO_MOVING_MPS = 0.5  # [m/s] the ego car moves above this ground speed
STATIONARY_MPS = 0.5  # [m/s] a vehicle slower than this over the ground is stationary
CO_MOVING_MPS = 1.0  # [m/s] a vehicle within this of the ego car's velocity is co-moving
MOTION_CLASSES = ("co-moving", "overtaking", "overtaken", "oncoming", "crossing", "stationary")
RANGE_BANDS_M = (0.0, 5.0, 10.0, 15.0, 25.0)  # [m] edges of the range bands of `breakdown`
SECTORS = ("front", "left", "rear", "right")  # |bearing| < 45, 45..135 left, >= 135, right
# the COCO benchmark's apparent sizes (pycocotools' area ranges [px]: small below 32^2,
# medium to 96^2, large above): a vehicle's pixels in the full-resolution id image
_COCO = CocoParams()
SIZE_CLASSES = {
    name: (float(lo), float(hi))
    for name, (lo, hi) in zip(_COCO.areaRngLbl, _COCO.areaRng, strict=True)
    if name != "all"
}
UNMATCHED_KINDS = ("duplicate", "misplaced", "clutter")  # `unmatched_split`
MISPLACED_M = 5.0  # [m] unmatched this near a vehicle: misplaced, farther: clutter; 1.5-10


def motion_class(speed_mps: float, yaw_rad: float, ego_speed_mps: float, ego_yaw_rad: float) -> str:
    """A vehicle's motion relative to the ego car, both given by ground speed [m/s] and
    heading [rad] in one world frame: "stationary" (slower than STATIONARY_MPS), else
    "co-moving" (velocity within CO_MOVING_MPS of the ego car's), else by heading
    relative to the ego car's: "oncoming" (beyond 135 deg), "crossing" (45-135 deg),
    else "overtaking" (faster along the ego car's heading) or "overtaken"."""
    if speed_mps < STATIONARY_MPS:
        return "stationary"
    v = speed_mps * np.array([math.cos(yaw_rad), math.sin(yaw_rad)])
    ego = ego_speed_mps * np.array([math.cos(ego_yaw_rad), math.sin(ego_yaw_rad)])
    if np.linalg.norm(v - ego) <= CO_MOVING_MPS:
        return "co-moving"
    rel = abs(
        math.degrees(math.atan2(math.sin(yaw_rad - ego_yaw_rad), math.cos(yaw_rad - ego_yaw_rad)))
    )
    if rel > 135.0:
        return "oncoming"
    if rel > 45.0:
        return "crossing"
    along = speed_mps * math.cos(yaw_rad - ego_yaw_rad)
    return "overtaking" if along > ego_speed_mps else "overtaken"


def sector(bearing_deg: float) -> str:
    """ "front" (|bearing| < 45 deg), "rear" (|bearing| >= 135), else "left" (bearing > 0)
    or "right", of a bearing [deg] (0 ahead, +90 left): symmetric about the car's axis."""
    a = abs(bearing_deg)
    if a < 45.0:
        return "front"
    if a >= 135.0:
        return "rear"
    return "left" if bearing_deg > 0 else "right"


# ------------------------------------------------------------------ inputs
@dataclass(frozen=True)
class GtVehicle:
    """A ground-truth vehicle: id and footprint (4, 2) [m] in the ego road frame, its
    motion relative to the ego car (one of `MOTION_CLASSES`, "" if unknown), its
    velocity over the ground in the ego road frame's axes (2,) [m/s] (NaN if unknown) and
    its apparent size, the pixels it covers in the frame's image [px] (NaN if unknown).

    The corners go around a convex polygon (either direction).
    """

    id: int
    footprint_xy: np.ndarray
    motion: str = ""
    velocity_xy: np.ndarray = field(default_factory=lambda: np.full(2, NAN))
    visible_px: float = NAN

    def __post_init__(self) -> None:
        fp = np.asarray(self.footprint_xy, dtype=float)
        if fp.shape != (4, 2) or not np.all(np.isfinite(fp)):
            raise ValueError(f"GtVehicle {self.id}: footprint_xy must be finite (4, 2), got {fp}")
        object.__setattr__(self, "footprint_xy", fp)
        v = np.asarray(self.velocity_xy, dtype=float)
        if v.shape != (2,):
            raise ValueError(f"GtVehicle {self.id}: velocity_xy must have shape (2,), got {v}")
        object.__setattr__(self, "velocity_xy", v)
        px = float(self.visible_px)
        if not (math.isnan(px) or px >= 0):
            raise ValueError(f"GtVehicle {self.id}: visible_px must be >= 0 or NaN, got {px}")
        object.__setattr__(self, "visible_px", px)

    @classmethod
    def from_box(
        cls,
        vehicle_id: int,
        x_m: float,
        y_m: float,
        length_m: float,
        width_m: float,
        yaw_rad: float,
    ) -> GtVehicle:
        """Footprint of a box: centre (x, y) [m], length along its heading, yaw to ego x [rad]."""
        return cls(int(vehicle_id), box_footprint(x_m, y_m, length_m, width_m, yaw_rad))


def box_footprint(
    x_m: float, y_m: float, length_m: float, width_m: float, yaw_rad: float
) -> np.ndarray:
    """(4, 2) corners [m] (counter-clockwise) of a box: centre (x, y), length along its
    heading yaw [rad] from the x axis, width across it."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * [length_m / 2, width_m / 2]
    return half @ np.array([[c, -s], [s, c]]).T + [x_m, y_m]


def plan_box_xywh(corners_xy: np.ndarray) -> np.ndarray:
    """(4,) plan-view axis-aligned extent of points (N, 2) [m]: (x min, y min, x extent,
    y extent), the ``xywh`` layout of TrackEval (x of the frame as its x, y as its y)."""
    p = np.asarray(corners_xy, dtype=float).reshape(-1, 2)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]])


def box_iou_xywh(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) IoU of axis-aligned boxes a (A, 4) and b (B, 4) in the ``xywh`` layout, with
    the arithmetic of TrackEval's ``_calculate_box_ious`` (far corners as x + w, y + h;
    0 for a box of area <= eps), so that both give the same floats."""
    eps = np.finfo("float").eps
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    a = np.column_stack([a[:, 0], a[:, 1], a[:, 0] + a[:, 2], a[:, 1] + a[:, 3]])
    b = np.column_stack([b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]])
    lo = np.minimum(a[:, None, :], b[None, :, :])
    hi = np.maximum(a[:, None, :], b[None, :, :])
    inter = np.maximum(lo[..., 2] - hi[..., 0], 0) * np.maximum(lo[..., 3] - hi[..., 1], 0)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    inter[area_a <= 0 + eps, :] = 0
    inter[:, area_b <= 0 + eps] = 0
    inter[union <= 0 + eps] = 0
    union[union <= 0 + eps] = 1
    return inter / union


@dataclass
class EvalFrame:
    """One frame: ground truth (evaluation set), hypotheses (id, x [m], y [m]) and whether
    the ego car moves (`EGO_MOVING_MPS`); optionally each hypothesis's box centre (x, y)
    [m] (NaN where it has no box), empty when none has one; optionally each hypothesis's
    box (x, y [m], yaw [rad], length, width [m]; NaN where it has none), empty when none
    has one: ``hyp_box_xywh`` (H, 4) its plan-view extent (`plan_box_xywh`), NaN rows
    where none, ``hyp_yaw`` (H,) its yaw [rad]; optionally each hypothesis's state, empty
    when none has one: ``velocities`` (vx, vy) [m/s] over the ground in the ego road
    frame's axes, ``covariances`` (var_x [m²], cov_xy [m²], var_y [m²], var_vx, cov_vxvy,
    var_vy [m²/s²]) of its position and velocity (the columns of ``tracks.csv``), NaN
    where it has none: ``hyp_velocity`` (H, 2), ``hyp_cov`` (H, 6)."""

    gt: Sequence[GtVehicle]
    hypotheses: Sequence[tuple[int, float, float]] = ()
    t_s: float = NAN
    ego_moving: bool = True
    centres: Sequence[tuple[float, float]] = ()
    boxes: Sequence[tuple[float, float, float, float, float]] = ()
    velocities: Sequence[tuple[float, float]] = ()
    covariances: Sequence[tuple[float, ...]] = ()
    hyp_ids: np.ndarray = field(init=False, repr=False)
    hyp_xy: np.ndarray = field(init=False, repr=False)
    hyp_centre_xy: np.ndarray = field(init=False, repr=False)
    hyp_box_xywh: np.ndarray = field(init=False, repr=False)
    hyp_yaw: np.ndarray = field(init=False, repr=False)
    hyp_velocity: np.ndarray = field(init=False, repr=False)
    hyp_cov: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.gt = list(self.gt)
        h = list(self.hypotheses)
        self.hyp_ids = np.array([int(r[0]) for r in h], dtype=int)
        self.hyp_xy = np.array([[float(r[1]), float(r[2])] for r in h]).reshape(-1, 2)
        if not np.all(np.isfinite(self.hyp_xy)):
            raise ValueError(f"frame t={self.t_s}: hypothesis positions must be finite: {h}")
        c = np.array(list(self.centres), float).reshape(-1, 2)
        if len(c) not in (0, len(h)):
            raise ValueError(f"frame t={self.t_s}: {len(c)} box centres for {len(h)} hypotheses")
        self.hyp_centre_xy = c if len(c) else np.full((len(h), 2), NAN)
        b = np.array(list(self.boxes), float).reshape(-1, 5)
        if len(b) not in (0, len(h)):
            raise ValueError(f"frame t={self.t_s}: {len(b)} boxes for {len(h)} hypotheses")
        self.hyp_box_xywh = np.full((len(h), 4), NAN)
        self.hyp_yaw = np.full(len(h), NAN)
        for i, box in enumerate(b):
            if np.all(np.isfinite(box)):
                x, y, yaw, length, width = box
                self.hyp_box_xywh[i] = plan_box_xywh(box_footprint(x, y, length, width, yaw))
                self.hyp_yaw[i] = yaw
        self.hyp_velocity = self._per_hypothesis("velocities", self.velocities, 2)
        self.hyp_cov = self._per_hypothesis("covariances", self.covariances, 6)
        gt_ids = [g.id for g in self.gt]
        for name, ids in (("ground-truth", gt_ids), ("hypothesis", self.hyp_ids.tolist())):
            if len(set(ids)) != len(ids):
                raise ValueError(f"frame t={self.t_s}: duplicate {name} ids {sorted(ids)}")

    def _per_hypothesis(self, name: str, rows: Sequence, width: int) -> np.ndarray:
        """(H, width) of rows given per hypothesis, all NaN when none is given."""
        a = np.array(list(rows), float).reshape(-1, width)
        if len(a) not in (0, len(self.hyp_ids)):
            raise ValueError(
                f"frame t={self.t_s}: {len(a)} {name} for {len(self.hyp_ids)} hypotheses"
            )
        return a if len(a) else np.full((len(self.hyp_ids), width), NAN)

    @property
    def gt_ids(self) -> np.ndarray:
        return np.array([g.id for g in self.gt], dtype=int)


def hypotheses_from_tracks(tracks: Iterable[Any]) -> list[tuple[int, float, float]]:
    """(id, x, y) of tracks with ``.id`` and ``.x`` (e.g. `estimator.surround.tracking.Track`)."""
    return [(int(t.id), float(t.x[0]), float(t.x[1])) for t in tracks]


# ------------------------------------------------------------------ geometry
def _closest_on_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P, E, 2) closest point of each segment a[e]-b[e] (E, 2) to each point (P, 2)."""
    ab = b - a
    denom = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.einsum("pej,ej->pe", points[:, None, :] - a[None], ab) / denom
    t = np.clip(t, 0.0, 1.0)
    return a[None] + t[..., None] * ab[None]


def point_footprint_distance(points_xy: np.ndarray, footprint_xy: np.ndarray) -> np.ndarray:
    """(P,) distance [m] from points (P, 2) to a convex polygon (V, 2); 0 inside or on it."""
    pts = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    poly = np.asarray(footprint_xy, dtype=float)
    a, b = poly, np.roll(poly, -1, axis=0)
    closest = _closest_on_segments(pts, a, b)
    dist = np.linalg.norm(pts[:, None, :] - closest, axis=2).min(axis=1)
    # inside: the point is on the same side of every edge (either orientation)
    ab = b - a
    ap = pts[:, None, :] - a[None]
    cross = ab[None, :, 0] * ap[..., 1] - ab[None, :, 1] * ap[..., 0]
    inside = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
    return np.where(inside, 0.0, dist)


def nearest_footprint_point(
    footprint_xy: np.ndarray, camera_xy: Sequence[float] = (0.0, 0.0)
) -> np.ndarray:
    """(2,) point of the footprint boundary nearest to the camera foot [m]."""
    poly = np.asarray(footprint_xy, dtype=float)
    cam = np.asarray(camera_xy, dtype=float).reshape(1, 2)
    closest = _closest_on_segments(cam, poly, np.roll(poly, -1, axis=0))[0]
    return closest[np.argmin(np.linalg.norm(closest - cam, axis=1))]


def distance_matrix(frame: EvalFrame) -> np.ndarray:
    """(G, H) footprint distances [m] of a frame's vehicles (rows) and hypotheses (cols)."""
    D = np.zeros((len(frame.gt), len(frame.hyp_xy)))
    for i, g in enumerate(frame.gt):
        D[i] = point_footprint_distance(frame.hyp_xy, g.footprint_xy)
    return D


def _gated_assignment(D: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """Most pairs with D <= gate, then least total distance; (gt row, hyp col) pairs."""
    allowed = D <= gate
    if not allowed.any():
        return []
    big = 1.0 + min(D.shape) * (gate + 1.0)  # exceeds any sum of allowed distances
    rows, cols = linear_sum_assignment(np.where(allowed, D, big))
    return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if allowed[r, c]]


# ------------------------------------------------------------------ metrics
def _hota(
    gt_ids: Sequence[np.ndarray], hyp_ids: Sequence[np.ndarray], sims: Sequence[np.ndarray]
) -> dict[str, float]:
    """TrackEval's HOTA, DetA and AssA (means over alpha) of per-frame ids (G,), (H,) and
    similarities (G, H)."""
    # TrackEval wants ids 0..n-1 with every id present somewhere: an id that never
    # appears gives 0/0 in its global alignment score and a NaN cost matrix
    gt_index = {g: k for k, g in enumerate(sorted({int(g) for f in gt_ids for g in f}))}
    hyp_index = {h: k for k, h in enumerate(sorted({int(h) for f in hyp_ids for h in f}))}
    data = {
        "num_timesteps": len(sims),
        "num_gt_ids": len(gt_index),
        "num_tracker_ids": len(hyp_index),
        "num_gt_dets": sum(len(f) for f in gt_ids),
        "num_tracker_dets": sum(len(f) for f in hyp_ids),
        "gt_ids": [np.array([gt_index[int(g)] for g in f], dtype=int) for f in gt_ids],
        "tracker_ids": [np.array([hyp_index[int(h)] for h in f], dtype=int) for f in hyp_ids],
        "similarity_scores": list(sims),
    }
    res = HOTA().eval_sequence(data)
    return {k: float(np.mean(res[k])) for k in ("HOTA", "DetA", "AssA")}


def _hota_point(frames: Sequence[EvalFrame], dists: Sequence[np.ndarray], gate: float) -> float:
    """Mean over alpha of TrackEval's HOTA, similarity max(0, 1 - d / gate)."""
    sims = [np.clip(1.0 - D / gate, 0.0, 1.0) for D in dists]
    return _hota([f.gt_ids for f in frames], [f.hyp_ids for f in frames], sims)["HOTA"]


def _hota_box(frames: Sequence[EvalFrame]) -> dict[str, float]:
    """HOTA, DetA, AssA with similarity the IoU of plan-view boxes (module docstring),
    over every frame, of the hypotheses with a box."""
    gt_ids, hyp_ids, sims = [], [], []
    for f in frames:
        has = np.all(np.isfinite(f.hyp_box_xywh), axis=1)
        gt_box = np.array([plan_box_xywh(g.footprint_xy) for g in f.gt]).reshape(-1, 4)
        gt_ids.append(f.gt_ids)
        hyp_ids.append(f.hyp_ids[has])
        sims.append(box_iou_xywh(gt_box, f.hyp_box_xywh[has]))
    return _hota(gt_ids, hyp_ids, sims)


def _motmetrics(frames: Sequence[EvalFrame], dists: Sequence[np.ndarray], gate: float) -> dict:
    acc = mm.MOTAccumulator(auto_id=False)
    for k, (f, D) in enumerate(zip(frames, dists, strict=True)):
        acc.update(f.gt_ids.tolist(), f.hyp_ids.tolist(), np.where(D <= gate, D, np.nan), frameid=k)
    names = ["mota", "idf1", "num_switches", "num_matches", "num_false_positives", "num_misses"]
    summary = mm.metrics.create().compute(acc, metrics=names, name="seq")
    return {n: summary[n].iloc[0] for n in names}


def match_frames(frames: Sequence[EvalFrame], cfg: MetricsConfig):
    """Per-frame distance matrices and detection matches (frame, gt row, hyp col)."""
    dists = [distance_matrix(f) for f in frames]
    matches = [(k, r, c) for k, D in enumerate(dists) for r, c in _gated_assignment(D, cfg.gate_m)]
    return dists, matches


def evaluate(frames: Sequence[EvalFrame], config: MetricsConfig | None = None) -> dict:
    """Detection, tracking and localisation metrics of a sequence.

    Returns ``{"gate_m", "counts", "detection": {"recall", "precision", "gt_count",
    "matched"}, "tracking": {"mota", "idf1", "hota", "id_switches", "hota_box",
    "deta_box", "assa_box"},
    "localization": {"median_error_m", "p90_error_m", "centre_median_error_m",
    "centre_p90_error_m", "offset_median_error_m"}, "nan_reasons"}`` with
    plain Python numbers (JSON-ready). ``nan_reasons`` maps "section.metric" to
    why that metric is NaN.
    """
    cfg = config if config is not None else MetricsConfig()
    frames = list(frames)
    dists, matches = match_frames(frames, cfg)
    gt_count = sum(len(f.gt) for f in frames)
    hyp_count = sum(len(f.hyp_ids) for f in frames)
    matched = len(matches)
    reasons: dict[str, str] = {}

    def ratio(num: float, den: int, key: str, why: str) -> float:
        if den == 0:
            reasons[key] = why
            return NAN
        return float(num / den)

    recall = ratio(matched, gt_count, "detection.recall", "no ground-truth vehicle")
    precision = ratio(matched, hyp_count, "detection.precision", "no hypothesis")

    # each matched vehicle's footprint point nearest the camera (N, 2), for both errors below
    nearest = np.array(
        [
            nearest_footprint_point(frames[k].gt[r].footprint_xy, cfg.camera_xy)
            for k, r, _ in matches
        ]
    ).reshape(-1, 2)
    errors = np.array(
        [
            float(np.linalg.norm(frames[k].hyp_xy[c] - p))
            for (k, _, c), p in zip(matches, nearest, strict=True)
        ]
    )
    if errors.size:
        median_err, p90_err = float(np.median(errors)), float(np.percentile(errors, 90))
    else:
        median_err = p90_err = NAN
        reasons["localization.median_error_m"] = reasons["localization.p90_error_m"] = (
            "no matched hypothesis"
        )

    # box centres: matched hypotheses that have one, to the footprint's centre; and the
    # box's offset from its point against the centre's offset from the nearest ground
    # point (what the box adds to the point's error)
    centre_err, offset_err = [], []
    for (k, r, c), p in zip(matches, nearest, strict=True):
        f = frames[k]
        if not np.all(np.isfinite(f.hyp_centre_xy[c])):
            continue
        centre = f.gt[r].footprint_xy.mean(0)
        centre_err.append(float(np.linalg.norm(f.hyp_centre_xy[c] - centre)))
        offset = (f.hyp_centre_xy[c] - f.hyp_xy[c]) - (centre - p)
        offset_err.append(float(np.linalg.norm(offset)))
    centre_err, offset_err = np.array(centre_err), np.array(offset_err)
    if centre_err.size:
        centre_med = float(np.median(centre_err))
        centre_p90 = float(np.percentile(centre_err, 90))
        offset_med = float(np.median(offset_err))
    else:
        centre_med = centre_p90 = offset_med = NAN
        for key in ("centre_median_error_m", "centre_p90_error_m", "offset_median_error_m"):
            reasons[f"localization.{key}"] = "no matched hypothesis with a box"

    mot = {"mota": NAN, "idf1": NAN, "num_switches": 0, "num_matches": 0}
    mot |= {"num_false_positives": hyp_count, "num_misses": 0}
    hota = NAN
    box_hyp_count = sum(int(np.all(np.isfinite(f.hyp_box_xywh), axis=1).sum()) for f in frames)
    box = {"HOTA": NAN, "DetA": NAN, "AssA": NAN}
    box_keys = ("tracking.hota_box", "tracking.deta_box", "tracking.assa_box")
    if gt_count == 0:
        for key in ("tracking.mota", "tracking.idf1", "tracking.hota", *box_keys):
            reasons[key] = "no ground-truth vehicle"
    elif frames:
        mot = _motmetrics(frames, dists, cfg.gate_m)
        hota = _hota_point(frames, dists, cfg.gate_m)
        if box_hyp_count:
            box = _hota_box(frames)
        else:
            reasons.update(dict.fromkeys(box_keys, "no hypothesis with a box"))

    return {
        "gate_m": float(cfg.gate_m),
        "counts": {
            "frames": len(frames),
            "empty_frames": sum(1 for f in frames if not f.gt and not len(f.hyp_ids)),
            "gt_count": gt_count,
            "hyp_count": hyp_count,
            "gt_ids": len({g.id for f in frames for g in f.gt}),
            "hyp_ids": len({int(h) for f in frames for h in f.hyp_ids}),
            "false_positives": hyp_count - matched,
            "misses": gt_count - matched,
            "mot_matches": int(mot["num_matches"]),
            "mot_false_positives": int(mot["num_false_positives"]),
            "mot_misses": int(mot["num_misses"]),
            "localization_pairs": int(errors.size),
            "centre_pairs": int(centre_err.size),
            "box_hyp_count": box_hyp_count,
        },
        "detection": {
            "recall": recall,
            "precision": precision,
            "gt_count": gt_count,
            "matched": matched,
        },
        "tracking": {
            "mota": float(mot["mota"]),
            "idf1": float(mot["idf1"]),
            "hota": hota,
            "id_switches": int(mot["num_switches"]),
            "hota_box": box["HOTA"],
            "deta_box": box["DetA"],
            "assa_box": box["AssA"],
        },
        "localization": {
            "median_error_m": median_err,
            "p90_error_m": p90_err,
            "centre_median_error_m": centre_med,
            "centre_p90_error_m": centre_p90,
            "offset_median_error_m": offset_med,
        },
        "nan_reasons": reasons,
    }


# ------------------------------------------------------------------ where detection fails
@dataclass
class _Placed:
    """Every vehicle and hypothesis of a sequence, relative to the camera foot, and whether
    detection matched it: vehicles by their footprint point nearest the camera (G, 2),
    found (G,), motion (G,) class, size_px (G,) apparent size; hypotheses by their own
    point (H, 2), matched (H,); the index of each one's frame in the sequence, gt_frame
    (G,) and hyp_frame (H,)."""

    gt_xy: np.ndarray
    found: np.ndarray
    motion: list[str]
    size_px: np.ndarray
    hyp_xy: np.ndarray
    matched: np.ndarray
    hyp_gt_m: np.ndarray  # (H,) [m] footprint distance to the frame's nearest vehicle (inf: none)
    gt_frame: np.ndarray
    hyp_frame: np.ndarray

    @staticmethod
    def of(frames: Sequence[EvalFrame], cfg: MetricsConfig) -> _Placed:
        dists, matches = match_frames(frames, cfg)
        gt_hit = {(k, r) for k, r, _ in matches}
        hyp_hit = {(k, c) for k, _, c in matches}
        cam = np.asarray(cfg.camera_xy, float)
        gt = [(k, r, g) for k, f in enumerate(frames) for r, g in enumerate(f.gt)]
        gt_xy = [nearest_footprint_point(g.footprint_xy, cam) - cam for _, _, g in gt]
        hyp = [(k, c) for k, f in enumerate(frames) for c in range(len(f.hyp_xy))]
        return _Placed(
            np.asarray(gt_xy, float).reshape(-1, 2),
            np.array([(k, r) in gt_hit for k, r, _ in gt], bool),
            [g.motion for _, _, g in gt],
            np.array([g.visible_px for _, _, g in gt], float).reshape(-1),
            np.asarray([frames[k].hyp_xy[c] - cam for k, c in hyp], float).reshape(-1, 2),
            np.array([(k, c) in hyp_hit for k, c in hyp], bool),
            np.array([dists[k][:, c].min(initial=np.inf) for k, c in hyp], float).reshape(-1),
            np.array([k for k, _, _ in gt], int),
            np.array([k for k, _ in hyp], int),
        )

    def of_frames(self, keep: np.ndarray) -> _Placed:
        """The vehicles and hypotheses of the frames where keep (frames,) is true (each
        frame is matched on its own, so its matches stay what they are)."""
        g, h = keep[self.gt_frame], keep[self.hyp_frame]
        return _Placed(
            self.gt_xy[g],
            self.found[g],
            [m for m, k in zip(self.motion, g, strict=True) if k],
            self.size_px[g],
            self.hyp_xy[h],
            self.matched[h],
            self.hyp_gt_m[h],
            self.gt_frame[g],
            self.hyp_frame[h],
        )


def _range_m(xy: np.ndarray) -> np.ndarray:
    return np.hypot(xy[:, 0], xy[:, 1])


def _bearing_deg(xy: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(xy[:, 1], xy[:, 0]))


def ratio(num: int, den: int) -> float:
    """num / den, NaN when den is 0 (nothing to count)."""
    return float(num / den) if den else NAN


BAND_NAMES = [
    f"{lo:g}-{hi:g} m" for lo, hi in zip(RANGE_BANDS_M[:-1], RANGE_BANDS_M[1:], strict=True)
]


def band_labels(xy: np.ndarray) -> np.ndarray:
    """(N,) range band name of points (N, 2) ("" beyond the bands)."""
    i = np.digitize(_range_m(xy), RANGE_BANDS_M) - 1
    names = np.array([*BAND_NAMES, ""], dtype=object)
    return names[np.where((i >= 0) & (i < len(BAND_NAMES)), i, -1)]


def _sector_labels(xy: np.ndarray) -> np.ndarray:
    """(N,) sector name of points (N, 2)."""
    return np.array([sector(b) for b in _bearing_deg(xy)], dtype=object)


def _bins(placed: _Placed, names: Sequence[str], label_of) -> dict:
    """Per name of a bin (label_of: (N, 2) points -> (N,) names): the vehicles' gt_count,
    matched and recall, the hypotheses' hyp_count, hyp_matched and precision."""
    gt_lab, hyp_lab = label_of(placed.gt_xy), label_of(placed.hyp_xy)
    out = {}
    for name in names:
        g, h = gt_lab == name, hyp_lab == name
        n, m = int(g.sum()), int((g & placed.found).sum())
        hn, hm = int(h.sum()), int((h & placed.matched).sum())
        out[name] = {"gt_count": n, "matched": m, "hyp_count": hn, "hyp_matched": hm}
        out[name] |= {"recall": ratio(m, n), "precision": ratio(hm, hn)}
    return out


def unmatched_split(placed: _Placed, gate_m: float) -> dict:
    """What the hypotheses that match no vehicle are: {"hyp_count", "unmatched",
    "duplicate" (within the gate of a vehicle that another hypothesis matched),
    "misplaced" (within `MISPLACED_M` of a vehicle's footprint, beyond the gate: a vehicle
    placed wrong), "clutter" (farther from every vehicle of the frame), and the three
    shares of the unmatched ("duplicate_share", ...; NaN when none is unmatched)}."""
    d = placed.hyp_gt_m[~placed.matched]
    kinds = (d <= gate_m, (d > gate_m) & (d <= MISPLACED_M), d > MISPLACED_M)
    n = {k: int(sel.sum()) for k, sel in zip(UNMATCHED_KINDS, kinds, strict=True)}
    return {
        "hyp_count": len(placed.matched),
        "unmatched": len(d),
        **n,
        **{f"{k}_share": ratio(v, len(d)) for k, v in n.items()},
    }


def breakdown(
    frames: Sequence[EvalFrame], config: MetricsConfig | None = None, tracked: bool = True
) -> dict:
    """Where detection fails: recall and precision by range band (`RANGE_BANDS_M`) and by
    bearing sector (`sector`), recall by the vehicles' motion (`MOTION_CLASSES`) and by
    their apparent size (`SIZE_CLASSES`; a hypothesis has neither, so no precision
    there), what the unmatched hypotheses are
    (`unmatched_split`), and every metric of `evaluate` and the three breakdowns over the
    frames where the ego car moves and over those where it is stopped.

    A vehicle is placed by its footprint point nearest the camera, a hypothesis by its
    own point; a matched pair counts in the vehicle's bin for recall and in the
    hypothesis' bin for precision (the same bin but at a bin's edge). NaN: an empty bin.

    tracked=False: hypotheses without identities across frames (a detector's candidates,
    before the tracker decides which are vehicles): no tracking or localisation metrics;
    "detection" (recall, precision and counts, `_counted`) overall and per ego state.
    """
    cfg = config if config is not None else MetricsConfig()
    frames = list(frames)
    placed = _Placed.of(frames, cfg)
    ego = {}
    moving_frames = np.array([f.ego_moving for f in frames], bool)
    for state, moving in (("moving", True), ("stopped", False)):
        keep = moving_frames == moving
        sub = placed.of_frames(keep)
        if tracked:
            m = evaluate([f for f, k in zip(frames, keep, strict=True) if k], cfg)
            scores = {key: m[key] for key in ("detection", "tracking", "localization")}
        else:
            scores = {"detection": _counted(sub)}
        ego[state] = {"frames": int(keep.sum()), **scores, **_where(sub)}
    out = {
        **_where(placed),
        "unmatched": unmatched_split(placed, cfg.gate_m),
        "ego_state": ego,
    }
    return out if tracked else {"detection": _counted(placed), **out}


def _counted(placed: _Placed) -> dict:
    """{"recall", "precision", "gt_count", "matched", "hyp_count"} of placed vehicles and
    hypotheses (NaN: nothing to count)."""
    n, m = len(placed.found), int(placed.found.sum())
    hn, hm = len(placed.matched), int(placed.matched.sum())
    return {
        "recall": ratio(m, n),
        "precision": ratio(hm, hn),
        "gt_count": n,
        "matched": m,
        "hyp_count": hn,
    }


def _where(placed: _Placed) -> dict:
    """{"range_bands", "sectors", "motion", "sizes"} of `breakdown` for the placed
    vehicles and hypotheses."""
    classes = np.array([m or "unknown" for m in placed.motion], dtype=object)
    size = placed.size_px
    sizes = {name: (size >= lo) & (size < hi) for name, (lo, hi) in SIZE_CLASSES.items()}
    return {
        "range_bands": _bins(placed, BAND_NAMES, band_labels),
        "sectors": _bins(placed, SECTORS, _sector_labels),
        "motion": _recalls(
            placed, {name: classes == name for name in MOTION_CLASSES + ("unknown",)}
        ),
        "sizes": _recalls(placed, {**sizes, "unknown": np.isnan(size)}),
    }


def _recalls(placed: _Placed, classes: dict[str, np.ndarray]) -> dict:
    """{class: {"gt_count", "matched", "recall"}} of the placed vehicles in each class
    (G,) bool (a hypothesis has no class: no precision); an empty "unknown" class is
    left out."""
    out = {}
    for name, sel in classes.items():
        n, m = int(sel.sum()), int((sel & placed.found).sum())
        if name != "unknown" or n:
            out[name] = {"gt_count": n, "matched": m, "recall": ratio(m, n)}
    return out


def recall_polar(
    frames: Sequence[EvalFrame],
    range_edges_m: Sequence[float],
    bearing_edges_deg: Sequence[float],
    config: MetricsConfig | None = None,
) -> dict:
    """Recall on a polar grid around the camera: {"range_edges_m", "bearing_edges_deg",
    "gt_count" (R, B), "matched" (R, B)} as lists; vehicles placed by their footprint
    point nearest the camera, bearing 0 ahead, +90 left."""
    cfg = config if config is not None else MetricsConfig()
    placed = _Placed.of(list(frames), cfg)
    edges = (np.asarray(range_edges_m, float), np.asarray(bearing_edges_deg, float))
    r, b, hit = _range_m(placed.gt_xy), _bearing_deg(placed.gt_xy), placed.found
    gt_n = np.histogram2d(r, b, edges)[0]
    hit_n = np.histogram2d(r[hit], b[hit], edges)[0]
    return {
        "range_edges_m": edges[0].tolist(),
        "bearing_edges_deg": edges[1].tolist(),
        "gt_count": gt_n.astype(int).tolist(),
        "matched": hit_n.astype(int).tolist(),
    }


# ------------------------------------------------------------------ recall by bins
def _recall_by(
    frames: Sequence[EvalFrame],
    bin_edges: Sequence[float],
    config: MetricsConfig | None,
    key,
) -> dict:
    cfg = config if config is not None else MetricsConfig()
    edges = np.asarray(bin_edges, dtype=float)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(f"bin edges must be 1-D, increasing, >= 2 values, got {edges}")
    placed = _Placed.of(list(frames), cfg)
    values, found = key(placed.gt_xy), placed.found
    gt_n = np.histogram(values, edges)[0]
    hit_n = np.histogram(values[found], edges)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        rec = np.where(gt_n > 0, hit_n / np.maximum(gt_n, 1), np.nan)
    return {
        "bin_edges": edges.tolist(),
        "gt_count": gt_n.astype(int).tolist(),
        "matched": hit_n.astype(int).tolist(),
        "recall": [float(v) for v in rec],  # NaN: no vehicle in the bin
    }


def recall_by_range(
    frames: Sequence[EvalFrame], bin_edges_m: Sequence[float], config: MetricsConfig | None = None
) -> dict:
    """Detection recall binned by range [m] of each vehicle's footprint point nearest the camera.

    Returns {"bin_edges", "gt_count", "matched", "recall"} (lists, one entry per
    bin; recall NaN for an empty bin). Vehicles outside the edges are not counted.
    """
    return _recall_by(frames, bin_edges_m, config, _range_m)


def recall_by_bearing(
    frames: Sequence[EvalFrame],
    bin_edges_deg: Sequence[float],
    config: MetricsConfig | None = None,
) -> dict:
    """Detection recall binned by bearing [deg] of each vehicle's nearest footprint point.

    Bearing = atan2(y, x) around the camera foot in (-180, 180]: 0 ahead, +90
    left, -90 right, ±180 behind. Same return layout as `recall_by_range`.
    """
    return _recall_by(frames, bin_edges_deg, config, _bearing_deg)
