"""`omnibench bench estimate`: time per frame of the direct estimator on synthetic frames.

Frames come from `estimator.synthetic` (textured road, no renderer, nothing from
sim/): a car at 25 m/s turning at 0.1 rad/s with 0.3 deg of camera vibration at
15 fps. OpenCV and the BLAS run on one thread while timing (the target is one core;
numpy's OpenBLAS would otherwise start a thread per core for the larger matrix
products). Both the wall-clock time and the process CPU time of each step are
measured: on a machine shared with other work the wall clock includes waiting for a
core, the CPU time does not (it is what one dedicated core would take).
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from estimator.camera.files import load_camera
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import default_config
from estimator.synthetic import RoadTexture, drive_poses, pixel_angle_rad, render_road, to_uint8


def bench_direct(
    camera_name: str = "omni-near", n_frames: int = 30, warmup: int = 3, **config
) -> dict:
    """Median time of `DirectEstimator.step` over ``n_frames`` frames (after ``warmup``).

    Returns ms_per_frame (median wall clock), p90_ms_per_frame, cpu_ms_per_frame (median process
    CPU time), frames, width, height, points and
    iterations of the last frame, the median |speed error| [%] against the
    synthetic truth (25 m/s; the CAN speed given is 8 % high) and blas_threads (the
    most threads of a thread pool while timing: 1).
    """
    camera, mount = load_camera(camera_name)
    fps, speed = 15.0, 25.0
    total = n_frames + warmup + 1
    poses = drive_poses(mount, np.arange(total) / fps, speed, 0.1)
    tex = RoadTexture(seed=1)
    angle = pixel_angle_rad(camera)
    frames = [
        to_uint8(render_road(camera, T, tex, pixel_angle=angle)) for T in poses.T_world_actual
    ]
    est = DirectEstimator(camera, mount, default_config(camera.kind, **config))
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    times, cpu, errors = [], [], []
    try:
        with threadpool_limits(limits=1):
            blas_threads = max((p["num_threads"] for p in threadpool_info()), default=1)
            for k, img in enumerate(frames):
                t0, c0 = time.perf_counter(), time.process_time()
                rec = est.step(img, poses.t_s[k], 1.08 * speed)
                dt, dc = time.perf_counter() - t0, time.process_time() - c0
                if k > warmup:
                    times.append(dt)
                    cpu.append(dc)
                    errors.append(abs(rec.speed_mps / speed - 1.0))
    finally:
        cv2.setNumThreads(threads)
    ms = 1000.0 * np.asarray(times)
    return {
        "ms_per_frame": float(np.median(ms)),
        "p90_ms_per_frame": float(np.percentile(ms, 90)),
        "cpu_ms_per_frame": float(np.median(1000.0 * np.asarray(cpu))),
        "frames": len(times),
        "camera": camera_name,
        "width": camera.width,
        "height": camera.height,
        "points": rec.n_points,
        "iterations": rec.iterations,
        "speed_error_pct": 100.0 * float(np.median(errors)),
        "blas_threads": blas_threads,
    }
