"""Synthetic road images with known motion, without a renderer (for tests and the bench).

Each pixel's ray (``camera.pixel_rays()``, actual camera frame) is turned into
the world by the camera pose, intersected with the road plane z = 0 and looks
up a procedural road texture: seeded multi-scale value noise in world
coordinates (`RoadTexture`), band-limited per pixel (octaves finer than the
pixel's footprint on the road fade out, so that far road does not alias).
Rays that miss the road see a flat sky; pixels outside the camera's valid mask
are black.

Also `drive_poses`: camera poses of a car on a circular arc with roll/pitch
vibration of the camera on its mount, built from `estimator.geometry` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.geometry import make_T, rot_z, so3_exp

_LATTICE = 256  # [cells] side of each octave's random lattice (tiled)


@dataclass
class RoadTexture:
    """Seeded multi-scale value noise on the road plane, intensity ~ 128 +- 60 [DN].

    cells_m: cell size of each octave [m]; amplitudes: their std [DN].
    """

    seed: int = 0
    cells_m: tuple[float, ...] = (0.04, 0.1, 0.25, 0.6, 1.5, 4.0)
    amplitudes: tuple[float, ...] = (22.0, 22.0, 20.0, 16.0, 14.0, 12.0)
    mean: float = 128.0
    _lattices: list[np.ndarray] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rng = np.random.default_rng([self.seed, 0x7E47])
        # unit-std lattice values; cubic interpolation keeps ~0.6 of the std
        self._lattices = [
            rng.standard_normal((_LATTICE, _LATTICE)).astype(np.float32) for _ in self.cells_m
        ]

    def sample(self, xy_m: np.ndarray, footprint_m: np.ndarray | None = None) -> np.ndarray:
        """(N,) float32 intensity at road points xy_m (N, 2) [m].

        footprint_m: (N,) size of the pixel on the road [m]; an octave fades out
        between cell = 2 and cell = 1 footprint (band limit against aliasing).
        """
        xy = np.asarray(xy_m, dtype=np.float64)
        out = np.full(len(xy), self.mean, np.float32)
        for cell, amp, lat in zip(self.cells_m, self.amplitudes, self._lattices, strict=True):
            g = np.mod(xy / cell, _LATTICE).astype(np.float32)
            val = _remap_points(lat, g)
            w = np.float32(amp / 0.6)
            if footprint_m is not None:
                w = w * np.clip(cell / np.maximum(footprint_m, 1e-9) - 1.0, 0.0, 1.0)
            out += w * val
        return out


def _remap_points(img: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(N,) bicubic, wrapped samples of img at (N, 2) float32 (col, row) coordinates."""
    n = len(g)
    cols = 4096
    rows = max(1, -(-n // cols))
    m = np.zeros((rows * cols, 2), np.float32)
    m[:n] = g
    m = m.reshape(rows, cols, 2)
    out = cv2.remap(img, m, None, cv2.INTER_CUBIC, borderMode=cv2.BORDER_WRAP)
    return out.reshape(-1)[:n]


def pixel_angle_rad(camera: CameraModel) -> np.ndarray:
    """(H, W) angle between a pixel's ray and its neighbours' (the larger of u, v) [rad]."""
    rays = camera.pixel_rays().astype(np.float64)
    du = np.linalg.norm(np.gradient(rays, axis=1), axis=-1)
    dv = np.linalg.norm(np.gradient(rays, axis=0), axis=-1)
    return np.nan_to_num(np.maximum(du, dv), nan=0.0)


def render_road(
    camera: CameraModel,
    T_world_actual: np.ndarray,
    texture: RoadTexture,
    sky: float = 200.0,
    pixel_angle: np.ndarray | None = None,
    lod_from: np.ndarray | None = None,
) -> np.ndarray:
    """(H, W) float32 image [DN] of the textured road seen from the actual camera pose (4, 4).

    lod_from: (4, 4) camera pose whose pixel footprints set the texture's band
    limit (default: this pose). Giving the same pose for a pair of frames makes
    the road's brightness a fixed function of the world point in both (exact
    brightness constancy); by default each frame is band-limited for its own view.
    """
    rays = camera.pixel_rays().astype(np.float64).reshape(-1, 3)
    if pixel_angle is None:
        pixel_angle = pixel_angle_rad(camera)
    R, o = T_world_actual[:3, :3], T_world_actual[:3, 3]
    d = rays @ R.T
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(d[:, 2] < -1e-6, -o[2] / d[:, 2], np.inf)
    hit = np.isfinite(t) & (t < 5000.0)
    img = np.full(len(rays), sky, np.float32)
    xy = o[:2] + t[hit, None] * d[hit, :2]
    if lod_from is None:
        foot = t[hit] * pixel_angle.reshape(-1)[hit] / np.maximum(-d[hit, 2], 1e-3)
    else:
        foot = _footprint_from(camera, lod_from, xy, pixel_angle)
    img[hit] = texture.sample(xy, foot)
    img[~camera.valid_mask().reshape(-1)] = 0.0
    return img.reshape(camera.height, camera.width)


def _footprint_from(
    camera: CameraModel, T_world_cam: np.ndarray, xy: np.ndarray, pixel_angle: np.ndarray
) -> np.ndarray:
    """(N,) footprint [m] that road points xy (N, 2) have in the view of pose T_world_cam."""
    R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
    P = np.column_stack([xy - o[:2], np.full(len(xy), -o[2])])  # viewpoint -> point, world
    t = np.linalg.norm(P, axis=1)
    w = np.nan_to_num(camera.project(P @ R), nan=-1.0)  # pixel in that view
    u = np.clip(np.rint(w[:, 0]), 0, camera.width - 1).astype(int)
    v = np.clip(np.rint(w[:, 1]), 0, camera.height - 1).astype(int)
    ang = pixel_angle[v, u]
    return t * ang / np.maximum(o[2] / t, 1e-3)


def to_uint8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class DrivePoses:
    """Poses of a synthetic drive: t_s (n,), T_world_nominal / T_world_actual (n, 4, 4),
    A_cam_rad (n, 3) vibration angle in the nominal camera frame, speed_mps (n,)."""

    t_s: np.ndarray
    T_world_nominal: np.ndarray
    T_world_actual: np.ndarray
    A_cam_rad: np.ndarray
    speed_mps: np.ndarray


def drive_poses(
    mount: CameraMount,
    t_s: np.ndarray,
    speed_mps: float,
    yaw_rate_rps: float,
    vib_amplitude_deg: float = 0.3,
    vib_frequency_hz: float = 2.0,
    vib_phase_rad: tuple[float, float] = (0.4, 1.3),
) -> DrivePoses:
    """Camera poses of a car at constant speed and yaw rate, with roll/pitch vibration.

    The car starts at the origin heading along world x; vibration rotates the
    actual camera about the car's x (roll) and y (pitch, at 1.37x the frequency)
    axes: ``R_nominal_actual = exp([A]x)`` (docs/CONVENTIONS.md).
    """
    t = np.asarray(t_s, dtype=float)
    yaw = yaw_rate_rps * t
    if abs(yaw_rate_rps) > 1e-9:
        x = speed_mps / yaw_rate_rps * np.sin(yaw)
        y = speed_mps / yaw_rate_rps * (1.0 - np.cos(yaw))
    else:
        x, y = speed_mps * t, np.zeros_like(t)
    amp, w = np.radians(vib_amplitude_deg), 2.0 * np.pi * vib_frequency_hz
    T_n, T_a, A = [], [], []
    for k in range(len(t)):
        T_wn = make_T(rot_z(yaw[k]), (x[k], y[k], 0.0)) @ mount.T_car_cam
        A_car = np.array(
            [
                amp * np.sin(w * t[k] + vib_phase_rad[0]),
                amp * np.sin(1.37 * w * t[k] + vib_phase_rad[1]),
                0.0,
            ]
        )
        A_cam = mount.R_car_cam.T @ A_car
        T_wa = T_wn.copy()
        T_wa[:3, :3] = T_wn[:3, :3] @ so3_exp(A_cam)
        T_n.append(T_wn)
        T_a.append(T_wa)
        A.append(A_cam)
    return DrivePoses(t, np.array(T_n), np.array(T_a), np.array(A), np.full(len(t), speed_mps))
