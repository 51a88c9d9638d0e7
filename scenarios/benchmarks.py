"""Speed benchmarks on rendered drives: `omnibench bench detect` and `bench estimate`.

- `bench_detect`: detection + tracking. The drive (by default every frame of the dense
  exit, `dense-exit-omni-near`: the library's densest traffic around the car, 3.9
  vehicles within 25 m a frame, up to 6) is rendered once into ``renders/bench/`` and
  reused. The surround analysis runs with the ground-truth motion (so only detection and
  tracking are timed).
- `bench_estimate`: `DirectEstimator.step` on the frames of a library drive (default
  highway-omni-near, with its sensor effects), rendered once into the suites' render
  cache (``renders/cache/<render key>``, `scenarios.suite.render_key_for`) and reused.

OpenCV and the BLAS run on one thread while timing (the targets are per core). Each
returns the median and the 90th percentile of the per-frame wall-clock times
(``ms_per_frame``, ``p90_ms_per_frame``) and the frames timed.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.egomotion.bench import time_steps
from estimator.fileio import read_png
from estimator.frame_times import FrameTimes
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DEFAULT_DETECTOR, DETECTOR_METHODS, DetectorConfig
from scenarios.config import load_scenario
from sim.drive import load_groundtruth, render_drive

DETECT_BENCH_SCENARIO = "dense-exit-omni-near"  # the drive `bench_detect` times


def bench_detect(
    camera: str | dict[str, Any] = "omni-near",
    n_frames: int | None = None,
    cache_dir: Path = Path("renders/bench"),
    scenario: str = DETECT_BENCH_SCENARIO,
    detector: str = DEFAULT_DETECTOR,
) -> dict:
    """Median ms per frame of `SurroundAnalyzer.step` (compensation, motion hypotheses,
    plan view, blobs, tracker) over a rendered dense drive, its p90 and median process CPU
    time (one core: about the wall time), the median ms of each stage (``stages_ms``:
    warps, score, blobs, refine, track; `SurroundAnalyzer.stage_seconds`) and how many
    vehicles it saw (``vehicles_in_range``: vehicle-frames within the detection range, per
    frame).

    n_frames: frames after the first (None: the whole drive; the first of them warms up,
    so n_frames - 1 are timed); scenario: a library name or a scenario file; detector: a
    built-in method (`DetectorConfig.method`).
    """
    if detector not in DETECTOR_METHODS:
        raise ValueError(f"detector {detector!r}: choose one of {', '.join(DETECTOR_METHODS)}")

    dense = load_scenario(scenario)
    if n_frames is None:
        n_frames = dense.n_frames - 1
    if not 2 <= n_frames < dense.n_frames:
        raise ValueError(
            f"{dense.name} has {dense.n_frames} frames; n_frames must be 2..{dense.n_frames - 1}, "
            f"got {n_frames}"
        )
    name = camera if isinstance(camera, str) else "inline"
    # the drive's own first frames (its scenery laid out for the whole drive)
    sc = dense.model_copy(update={"name": f"bench-detect-{dense.name}-{name}", "camera": camera})
    out = Path(cache_dir) / sc.name
    render_drive(sc, out, progress=True, max_frames=n_frames + 1)
    gt = load_groundtruth(out)
    cam, mount = load_camera(out / "camera.yaml")
    # as `omnibench run`
    sa = SurroundAnalyzer(with_folder_body_mask(cam, out), mount, DetectorConfig(method=detector))
    images = [read_png(out / "frames" / f"{k:06d}.png") for k in range(len(gt))]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    clock, stages = FrameTimes(), []
    try:
        for k, img in enumerate(images):
            m = gt[k]["motion_from_prev"]
            x = np.r_[m["V_mps"], m["W_rps"], m["A_rad"]] if m else np.zeros(9)
            dt = m["dt_s"] if m else 0.0
            clock.start()
            sa.step(
                k, gt[k]["t_s"], img, x, dt, gt[k]["ego"]["speed_mps"], gt[k]["ego"]["yaw_rate_rps"]
            )
            clock.stop(keep=k >= 2)
            if k >= 2:
                stages.append(sa.stage_seconds)
    finally:
        cv2.setNumThreads(threads)
    near = [
        sum(
            np.hypot(v["x_m"] - f["ego"]["x_m"], v["y_m"] - f["ego"]["y_m"]) < sc.detection_range_m
            for v in f["vehicles"]
        )
        for f in gt
    ]
    return {
        "bench": "detect",
        "scenario": dense.name,
        "detector": detector,
        "vehicles_in_range": float(np.mean(near)),
        **clock.summary(),
        "stages_ms": {
            n: 1000.0 * float(np.median([st.get(n, 0.0) for st in stages])) for n in stages[0]
        },
        "width": cam.width,
        "height": cam.height,
        "camera": camera,
    }


def bench_estimate(
    scenario: str = "highway-omni-near",
    n_frames: int = 40,
    warmup: int = 3,
    camera: str | dict[str, Any] | None = None,
    cache_dir: Path | None = None,
    progress: bool = True,
) -> dict:
    """Median and 90th percentile time of `DirectEstimator.step` per frame over
    ``n_frames`` rendered frames of library drive ``scenario`` after ``warmup`` pairs.

    camera: the drive's camera instead of the scenario's (a preset name or a camera dict,
    e.g. a smaller one for a quick check). The first ``n_frames + warmup + 1`` frames are
    rendered into ``cache_dir`` (default the suites' render cache) unless already there.
    Returns bench, ms_per_frame, p90_ms_per_frame (wall clock), cpu_ms_per_frame (median
    process CPU time: what one dedicated core would take), frames, scenario, camera,
    width, height, speed_error_pct (median |error| of the forward speed) and blas_threads.
    """
    from estimator.egomotion.baselines import make_estimator
    from estimator.recording import read_can_csv, read_timestamps_csv
    from scenarios.suite import render_key_for
    from scenarios.suite_runner import DEFAULT_CACHE, drive_complete, file_lock

    if n_frames < 1 or warmup < 0:
        raise ValueError(f"n_frames must be >= 1 and warmup >= 0, got {n_frames}, {warmup}")
    sc = load_scenario(scenario, **({"camera": camera} if camera is not None else {}))
    total = n_frames + warmup + 1  # frame 0 has no pair: its step only stores the image
    if total > sc.n_frames:
        raise ValueError(
            f"{sc.name} has {sc.n_frames} frames; {n_frames} timed + {warmup} warm-up need {total}"
        )
    drive = Path(cache_dir if cache_dir is not None else DEFAULT_CACHE) / render_key_for(sc, total)
    with file_lock(drive.with_name(drive.name + ".lock")):
        if not drive_complete(drive, total):
            render_drive(sc, drive, progress=progress, max_frames=total)
    gt = load_groundtruth(drive)
    cam, mount = load_camera(drive / "camera.yaml")
    t_s = read_timestamps_csv(drive / "timestamps.csv")
    can = read_can_csv(drive / "can.csv")
    images = [read_png(drive / "frames" / f"{k:06d}.png") for k in range(total)]
    est = make_estimator("direct", cam, mount)
    R = mount.R_car_cam
    truth = [math.nan] + [
        float((R @ np.asarray(g["motion_from_prev"]["V_mps"]))[0]) for g in gt[1:total]
    ]
    res = time_steps(est, images, t_s, [can.at(float(t)) for t in t_s], truth, warmup=warmup)
    return {
        "bench": "estimate",
        **{k: res[k] for k in ("ms_per_frame", "p90_ms_per_frame", "cpu_ms_per_frame", "frames")},
        "scenario": sc.name,
        "camera": sc.camera if isinstance(sc.camera, str) else "inline",
        "width": cam.width,
        "height": cam.height,
        "speed_error_pct": res["speed_error_pct"],
        "blas_threads": res["blas_threads"],
    }
