"""What a two-frame motion test can see at all: per evaluated vehicle of a rendered drive,
the pixels whose scene point moved unlike any static point on their ray.

A pixel of frame k sees a point of a vehicle (id and range images). Its material point
was, ``baseline`` frames earlier, where the vehicle's rigid motion over the ground puts it
(ground truth); a static point at height z on the pixel's ray would have been elsewhere.
The pixel's **motion evidence** is the smallest distance [px] between the two over the
static heights a detector tests (0..2h/3 above the road, the motion hypotheses lambda 1..3
of `estimator.surround.detection`). A pixel whose evidence is below a test's registration
error looks static to every test that compares two frames; a vehicle with too few evident
pixels is beyond them all. The bound ignores texture (a flat body shows its motion only at
its edges: `evident_edge_px` counts the evident pixels on an edge of the frame).

A pixel without motion evidence may still **stand** above the road: its earlier pixel
lies on the static curve but away from the road's own prediction (`pixel_road_px` >=
EVIDENT_PX). A vehicle the ego car overtakes slowly looks like that over most of its
body: a test for structure standing on the road (plane parallax, whatever moves) could see
it where a motion test cannot; `standing_px` counts such pixels, and the summary the
vehicle-frames with enough evident or standing pixels (the bound of "motion or height").

    python -m scenarios.motion_evidence DRIVE_DIR [--baseline 2] [--every 3]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.camera.models import CameraModel
from estimator.fileio import read_png
from estimator.geometry import rot_z
from estimator.surround.detection import DetectorConfig, VehicleDetector
from scenarios.point_audit import camera_unit_rays
from scenarios.runner import gt_evaluation_set
from sim.drive import load_groundtruth

STATIC_HEIGHTS = 41  # [-] static heights sampled over 0..z_max (spacing z_max/40)
_DETECTOR = DetectorConfig()
# [px] full resolution: one pixel of the detector's working scale
EVIDENT_PX = float(_DETECTOR.scale)
# [grey level/px] gradient of an edge: the detector's refinement's
EDGE_GREY_PER_PX = _DETECTOR.refine_min_gradient
# [-] the highest static point tested, as a share of the camera's height: lambda = h/(h - z)
Z_MAX_PER_H = 1.0 - 1.0 / max(_DETECTOR.static_lambdas)


def _camera_points(P_world: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """(N, 3) world points -> camera axes of the pose T_world_cam (4, 4)."""
    return (P_world - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]


def pixel_evidence_px(
    camera: CameraModel,
    T_world_cam: np.ndarray,
    T_world_cam_early: np.ndarray,
    P_world: np.ndarray,
    P_world_early: np.ndarray,
    z_max_m: float,
) -> np.ndarray:
    """(N,) motion evidence [px] of scene points seen at P_world (N, 3) now that were at
    P_world_early (N, 3) in the earlier frame: the distance of their earlier pixel from
    the curve of earlier pixels of a static point at height 0..z_max_m [m] on the same ray
    (world z up, the road at z = 0; the curve as a polyline through STATIC_HEIGHTS
    samples). NaN for rays that do not meet that height range below the camera."""
    centre = T_world_cam[:3, 3]
    ray = P_world - centre  # world directions of the pixels' rays
    w_true = camera.project(_camera_points(P_world_early, T_world_cam_early))
    best = np.full(len(P_world), np.inf)
    down = ray[:, 2] < 0
    a = None
    for z in np.linspace(0.0, z_max_m, STATIC_HEIGHTS):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (z - centre[2]) / ray[:, 2]
        b = camera.project(_camera_points(centre + s[:, None] * ray, T_world_cam_early))
        if a is not None:  # the nearest point of the segment a-b
            ab = b - a
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.clip(np.sum((w_true - a) * ab, axis=1) / np.sum(ab * ab, axis=1), 0, 1)
            t = np.nan_to_num(t)  # a zero-length segment: its point
            best = np.fmin(best, np.hypot(*(w_true - a - t[:, None] * ab).T))
        a = b
    best[~down | ~np.isfinite(best)] = np.nan
    return best


def pixel_road_px(
    camera: CameraModel,
    T_world_cam: np.ndarray,
    T_world_cam_early: np.ndarray,
    P_world: np.ndarray,
    P_world_early: np.ndarray,
) -> np.ndarray:
    """(N,) distance [px] of the earlier pixel of scene points seen at P_world (N, 3), which
    were at P_world_early (N, 3), from where the road point on the same ray would have been
    (the road hypothesis, lambda = 1). NaN for rays that do not meet the road."""
    centre = T_world_cam[:3, 3]
    ray = P_world - centre
    w_true = camera.project(_camera_points(P_world_early, T_world_cam_early))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -centre[2] / ray[:, 2]
    road = camera.project(_camera_points(centre + s[:, None] * ray, T_world_cam_early))
    d = np.hypot(*(w_true - road).T)
    d[~(ray[:, 2] < 0) | ~np.isfinite(d)] = np.nan
    return d


def drive_evidence(
    drive_dir: Path, baseline: int = 2, every: int = 3, max_range_m: float = 25.0
) -> list[dict]:
    """Per evaluated vehicle-frame (`scenarios.runner.gt_evaluation_set`; every ``every``th
    frame from ``baseline`` on): its motion class, visible pixels, visible pixels in a
    detector's analysed area that meet the road's ray range, and of those the evident
    ones (`pixel_evidence_px` >= EVIDENT_PX), the evident ones on an edge, and the standing
    ones (not evident, `pixel_road_px` >= EVIDENT_PX)."""
    drive_dir = Path(drive_dir)
    if baseline < 1 or every < 1:
        raise ValueError(f"baseline and every must be >= 1, got {baseline}, {every}")
    camera, mount = load_camera(drive_dir / "camera.yaml")
    det = VehicleDetector(with_folder_body_mask(camera, drive_dir), mount, _DETECTOR)
    area = det.analysed_area & det.comp.road_mask(1)
    rays = camera_unit_rays(camera)
    gt = load_groundtruth(drive_dir)
    out = []
    for k in range(baseline, len(gt), every):
        f, e = gt[k], gt[k - baseline]
        T, T_e = np.asarray(f["T_world_cam_actual"]), np.asarray(e["T_world_cam_actual"])
        ids = read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        rng_m = read_png(drive_dir / "range" / f"{k:06d}.png").astype(np.float64) / 100.0
        grey = cv2.cvtColor(read_png(drive_dir / "frames" / f"{k:06d}.png"), cv2.COLOR_RGB2GRAY)
        g = np.float32(grey)
        g2 = (cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8) ** 2
        g2 += (cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8) ** 2
        now = {v["id"]: v for v in f["vehicles"]}
        then = {v["id"]: v for v in e["vehicles"]}
        for gv in gt_evaluation_set(f, max_range_m)[0]:
            seen = ids == gv.id
            rec = {"frame": k, "id": gv.id, "motion": gv.motion, "visible_px": int(seen.sum())}
            r, c = np.nonzero(seen & area)
            rec["analysed_px"] = len(r)
            rec["evident_px"] = rec["evident_edge_px"] = rec["standing_px"] = 0
            if len(r) and gv.id in then:
                v, ve = now[gv.id], then[gv.id]
                P = T[:3, 3] + (rays[r, c] * rng_m[r, c, None]) @ T[:3, :3].T
                body = (P[:, :2] - [v["x_m"], v["y_m"]]) @ rot_z(v["yaw_rad"])[
                    :2, :2
                ]  # R^T (p - o)
                P_e = np.c_[body @ rot_z(ve["yaw_rad"])[:2, :2].T + [ve["x_m"], ve["y_m"]], P[:, 2]]
                ev = pixel_evidence_px(camera, T, T_e, P, P_e, Z_MAX_PER_H * T[2, 3]) >= EVIDENT_PX
                stands = ~ev & (pixel_road_px(camera, T, T_e, P, P_e) >= EVIDENT_PX)
                rec["evident_px"] = int(ev.sum())
                rec["evident_edge_px"] = int((ev & (g2[r, c] >= EDGE_GREY_PER_PX**2)).sum())
                rec["standing_px"] = int(stands.sum())
            out.append(rec)
    return out


def summary(records: list[dict], min_px: tuple[int, ...] = (20, 80)) -> dict:
    """Per motion class (and "all"): vehicle-frames, and the share with at least each
    min_px evident pixels, evident edge pixels, and evident or standing pixels."""
    classes = ["all"] + sorted({r["motion"] for r in records})
    out = {}
    for cls in classes:
        sel = [r for r in records if cls == "all" or r["motion"] == cls]
        ev = np.array([r["evident_px"] for r in sel])
        edge = np.array([r["evident_edge_px"] for r in sel])
        either = ev + np.array([r["standing_px"] for r in sel], dtype=ev.dtype)
        row = {"vehicle_frames": len(sel)}
        for m in min_px:
            row[f"evident_px>={m}"] = float(np.mean(ev >= m)) if len(sel) else float("nan")
            row[f"evident_edge_px>={m}"] = float(np.mean(edge >= m)) if len(sel) else float("nan")
            row[f"evident_or_standing_px>={m}"] = (
                float(np.mean(either >= m)) if len(sel) else float("nan")
            )
        out[cls] = row
    return out


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("drive_dir", type=Path, help="a rendered drive (omnibench render)")
    p.add_argument("--baseline", type=int, default=2, help="frames between the pair")
    p.add_argument("--every", type=int, default=3, help="every n-th frame")
    a = p.parse_args(argv)
    res = summary(drive_evidence(a.drive_dir, a.baseline, a.every))
    for cls, row in res.items():
        print(
            f"{cls:11s} "
            + "  ".join(f"{k} {v:.2f}" for k, v in row.items() if k != "vehicle_frames")
            + f"  (n={row['vehicle_frames']})"
        )
    print(json.dumps(res))


if __name__ == "__main__":
    main()
