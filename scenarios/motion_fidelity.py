"""Does the road move in the rendered images as the exact homography says? (No estimator.)

For a pair of consecutive frames of a drive rendered without sensor effects, frame k+1
is warped into frame k by the exact plane-induced map of the ground truth: a pixel x of
frame k sees the road point X (its ray meets z = 0 at frame k's actual pose), which frame
k+1 sees at x' (projected at its actual pose); warped(x) = I_k+1(x'). Were the images
exact, warped would equal I_k on the road. Road patches (patch_px square, only road
plane: no vehicle, nothing above the road, valid pixels) of I_k and warped are compared
by phase correlation (OpenCV, Hanning window): the shift found is the renderer's error
of the motion at that patch [px], against the exact motion (x' - x at the patch centre).

`patch_errors` measures a drive; `summary` gives the mean of the error along the motion
(a renderer that pulls the motion towards zero gives a negative mean), its RMS (the error
vector's length) and both per range band.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from estimator import fileio as io
from estimator.camera.files import load_camera
from estimator.camera.models import CameraModel

RANGE_BANDS_M = (0.0, 10.0, 20.0, 40.0, np.inf)  # [m] along the ray at the patch centre
MIN_TEXTURE_DN = 1.0  # [DN/px] least RMS gradient of a patch worth a measurement, 0..10
WARP_REACH_PX = 4  # [px] reach of the Lanczos-4 kernel that warps frame k+1
NEARER = 0.97  # [-] a range below this fraction of the plane's is something on the road


@dataclass
class PatchErrors:
    """Per patch (M,): range_m along the centre's ray [m], motion_px (M, 2) exact image
    motion of the centre from frame k to k+1 [px], error_px (M, 2) measured minus exact
    [px], frame (M,) k."""

    range_m: np.ndarray
    motion_px: np.ndarray
    error_px: np.ndarray
    frame: np.ndarray

    @classmethod
    def concat(cls, parts: list[PatchErrors]) -> PatchErrors:
        return cls(*(np.concatenate([getattr(p, f) for p in parts]) for f in cls.__annotations__))


def plane_map(
    camera: CameraModel, T_world_a: np.ndarray, T_world_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 2) float32 pixel of frame b that sees the road point of each pixel of frame a
    (NaN where a's ray misses the road plane), and (H, W) float32 range of a's ray [m]."""
    rays = camera.pixel_rays().reshape(-1, 3).astype(np.float64)
    d = rays @ T_world_a[:3, :3].T
    o = T_world_a[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.nan)
    X = o + t[:, None] * d
    P_b = (X - T_world_b[:3, 3]) @ T_world_b[:3, :3]
    w_b = camera.project(P_b)
    H, W = camera.height, camera.width
    return w_b.reshape(H, W, 2).astype(np.float32), t.reshape(H, W).astype(np.float32)


def pair_errors(
    camera: CameraModel,
    image_a: np.ndarray,
    image_b: np.ndarray,
    T_world_a: np.ndarray,
    T_world_b: np.ndarray,
    on_road_a: np.ndarray,
    on_road_b: np.ndarray,
    patch_px: int = 32,
    stride_px: int = 8,
) -> PatchErrors:
    """Patch errors of one pair of frames (images (H, W, 3) uint8 or (H, W) gray).

    on_road_a, on_road_b: (H, W) bool, pixels of each frame that see the bare road plane.
    """
    gray = [
        cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im for im in (image_a, image_b)
    ]
    a, b = (g.astype(np.float32) for g in gray)
    m, rng = plane_map(camera, T_world_a, T_world_b)
    H, W = a.shape
    inside = (
        np.isfinite(m[..., 0])
        & (m[..., 0] >= 1)
        & (m[..., 0] <= W - 2)
        & (m[..., 1] >= 1)
        & (m[..., 1] <= H - 2)
    )
    mm = np.nan_to_num(m, nan=-1.0)
    warped = cv2.remap(b, mm, None, cv2.INTER_LANCZOS4)
    # frame b must see the road point on the bare road too, with the kernel's reach of it
    k = 2 * WARP_REACH_PX + 1
    road_b = cv2.erode((on_road_b & camera.valid_mask()).astype(np.uint8), np.ones((k, k)))
    road_b = cv2.remap(road_b, mm, None, cv2.INTER_NEAREST)
    good = on_road_a & camera.valid_mask() & inside & (road_b > 0)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-6)
    half = patch_px // 2
    rows, motions, errors, ranges = [], [], [], []
    for r in range(0, H - patch_px + 1, stride_px):
        for c in range(0, W - patch_px + 1, stride_px):
            if not good[r : r + patch_px, c : c + patch_px].all():
                continue
            pa = a[r : r + patch_px, c : c + patch_px]
            pb = warped[r : r + patch_px, c : c + patch_px]
            gy, gx = np.gradient(pa)
            if np.sqrt(np.mean(gx**2 + gy**2)) < MIN_TEXTURE_DN:
                continue
            # warped(x) = a(x - e) for a render error e: ECC finds warped(x + e) = a(x)
            try:
                _, warp = cv2.findTransformECC(
                    pa,
                    pb,
                    np.eye(2, 3, dtype=np.float32),
                    cv2.MOTION_TRANSLATION,
                    criteria,
                    None,
                    1,
                )
            except cv2.error:  # did not converge: no measurement
                continue
            dx, dy = float(warp[0, 2]), float(warp[1, 2])
            cr, cc = r + half, c + half
            rows.append(cr)
            errors.append((dx, dy))
            motions.append(m[cr, cc] - (cc, cr))
            ranges.append(rng[cr, cc])
    n = len(rows)
    return PatchErrors(
        np.asarray(ranges, np.float64).reshape(n),
        np.asarray(motions, np.float64).reshape(n, 2),
        np.asarray(errors, np.float64).reshape(n, 2),
        np.zeros(n, np.int64),
    )


