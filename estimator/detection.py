"""Vehicle detection after ego-motion compensation (paper section 5).

1. Normalized frame difference (eq. 22) of the current frame and the
   motion-compensated previous frame: ``<g_t |g|> / (k + <|g|^2>)`` with
   Gaussian-weighted averaging over K x K.
2. Threshold, then the flat-plane transform into the plan view
   (`estimator.planview`).
3. Morphological closing with a 1 x N mask along the car's direction of
   motion, N = 5.0 m (two blobs within 5 m in that direction are one vehicle).
4. Blobs (connected components), nearby blobs clustered.
5. The blob point nearest the camera is on the road (the obstacle map): it
   gives the vehicle's road-plane position by inverse perspective.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.camera import CameraModel
from estimator.mount import CameraMount
from estimator.planview import PlanView


@dataclass(frozen=True)
class DetectorConfig:
    nd_kernel_px: int = 7  # K: Gaussian averaging window of eq. 22 [px]
    nd_k: float = 50.0  # k: regulariser of eq. 22 [grey level^2]
    threshold: float = 4.0  # on |normalised difference| [grey levels, ~ px of normal flow x g]
    plan_range_m: float = 30.0  # half-size of the plan view [m]
    m_per_px: float = 0.1  # plan-view resolution [m/px]
    gap_m: float = 5.0  # N: closing length along the direction of motion [m]
    min_blob_m2: float = 0.3  # smallest blob kept [m^2]
    cluster_m: float = 1.5  # blobs closer than this are one vehicle [m]
    max_range_m: float = 25.0  # detections farther than this are dropped [m]
    min_range_m: float = 0.0  # detections nearer than this are dropped [m]


@dataclass
class Detection:
    """A detected vehicle: nearest road point (x fwd, y left) [m] in the ego road frame."""

    x_m: float
    y_m: float
    area_m2: float
    bbox_plan: tuple[int, int, int, int]  # (col, row, width, height) in the plan view
    pixel: tuple[float, float] = (float("nan"), float("nan"))  # camera pixel of the point


@dataclass
class DetectionFrame:
    """Everything one frame of detection produced (kept for visualisation)."""

    detections: list[Detection]
    normalized_difference: np.ndarray  # (H, W) float32
    motion_mask: np.ndarray  # (H, W) bool
    plan_mask: np.ndarray = field(default=None)  # (S, S) uint8 after closing


def normalized_difference(current: np.ndarray, compensated_prev: np.ndarray, k: float,
                          kernel_px: int, valid: np.ndarray | None = None) -> np.ndarray:
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


class VehicleDetector:
    """Section 5 detector for one camera; the plan-view lookup is built once."""

    def __init__(self, camera: CameraModel, mount: CameraMount,
                 config: DetectorConfig | None = None) -> None:
        self.camera, self.mount = camera, mount
        self.cfg = config or DetectorConfig()
        self.plan = PlanView.build(camera, mount, self.cfg.plan_range_m, self.cfg.m_per_px)
        valid = camera.valid_mask()
        # keep a margin from the field-of-view border: warps are not defined beyond it
        self.valid = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        n = max(1, int(round(self.cfg.gap_m / self.cfg.m_per_px)))
        self._close_kernel = np.ones((n, 1), np.uint8)  # 1 x N along the direction of motion
        self._cluster_kernel = np.ones((max(1, int(self.cfg.cluster_m / self.cfg.m_per_px)),) * 2,
                                       np.uint8)
        x, y = PlanView._grid(self.plan.range_m, self.plan.m_per_px, self.plan.size)
        self._plan_dist = np.hypot(x, y).astype(np.float32)

    def detect(self, current_gray: np.ndarray, compensated_prev: np.ndarray,
               compensated_valid: np.ndarray | None = None) -> DetectionFrame:
        cfg = self.cfg
        valid = self.valid if compensated_valid is None else self.valid & compensated_valid
        nd = normalized_difference(current_gray, compensated_prev, cfg.nd_k, cfg.nd_kernel_px,
                                   valid)
        motion = (np.abs(nd) > cfg.threshold) & valid
        plan = self.plan.warp(motion.astype(np.uint8) * 255, nearest=True)
        plan = cv2.morphologyEx(plan, cv2.MORPH_CLOSE, self._close_kernel)
        dets = self._blobs(plan)
        return DetectionFrame(dets, nd.astype(np.float32), motion, plan)

    def _blobs(self, plan: np.ndarray) -> list[Detection]:
        cfg = self.cfg
        binary = (plan > 0).astype(np.uint8)
        n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
        px_area = cfg.m_per_px**2
        keep = np.zeros(n, bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] * px_area >= cfg.min_blob_m2
        if not keep.any():
            return []
        kept = np.where(keep[labels], 255, 0).astype(np.uint8)
        # nearby blobs are clustered: components of the dilated mask
        grown = cv2.dilate(kept, self._cluster_kernel)
        m, groups = cv2.connectedComponents((grown > 0).astype(np.uint8), connectivity=8)
        out: list[Detection] = []
        for g in range(1, m):
            sel = (groups == g) & (kept > 0)
            if not sel.any():
                continue
            d = np.where(sel, self._plan_dist, np.inf)
            r, c = np.unravel_index(int(np.argmin(d)), d.shape)  # obstacle map: nearest point
            xy = self.plan.to_road(np.array([r]), np.array([c]))[0]
            rng = float(np.hypot(*xy))
            if rng > cfg.max_range_m or rng < cfg.min_range_m:
                continue
            rows, cols = np.nonzero(sel)
            bbox = (int(cols.min()), int(rows.min()), int(np.ptp(cols) + 1), int(np.ptp(rows) + 1))
            pix = (float(self.plan.map_x[r, c]), float(self.plan.map_y[r, c]))
            out.append(Detection(float(xy[0]), float(xy[1]), float(sel.sum() * px_area), bbox,
                                 pix))
        return out
