"""`omnibench bench detect`: detection + tracking time per frame on a rendered drive.

The drive (a 30-vehicle highway, ``frames`` frames) is rendered once into
``renders/bench/`` and reused. The surround analysis runs with the ground-truth
motion (so only detection and tracking are timed), OpenCV on one thread.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from estimator.camera.files import load_camera
from estimator.fileio import read_png
from estimator.surround.analyzer import SurroundAnalyzer
from scenarios.config import Scenario
from sim.drive import load_groundtruth, render_drive


def bench_detect(
    camera: str = "omni-near", n_frames: int = 30, cache_dir: Path = Path("renders/bench")
) -> dict:
    """Median ms per frame of `SurroundAnalyzer.step` (compensation, eq. 22, plan view,
    blobs, tracker) over a rendered drive."""
    sc = Scenario(
        name=f"bench-detect-{camera}",
        env="highway-v0",
        env_config={"vehicles_count": 30, "lanes_count": 4},
        seed=1,
        duration_s=(n_frames + 1) / 15.0,
        fps=15.0,
        camera=camera,
    )
    out = Path(cache_dir) / sc.name
    render_drive(sc, out, progress=True)
    gt = load_groundtruth(out)
    cam, mount = load_camera(out / "camera.yaml")
    sa = SurroundAnalyzer(cam, mount)
    images = [read_png(out / "frames" / f"{k:06d}.png") for k in range(len(gt))]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    times = []
    try:
        for k, img in enumerate(images):
            m = gt[k]["motion_from_prev"]
            x = np.r_[m["V_mps"], m["W_rps"], m["A_rad"]] if m else np.zeros(9)
            dt = m["dt_s"] if m else 0.0
            t0 = time.perf_counter()
            sa.step(
                k, gt[k]["t_s"], img, x, dt, gt[k]["ego"]["speed_mps"], gt[k]["ego"]["yaw_rate_rps"]
            )
            if k >= 2:
                times.append(time.perf_counter() - t0)
    finally:
        cv2.setNumThreads(threads)
    ms = 1000.0 * float(np.median(times))
    return {
        "ms_per_frame": ms,
        "ms_p90": 1000.0 * float(np.percentile(times, 90)),
        "frames": len(times),
        "width": cam.width,
        "height": cam.height,
        "camera": camera,
    }
