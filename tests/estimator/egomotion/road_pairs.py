"""Synthetic image pairs of a known motion for the estimator's tests (no renderer).

The pairs come from `estimator.synthetic`: each pixel's ray is intersected with the road in
the true pose of each frame (sim.camera_motion, with vibration) and samples a seeded
procedural texture. Both frames are band-limited for the view of frame A (``lod_from``), so
the road's brightness is a fixed function of the world point: the pair obeys brightness
constancy up to 8-bit quantisation and interpolation. A box of pixels may see a textured
plane above the road instead (`raised_pair`, `slow_raised_frames`).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from estimator.camera.files import load_camera
from estimator.egomotion.ego_estimator import EgoMotionRecord
from estimator.egomotion.homography import make_state
from estimator.synthetic import RoadTexture, pixel_angle_rad, render_road, to_uint8
from sim.camera_motion import T_world_car, Vibration, camera_pose, motion_between

FPS = 15.0
DT = 1.0 / FPS
SPEED = 25.0  # [m/s]
YAW_RATE = 0.15  # [rad/s]
CAN_SCALE = 1.08  # CAN speed +8 %


@cache
def preset_camera(preset: str):
    camera, mount = load_camera(preset)
    return camera, mount, pixel_angle_rad(camera)


def drive_pose(mount, t_s: float):
    vib = Vibration(0.3, 2.0, 0.4, 1.3)  # [deg], [Hz]: A != 0
    yaw = YAW_RATE * t_s
    x, y = SPEED / YAW_RATE * np.sin(yaw), SPEED / YAW_RATE * (1 - np.cos(yaw))
    return camera_pose(T_world_car(x, y, yaw), mount, vib, t_s)


@cache
def road_pair(preset: str, seed: int = 0, t0: float = 0.3):
    """(A, B) uint8 images and the true state from frame A to frame B."""
    camera, mount, angle = preset_camera(preset)
    a, b = drive_pose(mount, t0), drive_pose(mount, t0 + DT)
    tex = RoadTexture(seed=seed)
    img_a = render_road(camera, a.T_world_actual, tex, pixel_angle=angle, lod_from=a.T_world_actual)
    img_b = render_road(camera, b.T_world_actual, tex, pixel_angle=angle, lod_from=a.T_world_actual)
    ms = motion_between(a, b, DT)
    return to_uint8(img_a), to_uint8(img_b), make_state(ms.V_mps, ms.W_rps, ms.A_rad)


def raised_pair(preset: str, t0: float, box: tuple[int, int, int, int], height_m: float):
    """Frames at t0 and t0 + DT where the pixels of box (u0, v0, w, h) see a textured plane
    ``height_m`` above the road (a long low wall's top along the road), the rest the road."""
    camera, mount, angle = preset_camera(preset)
    tex, tex_top = RoadTexture(seed=0), RoadTexture(seed=5)
    a, b = drive_pose(mount, t0), drive_pose(mount, t0 + DT)
    lower = np.eye(4)
    lower[2, 3] = -height_m  # the raised plane is the road seen from height_m lower
    u0, v0, w, h = box
    out = []
    for p in (a, b):
        img = render_road(
            camera, p.T_world_actual, tex, pixel_angle=angle, lod_from=a.T_world_actual
        )
        top = render_road(
            camera,
            lower @ p.T_world_actual,
            tex_top,
            pixel_angle=angle,
            lod_from=lower @ a.T_world_actual,
        )
        img[v0 : v0 + h, u0 : u0 + w] = top[v0 : v0 + h, u0 : u0 + w]
        out.append(to_uint8(img))
    return out


def slow_raised_frames(n: int, speed: float, box, height_m: float):
    """n frames of a straight drive at speed [m/s] (omni-near, vibrating) where the pixels of
    box (u0, v0, w, h) see a textured plane height_m above the road (a kerb's top)."""
    camera, mount, angle = preset_camera("omni-near")
    tex, tex_top = RoadTexture(seed=0), RoadTexture(seed=5)
    vib = Vibration(0.3, 2.0, 0.4, 1.3)
    lower = np.eye(4)
    lower[2, 3] = -height_m
    poses = [
        camera_pose(T_world_car(speed * k * DT, 0.0, 0.0), mount, vib, k * DT) for k in range(n)
    ]
    u0, v0, w, h = box
    frames = []
    for p in poses:
        T = p.T_world_actual
        img = render_road(camera, T, tex, pixel_angle=angle, lod_from=poses[0].T_world_actual)
        top = render_road(
            camera, lower @ T, tex_top, pixel_angle=angle, lod_from=lower @ poses[0].T_world_actual
        )
        img[v0 : v0 + h, u0 : u0 + w] = top[v0 : v0 + h, u0 : u0 + w]
        frames.append(to_uint8(img))
    return frames


def state_errors(rec: EgoMotionRecord, x_true: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(|dV|/|V| [%], |dW| per axis [deg/s], |dA| per axis [deg])."""
    d = rec.x - x_true
    return (
        100 * np.linalg.norm(d[:3]) / np.linalg.norm(x_true[:3]),
        np.degrees(np.abs(d[3:6])),
        np.degrees(np.abs(d[6:9])),
    )
