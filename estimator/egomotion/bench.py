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

from collections.abc import Callable, Sequence

import cv2
import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from estimator.camera.files import load_camera
from estimator.egomotion.direct import DirectEstimator
from estimator.egomotion.direct_config import default_config
from estimator.egomotion.ego_estimator import EgoMotionEstimator
from estimator.frame_times import FrameTimes, passes_summary
from estimator.synthetic import RoadTexture, drive_poses, pixel_angle_rad, render_road, to_uint8


def time_steps(
    make_estimator: Callable[[], EgoMotionEstimator],
    images: Sequence[np.ndarray],
    t_s: Sequence[float],
    can_mps: Sequence[float],
    true_speed_mps: Sequence[float],
    warmup: int,
    repeat: int = 1,
) -> dict:
    """Time ``step`` of a fresh ``make_estimator()`` on each frame, OpenCV and the BLAS on
    one thread, over ``repeat`` passes.

    images, t_s [s], can_mps [m/s], true_speed_mps [m/s]: one per frame (N,); the first
    ``warmup + 1`` steps are not timed (frame 0 has no pair). Returns ms_per_frame (median
    wall clock), p90_ms_per_frame, cpu_ms_per_frame (median process CPU time), frames (with
    more than one pass: each frame's fastest, `estimator.frame_times.fastest_pass`),
    repeat, passes (each pass's median and p90 as timed), speed_error_pct (median
    |relative error| of the forward speed, first pass), blas_threads (the most threads of a
    pool while timing: 1) and the last record's points and iterations.
    """
    if repeat < 1:
        raise ValueError(f"repeat must be 1 or more, got {repeat}")
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    passes, errors = [], []
    try:
        with threadpool_limits(limits=1):
            blas_threads = max((p["num_threads"] for p in threadpool_info()), default=1)
            for i in range(repeat):
                est, clock = make_estimator(), FrameTimes()
                for k, img in enumerate(images):
                    clock.start()
                    rec = est.step(img, float(t_s[k]), float(can_mps[k]))
                    clock.stop(keep=k > warmup)
                    if k > warmup and i == 0:
                        errors.append(abs(rec.speed_mps / true_speed_mps[k] - 1.0))
                passes.append(clock)
    finally:
        cv2.setNumThreads(threads)
    return {
        **passes_summary(passes),
        "speed_error_pct": 100.0 * float(np.median(errors)),
        "blas_threads": blas_threads,
        "points": getattr(rec, "n_points", 0),
        "iterations": getattr(rec, "iterations", []),
    }


def bench_direct(
    camera_name: str = "omni-near", n_frames: int = 30, warmup: int = 3, repeat: int = 1, **config
) -> dict:
    """`time_steps` of `DirectEstimator` over ``n_frames`` synthetic frames (after
    ``warmup``), ``repeat`` passes: a car at 25 m/s whose CAN speed is 8 % high. Adds
    camera, width, height.
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
    cfg = default_config(camera.kind, **config)
    res = time_steps(
        lambda: DirectEstimator(camera, mount, cfg),
        frames,
        poses.t_s,
        [1.08 * speed] * total,
        [speed] * total,
        warmup=warmup,
        repeat=repeat,
    )
    return {**res, "camera": camera_name, "width": camera.width, "height": camera.height}
