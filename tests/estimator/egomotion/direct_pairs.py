"""Helpers of the DirectEstimator tests: one frame pair through a fresh estimator
(`run_pair`), a turning car's pair (`turn_pair`) and a textured patch pasted into a pair
(`with_moving_patch`). The pairs come from `tests.estimator.egomotion.road_pairs`."""

from __future__ import annotations

import numpy as np

from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import DirectConfig
from estimator.egomotion.ego_estimator import EgoMotionRecord
from estimator.synthetic import RoadTexture, render_road, to_uint8
from sim.camera_motion import T_world_car, Vibration, camera_pose, motion_between
from tests.estimator.egomotion.road_pairs import CAN_SCALE, DT, SPEED, preset_camera


def run_pair(
    preset: str,
    img_a,
    img_b,
    t0: float = 0.3,
    config: DirectConfig | None = None,
    can=SPEED * CAN_SCALE,
) -> tuple[DirectEstimator, EgoMotionRecord]:
    """(estimator, record of the pair) of a fresh estimator of the preset's camera (its
    kind's default config unless given) stepped through img_a at t0 [s] and img_b one
    frame later, with the CAN speed can [m/s] (8 % high by default)."""
    camera, mount, _ = preset_camera(preset)
    est = DirectEstimator(camera, mount, config)
    first = est.step(img_a, t0, can)
    assert first.flags == ("init",) and not first.degraded
    return est, est.step(img_b, t0 + DT, can)


def turn_pair(camera, mount, angle, speed, yaw_rate, t0, lever_m=0.0):
    """(A, B) uint8 frames and the true motion of a car turning on a circle at yaw_rate
    [rad/s]: its point lever_m [m] behind the car origin (the rear axle) moves at speed."""

    def pose(t: float):
        yaw = yaw_rate * t
        ax, ay = speed / yaw_rate * np.sin(yaw), speed / yaw_rate * (1 - np.cos(yaw))
        x, y = ax + lever_m * np.cos(yaw), ay + lever_m * np.sin(yaw)
        return camera_pose(T_world_car(x, y, yaw), mount, Vibration(0.3, 2.0, 0.4, 1.3), t)

    a, b = pose(t0), pose(t0 + DT)
    tex = RoadTexture(seed=3)
    img_a = render_road(camera, a.T_world_actual, tex, pixel_angle=angle, lod_from=a.T_world_actual)
    img_b = render_road(camera, b.T_world_actual, tex, pixel_angle=angle, lod_from=a.T_world_actual)
    return to_uint8(img_a), to_uint8(img_b), motion_between(a, b, DT)


def with_moving_patch(
    img_a: np.ndarray, img_b: np.ndarray, box: tuple[int, int, int, int], shift: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Paste a textured patch at box (u0, v0, w, h) in A and shifted by (du, dv) px in B."""
    u0, v0, w, h = box
    rng = np.random.default_rng(7)
    patch = np.clip(128 + 60 * rng.standard_normal((h // 4 + 1, w // 4 + 1)), 0, 255)
    patch = np.kron(patch, np.ones((4, 4)))[:h, :w].astype(np.uint8)
    a, b = img_a.copy(), img_b.copy()
    a[v0 : v0 + h, u0 : u0 + w] = patch
    b[v0 + shift[1] : v0 + shift[1] + h, u0 + shift[0] : u0 + shift[0] + w] = patch
    return a, b
