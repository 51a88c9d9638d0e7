"""A third-party surround detector/tracker, written against omnibench's plug-in protocol.

Each frame is warped onto the road plane around the car (inverse perspective: each cell
of a square plan view, x forward and y left of the camera's foot, is a road point whose
pixel the camera model gives). The previous plan view is moved by the ego-motion since
then (on the road plane the road homography is a rigid motion: the distance driven and
the heading change), so that the road lines up and what stands above it or moves does
not. The absolute difference, thresholded and closed, falls apart into connected
components; each large enough one is a vehicle, reported at its cell nearest to the
camera (the vehicle's ground point nearest to the camera, the bench's convention). A
nearest-neighbour tracker, moved by the same ego-motion, keeps the ids.

Run it as ``--detector plan_difference:PlanDifferenceDetector`` with this folder on
``PYTHONPATH`` (examples/plan_difference/run_example.py does).
"""

from __future__ import annotations

import math

import cv2
import numpy as np


class PlanDifferenceDetector:
    """Plan-view frame difference + blobs + nearest-neighbour tracks (module docstring).

    Settings (keywords): range_m: half-size of the plan view [m]; cell_m: its cell [m];
    threshold: grey-level difference of a changed cell [0..255]; min_area_m2: the least
    area of a vehicle's blob [m^2]; gate_m: the farthest a track's point moves from one
    frame to the next [m]; min_hits: frames seen before a track is reported [-];
    max_missed: frames a track lives unseen [-]; blur_m: the Gaussian blur of the plan
    views (sigma) [m].
    """

    def __init__(
        self,
        camera,
        mount,
        range_m: float = 25.0,
        cell_m: float = 0.2,
        threshold: float = 12.0,
        min_area_m2: float = 2.0,
        gate_m: float = 3.0,
        min_hits: int = 2,
        max_missed: int = 2,
        blur_m: float = 0.5,
    ) -> None:
        self.range_m, self.cell_m, self.threshold = range_m, cell_m, threshold
        self.blur_m = blur_m
        self.min_cells = min_area_m2 / cell_m**2
        self.gate_m, self.min_hits, self.max_missed = gate_m, min_hits, max_missed
        n = int(round(2 * range_m / cell_m))
        c = range_m - (np.arange(n) + 0.5) * cell_m  # row i: x = c[i], column j: y = c[j]
        x, y = np.meshgrid(c, c, indexing="ij")
        h = float(mount.position_m[2])
        P_car = np.stack([x, y, np.full_like(x, -h)], axis=-1).reshape(-1, 3)  # from the viewpoint
        self.camera, self.n = camera, n
        self.P_cam = P_car @ np.asarray(mount.R_car_cam, float)  # nominal camera axes: R^T p
        self.xy = np.stack([x, y], axis=-1)  # (n, n, 2) road point of each cell [m]
        self.prev: tuple[np.ndarray, np.ndarray] | None = None  # plan view, seen
        self.tracks: dict[int, dict] = {}  # id -> {"xy", "hits", "missed"}
        self.next_id = 0

    def _plan(self, gray: np.ndarray, A_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(plan view (n, n) float32, seen (n, n) uint8) of a grey image taken by the camera
        turned by A (3,) [rad] from its mount: p_actual = exp([A]x)^T p_nominal."""
        R = cv2.Rodrigues(np.asarray(A_rad, float).reshape(3, 1))[0]
        P = self.P_cam @ R
        w = self.camera.project(P)
        ok = self.camera.valid_rays(P) & np.all(np.isfinite(w), axis=1)
        w[~ok] = -1.0
        maps = [w[:, i].reshape(self.n, self.n).astype(np.float32) for i in (0, 1)]
        plan = cv2.remap(gray, *maps, cv2.INTER_LINEAR).astype(np.float32)
        if self.blur_m > 0:  # misaligned sharp edges (lane marks) differ less
            plan = cv2.GaussianBlur(plan, (0, 0), self.blur_m / self.cell_m)
        return plan, ok.reshape(self.n, self.n).astype(np.uint8)

    def _move(self, speed_mps: float, yaw_rate_rps: float, dt_s: float) -> np.ndarray:
        """(2, 3) affine p_prev = R(psi) p_now + d of road points [m] between frames."""
        psi = yaw_rate_rps * dt_s
        d = speed_mps * dt_s * np.array([math.cos(psi / 2), math.sin(psi / 2)])
        c, s = math.cos(psi), math.sin(psi)
        return np.array([[c, -s, d[0]], [s, c, d[1]]])

    def _cells(self, A: np.ndarray) -> np.ndarray:
        """(2, 3) the affine A of road points [m] as one of plan-view cells (col, row)."""
        r, k = self.range_m / self.cell_m - 0.5, 1.0 / self.cell_m
        to_m = np.array([[0, -self.cell_m, self.range_m - self.cell_m / 2],
                         [-self.cell_m, 0, self.range_m - self.cell_m / 2], [0, 0, 1]])  # fmt: skip
        to_cell = np.array([[0, -k, r], [-k, 0, r], [0, 0, 1]])
        return (to_cell @ np.vstack([A, [0, 0, 1]]) @ to_m)[:2]

    def step(self, frame, t_s, image, x, dt_s, speed_mps, yaw_rate_rps):
        gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        A = np.asarray(x, float)[6:9]
        plan, seen = self._plan(gray, A if np.all(np.isfinite(A)) else np.zeros(3))
        prev, self.prev = self.prev, (plan, seen)
        ok = all(math.isfinite(v) for v in (dt_s, speed_mps, yaw_rate_rps)) and dt_s > 0
        if prev is None or not ok:
            return []
        motion = self._move(speed_mps, yaw_rate_rps, dt_s)
        M, n = self._cells(motion), plan.shape[::-1]
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP  # dst(cell) = src(M cell)
        moved = cv2.warpAffine(prev[0], M, n, flags=flags)
        both = seen & cv2.warpAffine(prev[1], M, n, flags=flags)
        changed = ((np.abs(plan - moved) > self.threshold) & (both > 0)).astype(np.uint8)
        changed = cv2.morphologyEx(changed, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
        count, labels, stats, _ = cv2.connectedComponentsWithStats(changed, connectivity=8)
        points = []
        for b in range(1, count):
            if stats[b, cv2.CC_STAT_AREA] >= self.min_cells:
                xy = self.xy[labels == b]
                points.append(xy[np.argmin(np.hypot(xy[:, 0], xy[:, 1]))])
        return self._track(points, motion)

    def _track(self, points: list[np.ndarray], A: np.ndarray) -> list[dict]:
        """Greedy nearest-neighbour association of this frame's points to the tracks,
        moved into this frame (p_now = R(psi)^T (p_prev - d)); the reported vehicles."""
        R, d = A[:, :2], A[:, 2]
        for tr in self.tracks.values():
            tr["xy"] = R.T @ (tr["xy"] - d)
        free = list(range(len(points)))
        pairs = sorted(
            (float(np.hypot(*(points[i] - tr["xy"]))), tid, i)
            for tid, tr in self.tracks.items()
            for i in free
        )
        hit: set[int] = set()
        for dist, tid, i in pairs:
            if dist <= self.gate_m and tid not in hit and i in free:
                self.tracks[tid].update(xy=points[i], hits=self.tracks[tid]["hits"] + 1, missed=0)
                hit.add(tid)
                free.remove(i)
        for tid in set(self.tracks) - hit:
            self.tracks[tid]["missed"] += 1
        self.tracks = {k: t for k, t in self.tracks.items() if t["missed"] <= self.max_missed}
        for i in free:
            self.tracks[self.next_id] = {"xy": points[i], "hits": 1, "missed": 0}
            hit.add(self.next_id)
            self.next_id += 1
        return [
            {"track_id": tid, "x_m": float(t["xy"][0]), "y_m": float(t["xy"][1])}
            for tid, t in sorted(self.tracks.items())
            if tid in hit and t["hits"] >= self.min_hits
        ]
