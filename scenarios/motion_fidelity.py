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
from scipy import ndimage

from estimator import fileio as io
from estimator.camera.files import load_camera
from estimator.camera.models import CameraModel

RANGE_BANDS_M = (0.0, 10.0, 20.0, 40.0, np.inf)  # [m] along the ray at the patch centre
MIN_TEXTURE_DN = 1.0  # [DN/px] least RMS gradient of a patch worth a measurement, 0..10
WARP_REACH_PX = 2  # [px] margin the cubic-spline resampling of frame k+1 reads, 2..8
SHIFT_ITERATIONS = 10  # [-] most Gauss-Newton steps of a patch's registration, 1..50
SHIFT_TOL_PX = 1e-4  # [px] a step this small ends the registration, 1e-6..1e-2
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


def register_shift(patch_a: np.ndarray, region_b: np.ndarray) -> np.ndarray:
    """(2,) shift e [px] (x, y) with b(x + e) = patch_a(x), for patch_a (P, P) and region_b
    (P + 2m, P + 2m) float32, b's pixels around the patch with a margin of m =
    WARP_REACH_PX (b resampled reads true pixels, not a border rule): Gauss-Newton on the
    Hanning-windowed squared difference; NaN where patch_a is too plain (RMS gradient below
    MIN_TEXTURE_DN), its texture cannot fix both axes or the shift leaves the margin."""
    P, m = patch_a.shape[0], WARP_REACH_PX
    if region_b.shape != (P + 2 * m, P + 2 * m):
        raise ValueError(f"region_b is {region_b.shape}, expected {(P + 2 * m,) * 2}")
    win = np.outer(np.hanning(P), np.hanning(P)).ravel()
    gy, gx = np.gradient(patch_a.astype(np.float64))
    if np.sqrt(np.mean(gx**2 + gy**2)) < MIN_TEXTURE_DN:
        return np.full(2, np.nan)
    J = np.stack([gx.ravel(), gy.ravel()], axis=1)  # (P*P, 2)
    Jw = J * win[:, None]
    A = Jw.T @ J
    if np.linalg.cond(A) > 1e12:
        return np.full(2, np.nan)
    coeffs = ndimage.spline_filter(region_b.astype(np.float64), order=3, mode="mirror")
    e = np.zeros(2)
    for _ in range(SHIFT_ITERATIONS):
        # b at x + e, exactly (cubic B-spline; OpenCV's remap rounds to 1/32 px)
        shifted = ndimage.shift(coeffs, (-e[1], -e[0]), order=3, mode="mirror", prefilter=False)
        shifted = shifted[m : m + P, m : m + P]
        step = np.linalg.solve(A, Jw.T @ (patch_a - shifted).ravel())
        e += step
        if np.abs(step).max() < SHIFT_TOL_PX or np.abs(e).max() > m - 1:
            break
    return e if np.abs(e).max() <= m - 1 else np.full(2, np.nan)


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
    # cubic spline at the exact coordinates (OpenCV's remap rounds them to 1/32 px)
    warped = ndimage.map_coordinates(
        b, (mm[..., 1], mm[..., 0]), order=3, mode="nearest", output=np.float32
    )
    # frame b must see the road point on the bare road too, with the kernel's reach of it
    k = 2 * WARP_REACH_PX + 1
    road_b = cv2.erode((on_road_b & camera.valid_mask()).astype(np.uint8), np.ones((k, k)))
    road_b = cv2.remap(road_b, mm, None, cv2.INTER_NEAREST)
    good = on_road_a & camera.valid_mask() & inside & (road_b > 0)
    half = patch_px // 2
    rows, motions, errors, ranges = [], [], [], []
    mg = WARP_REACH_PX  # frame b's patch is read with the resampling kernel's margin
    for r in range(mg, H - patch_px - mg + 1, stride_px):
        for c in range(mg, W - patch_px - mg + 1, stride_px):
            if not good[r - mg : r + patch_px + mg, c - mg : c + patch_px + mg].all():
                continue
            pa = a[r : r + patch_px, c : c + patch_px]
            pb = warped[r - mg : r + patch_px + mg, c - mg : c + patch_px + mg]
            # warped(x) = a(x - e) for a render error e: registration finds warped(x + e) = a(x)
            dx, dy = register_shift(pa, pb)
            if not np.isfinite(dx + dy):
                continue
            cr, cc = r + half, c + half
            rows.append(cr)
            errors.append((float(dx), float(dy)))
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


def exact_road_errors(
    camera: str = "omni-near", frames: int = 7, shortfall: float = 0.0
) -> PatchErrors:
    """Patch errors of exact images: a synthetic road (`estimator.synthetic.render_road`,
    one band limit for both frames, so that its brightness is a fixed function of the
    world point) seen from a camera preset driving at 12 m/s and 0.1 rad/s; frame b's
    camera moved (1 - shortfall) of the way. Its figures are the measurement's own floor."""
    from estimator.camera.files import resolve_camera
    from estimator.synthetic import RoadTexture, drive_poses, render_road, to_uint8

    cam, mount = resolve_camera(camera)
    t = np.arange(frames) / 15.0
    poses = drive_poses(mount, t, speed_mps=12.0, yaw_rate_rps=0.1)
    tex = RoadTexture(seed=3)
    road = np.ones((cam.height, cam.width), bool)
    parts = []
    for k in range(len(t) - 1):
        Ta, Tb = poses.T_world_actual[k], poses.T_world_actual[k + 1]
        a = to_uint8(render_road(cam, Ta, tex, lod_from=Ta))
        moved = Tb.copy()
        moved[:3, 3] = Ta[:3, 3] + (1.0 - shortfall) * (Tb[:3, 3] - Ta[:3, 3])
        b = to_uint8(render_road(cam, moved, tex, lod_from=Ta))
        p = pair_errors(cam, a, b, Ta, Tb, road, road)
        p.frame[:] = k
        parts.append(p)
    return PatchErrors.concat(parts)


def _with_median(errors: PatchErrors) -> dict:
    n = np.linalg.norm(errors.error_px, axis=1)
    return {**summary(errors), "median_abs_px": float(np.median(n)) if len(n) else float("nan")}


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
    (name, face_px) into out_dir and measure it; {"exact": the measurement's floor on
    exact images of the same camera, "plane": summary, "cube-512": ...}."""
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
    results = {"exact": _with_median(exact_road_errors(camera))}
    for name, face in renderers:
        label = name if face is None else f"{name}-{face}"
        drive = Path(out_dir) / f"{camera}-{label}"
        res = render_drive(sc, drive, progress=False, face_px=face, renderer=name)
        results[label] = {
            **_with_median(patch_errors(drive)),
            "render_ms_per_frame": res.render_ms_per_frame,
        }
    return results