def patch_errors(drive_dir: Path, patch_px: int = 32, stride_px: int = 8) -> PatchErrors:
    """Patch errors over every consecutive pair of a rendered drive (its frames, ids,
    range and ground truth); the drive should be rendered without sensor effects."""
    drive_dir = Path(drive_dir)
    camera, _ = load_camera(drive_dir / "camera.yaml")
    gt = [json.loads(line) for line in (drive_dir / "groundtruth.jsonl").read_text().splitlines()]
    rays = camera.pixel_rays().reshape(-1, 3).astype(np.float64)

    def on_road(k: int) -> np.ndarray:
        """The bare road: no vehicle, and nothing nearer than the plane (a guard-rail, a
        post: 3 % nearer is far beyond the depth buffer's error on the plane)."""
        T = np.asarray(gt[k]["T_world_cam_actual"], float)
        ids = io.read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        rng_m = io.read_png(drive_dir / "range" / f"{k:06d}.png").astype(np.float64) / 100.0
        d = rays @ T[:3, :3].T
        with np.errstate(divide="ignore", invalid="ignore"):
            t_plane = np.where(d[:, 2] < 0, -T[2, 3] / d[:, 2], np.inf).reshape(ids.shape)
            return (ids < 0) & (rng_m > NEARER * t_plane)

    parts = []
    road = [on_road(k) for k in range(len(gt))]
    for k in range(len(gt) - 1):
        p = pair_errors(
            camera,
            io.read_png(drive_dir / "frames" / f"{k:06d}.png"),
            io.read_png(drive_dir / "frames" / f"{k + 1:06d}.png"),
            np.asarray(gt[k]["T_world_cam_actual"], float),
            np.asarray(gt[k + 1]["T_world_cam_actual"], float),
            road[k],
            road[k + 1],
            patch_px,
            stride_px,
        )
        p.frame[:] = k
        parts.append(p)
    return PatchErrors.concat(parts)


def summary(e: PatchErrors) -> dict:
    """Mean error along the motion [px] (negative: the image moves less than the road),
    RMS of the error vector [px] and the patch count, overall and per range band."""

    def stats(sel: np.ndarray) -> dict:
        mot = e.motion_px[sel]
        unit = mot / np.maximum(np.linalg.norm(mot, axis=1, keepdims=True), 1e-9)
        along = np.sum(e.error_px[sel] * unit, axis=1)
        return {
            "patches": int(sel.sum()),
            "mean_along_motion_px": float(np.mean(along)) if sel.any() else float("nan"),
            "rms_px": float(np.sqrt(np.mean(np.sum(e.error_px[sel] ** 2, axis=1))))
            if sel.any()
            else float("nan"),
            "mean_motion_px": float(np.mean(np.linalg.norm(mot, axis=1)))
            if sel.any()
            else float("nan"),
        }

    out = stats(np.ones(len(e.range_m), bool))
    out["bands"] = {}
    for lo, hi in zip(RANGE_BANDS_M[:-1], RANGE_BANDS_M[1:], strict=True):
        out["bands"][f"{lo:g}-{hi:g} m"] = stats((e.range_m >= lo) & (e.range_m < hi))
    return out


def bench_fidelity(
    out_dir: Path,
    camera: str = "omni-far",
    frames: int = 40,
    seed: int = 11,
    renderers: tuple[tuple[str, int | None], ...] = (
        ("plane", None),
        ("cube", 512),
        ("cube", 1024),
    ),
) -> dict:
    """Render one highway-v0 drive (30 vehicles, no sensor effects) with each renderer
    (name, face_px) into out_dir and measure it; {"plane": summary, "cube-512": ...}."""
    from sim.drive import render_drive
    from sim.scenario import Scenario, SensorConfig

    sc = Scenario(
        name="fidelity",
        env="highway-v0",
        env_config={"vehicles_count": 30, "lanes_count": 4},
        seed=seed,
        duration_s=frames / 15.0,
        fps=15.0,
        camera=camera,
        sensor=SensorConfig.exact(),
    )
    results = {}
    for name, face in renderers:
        label = name if face is None else f"{name}-{face}"
        drive = Path(out_dir) / f"{camera}-{label}"
        res = render_drive(sc, drive, progress=False, face_px=face, renderer=name)
        errors = patch_errors(drive)
        n = np.linalg.norm(errors.error_px, axis=1)
        results[label] = {
            **summary(errors),
            "median_abs_px": float(np.median(n)) if len(n) else float("nan"),
            "render_ms_per_frame": res.render_ms_per_frame,
        }
    return results
