"""A third-party ego-motion estimator, written against omnibench's plug-in protocol.

Sparse corners on the road (``cv2.goodFeaturesToTrack``) are tracked into the next
frame by pyramidal Lucas-Kanade with a forward-backward check. Both ends of every track
are mapped onto the road plane with the camera model and its mount (each pixel's ray
met with the road), where the car's motion between the frames is a rigid motion of the
plane: a RANSAC fit of it (``cv2.estimateAffinePartial2D``) gives the distance driven
and the heading change, hence the forward speed and the yaw rate. Lucas-Kanade starts
each track where the CAN speed puts it, at one pyramid level: a deeper pyramid locks
onto the car body's edges, which do not move.

Run it as ``--estimator lk_homography:LKHomographyEstimator`` with this folder on
``PYTHONPATH`` (examples/lk_homography/run_example.py does).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from estimator.egomotion.ego_estimator import EgoMotionRecord


class LKHomographyEstimator:
    """Corners + Lucas-Kanade + RANSAC rigid motion of the road plane (module docstring).

    Settings (keywords): max_corners [-], min_range_m and max_range_m: the road ring used
    [m], ransac_m: inlier distance on the road [m], min_inliers [-].
    """

    def __init__(
        self,
        camera,
        mount,
        max_corners: int = 400,
        min_range_m: float = 3.0,
        max_range_m: float = 12.0,
        ransac_m: float = 0.2,
        min_inliers: int = 12,
    ) -> None:
        self.camera, self.mount = camera, mount
        self.max_corners, self.ransac_m, self.min_inliers = max_corners, ransac_m, min_inliers
        self.road_xy = self._road_points(camera.pixel_rays().reshape(-1, 3)).reshape(
            camera.height, camera.width, 2
        )
        rng = np.hypot(self.road_xy[..., 0], self.road_xy[..., 1])
        ok = camera.valid_mask() & np.isfinite(rng) & (rng >= min_range_m) & (rng <= max_range_m)
        self.mask = cv2.erode(ok.astype(np.uint8) * 255, np.ones((9, 9), np.uint8))
        self.prev: np.ndarray | None = None
        self.t_prev = math.nan
        self.k = 0

    def _road_points(self, rays_cam: np.ndarray) -> np.ndarray:
        """(N, 2) road point (x forward, y left) [m] relative to the camera of each ray
        (N, 3) in camera axes; NaN where the ray does not meet the road."""
        R = np.asarray(self.mount.R_car_cam, float)
        c = np.asarray(self.mount.position_m, float)
        d = np.asarray(rays_cam, float) @ R.T  # car axes
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -c[2] / d[:, 2]
        xy = s[:, None] * d[:, :2]
        xy[~(s > 0)] = np.nan
        return xy

    def step(self, image: np.ndarray, t_s: float, can_speed_mps: float | None):
        gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        k, self.k = self.k, self.k + 1
        can = float(can_speed_mps) if can_speed_mps is not None else math.nan
        prev, self.prev = self.prev, gray
        dt, self.t_prev = t_s - self.t_prev, t_s
        if prev is None:  # nothing to compare with: the CAN speed as the first record
            speed = can if math.isfinite(can) else 0.0
            return EgoMotionRecord.from_rates(
                k, t_s, 0.0, speed, 0.0, self.mount, can_speed_mps=can, degraded=True,
                reason="first frame: CAN speed",
            )  # fmt: skip
        p0 = cv2.goodFeaturesToTrack(prev, self.max_corners, 0.001, 5, mask=self.mask)
        if p0 is None or len(p0) < self.min_inliers:
            return self._fallback(k, t_s, dt, can, "too few corners on the road")
        # start each track where the road would be after driving at the CAN speed
        guess = self._predict(p0[:, 0].astype(np.float64), can if math.isfinite(can) else 0.0, dt)
        lk = {"winSize": (15, 15), "maxLevel": 1}
        p1, st, _ = cv2.calcOpticalFlowPyrLK(
            prev, gray, p0, guess.reshape(-1, 1, 2).astype(np.float32),
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk,
        )  # fmt: skip
        pb, stb, _ = cv2.calcOpticalFlowPyrLK(
            gray, prev, p1, p0.copy(), flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk
        )
        good = (st[:, 0] == 1) & (stb[:, 0] == 1) & (np.linalg.norm(pb - p0, axis=2)[:, 0] < 0.5)
        a = self._road_points(self.camera.unproject(p0[good, 0].astype(np.float64)))
        b = self._road_points(self.camera.unproject(p1[good, 0].astype(np.float64)))
        fin = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        a, b = a[fin], b[fin]
        if len(a) < self.min_inliers:
            return self._fallback(k, t_s, dt, can, "too few tracks")
        M, inl = cv2.estimateAffinePartial2D(
            a.astype(np.float32), b.astype(np.float32), method=cv2.RANSAC,
            ransacReprojThreshold=self.ransac_m, maxIters=500, confidence=0.999,
        )  # fmt: skip
        n_in = int(inl.sum()) if inl is not None else 0
        if M is None or n_in < self.min_inliers:
            return self._fallback(k, t_s, dt, can, "no rigid road motion found")
        # b = M a: the road moves by the inverse of the car's motion, p_b = R(-psi)(p_a - d)
        theta = math.atan2(M[1, 0], M[0, 0])
        psi = -theta
        c, s = math.cos(psi), math.sin(psi)
        d = -np.array([[c, -s], [s, c]]) @ M[:, 2]
        return EgoMotionRecord.from_rates(
            k, t_s, dt, float(d[0] / dt), psi / dt, self.mount,
            can_speed_mps=can, n_points=len(a), n_inliers=n_in,
        )  # fmt: skip

    def _predict(self, px: np.ndarray, speed_mps: float, dt: float) -> np.ndarray:
        """(N, 2) pixels where the road points under px (N, 2) are after the car drove
        speed_mps * dt straight on (px itself where a pixel does not see the road)."""
        xy = self._road_points(self.camera.unproject(px))
        xy[:, 0] -= speed_mps * dt
        R = np.asarray(self.mount.R_car_cam, float)
        h = float(self.mount.position_m[2])
        P_car = np.column_stack([xy, np.full(len(xy), -h)])  # from the camera, car axes
        w = self.camera.project(P_car @ R)  # camera axes: R^T p
        ok = np.all(np.isfinite(w), axis=1)
        return np.where(ok[:, None], w, px)

    def _fallback(self, k: int, t_s: float, dt: float, can: float, why: str):
        speed = can if math.isfinite(can) else math.nan
        return EgoMotionRecord.from_rates(
            k, t_s, dt, speed, 0.0, self.mount, can_speed_mps=can, degraded=True, reason=why
        )
