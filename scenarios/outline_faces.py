"""Which faces of a vehicle the detector's lower outline sees.

A vehicle track's detection carries the lower outline its box is fitted to
(`estimator.surround.detection.VehicleDetector._refine`): per bearing bin, the nearest
moving edge pixel, on the road. `estimator.surround.boxfit.fit_box` puts the box's
camera-facing faces on it. Where the outline is not the vehicle's nearest faces (a face
along the flow carries no motion at its lower edge; the motion test marks the silhouette
against the road beyond it), the box lands that much too far.

Per vehicle detection with an outline, against the evaluated vehicle within the metrics'
gate of the outline's nearest point (`scenarios.runner.gt_evaluation_set`), this tool
measures the median **depth** of the outline's points behind the vehicle's camera-facing
**side** face (a long face: 0 on it, the vehicle's width on the far side) and behind its
camera-facing **end** face (0 on it, its length at the far end). The drive is analysed as
`omnibench bench detect` analyses it (the true motion between frames), frames with the ego
car moving only.

    python -m scenarios.outline_faces DRIVE_DIR [--every 1]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.fileio import read_png
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DetectorConfig
from scenarios.benchmarks import true_motion
from scenarios.detection_metrics import (
    BAND_NAMES,
    EGO_MOVING_MPS,
    band_labels,
    nearest_footprint_point,
    point_footprint_distance,
)
from scenarios.runner import GATE_M, gt_evaluation_set
from sim.drive import DriveError, load_groundtruth


def face_depths(outline_xy: np.ndarray, footprint_xy: np.ndarray) -> tuple[float, float]:
    """(side, end) [m]: the median depth of outline points (N, 2) behind the footprint's
    (4, 2) camera-facing long face and camera-facing short face, the camera at the
    origin; NaN for an axis whose span holds the camera (no face on it faces it)."""
    fp = np.asarray(footprint_xy, float)
    p = np.asarray(outline_xy, float).reshape(-1, 2)
    c = fp.mean(axis=0)
    e1, e2 = fp[1] - fp[0], fp[2] - fp[1]
    # (unit axis, half extent) of the long and the short axis
    long_, short = (e1, e2) if np.hypot(*e1) >= np.hypot(*e2) else (e2, e1)
    out = []
    # the side face lies across the short axis, the end face across the long one
    for axis in (short, long_):
        half = 0.5 * float(np.hypot(*axis))
        u = axis / (2.0 * half)
        cam = -float(c @ u)  # the camera's coordinate along the axis, from the centre
        if abs(cam) <= half:
            out.append(math.nan)
            continue
        s = math.copysign(1.0, cam)  # the camera-facing face is at s * half
        out.append(float(np.median(half - s * ((p - c) @ u))))
    return out[0], out[1]


def drive_faces(drive_dir: Path, every: int = 1, max_range_m: float = 25.0) -> list[dict]:
    """Per vehicle detection with an outline in every ``every``-th frame (ego car moving)
    that lies within the gate of an evaluated vehicle: frame, vehicle id, the vehicle's
    range [m] (its nearest footprint point), `face_depths` (side_m, end_m), and the reported
    box's centre error [m] against the footprint's centre (NaN without a box)."""
    drive_dir = Path(drive_dir)
    if every < 1:
        raise ValueError(f"--every must be >= 1, got {every}")
    gt = load_groundtruth(drive_dir)  # DriveError: not a complete rendered drive
    camera, mount = load_camera(drive_dir / "camera.yaml")
    sa = SurroundAnalyzer(with_folder_body_mask(camera, drive_dir), mount, DetectorConfig())
    out = []
    for k, g in enumerate(gt):
        image = read_png(drive_dir / "frames" / f"{k:06d}.png")
        x, dt = true_motion(g)
        ego = g["ego"]
        sf = sa.step(k, g["t_s"], image, x, dt, ego["speed_mps"], ego["yaw_rate_rps"])
        if sf is None or k % every or ego["speed_mps"] <= EGO_MOVING_MPS:
            continue
        vehicles = gt_evaluation_set(g, max_range_m)[0]
        for d in sf.detection.detections:
            if d.outline_xy is None or not len(vehicles):
                continue
            o = np.asarray(d.outline_xy, float)
            near = o[np.argmin(np.hypot(*o.T))][None]
            dist = [float(point_footprint_distance(near, v.footprint_xy)[0]) for v in vehicles]
            j = int(np.argmin(dist))
            if dist[j] > GATE_M:
                continue
            v = vehicles[j]
            side, end = face_depths(o, v.footprint_xy)
            rng = float(np.hypot(*nearest_footprint_point(v.footprint_xy, np.zeros(2))))
            centre = np.asarray(v.footprint_xy, float).mean(axis=0)
            box = (
                math.nan
                if d.box is None
                else math.hypot(d.box.x_m - centre[0], d.box.y_m - centre[1])
            )
            out.append(
                {
                    "frame": k,
                    "id": v.id,
                    "range_m": rng,
                    "side_m": side,
                    "end_m": end,
                    "box_centre_m": box,
                }
            )
    return out


def summary(records: list[dict]) -> dict:
    """{band: {"detections", "side_p10_m", "side_median_m", "side_p90_m", "end_median_m",
    "box_centre_median_m"}}
    over the range bands (`scenarios.detection_metrics.BAND_NAMES`) and "all"."""
    rng = np.array([r["range_m"] for r in records], float)
    side = np.array([r["side_m"] for r in records], float)
    end = np.array([r["end_m"] for r in records], float)
    box = np.array([r["box_centre_m"] for r in records], float)
    bands = band_labels(np.column_stack([rng, np.zeros(len(rng))]))

    def row(keep: np.ndarray) -> dict:
        s, e = side[keep & np.isfinite(side)], end[keep & np.isfinite(end)]
        b = box[keep & np.isfinite(box)]
        p10, p50, p90 = np.percentile(s, [10, 50, 90]) if s.size else (math.nan,) * 3
        return {
            "detections": int(keep.sum()),
            "side_p10_m": float(p10),
            "side_median_m": float(p50),
            "side_p90_m": float(p90),
            "end_median_m": float(np.median(e)) if e.size else math.nan,
            "box_centre_median_m": float(np.median(b)) if b.size else math.nan,
        }

    res = {n: row(bands == n) for n in BAND_NAMES}
    res["all"] = row(np.ones(len(rng), bool))
    return res


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("drive_dir", type=Path, help="a rendered drive (omnibench render)")
    p.add_argument("--every", type=int, default=1, help="every n-th frame")
    a = p.parse_args(argv)
    try:  # the checks come before any frame is analysed
        records = drive_faces(a.drive_dir, a.every)
    except (ValueError, DriveError) as e:
        p.error(str(e))
    res = summary(records)
    for band, r in res.items():
        print(
            f"{band:6s} detections {r['detections']:4d}  behind the side face p10 / median / p90 "
            f"{r['side_p10_m']:.2f} / {r['side_median_m']:.2f} / {r['side_p90_m']:.2f} m  "
            f"behind the end face {r['end_median_m']:.2f} m  "
            f"box centre {r['box_centre_median_m']:.2f} m"
        )
    print(json.dumps(res))


if __name__ == "__main__":
    main()
