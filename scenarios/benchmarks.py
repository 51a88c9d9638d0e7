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
(``ms_per_frame``, ``p90_ms_per_frame``) and the frames timed; `bench_detect` can time
the drive several times and keep each frame's fastest pass (``repeat``).
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
from estimator.frame_times import FrameTimes, passes_summary
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DEFAULT_DETECTOR, DETECTOR_METHODS, DetectorConfig
from scenarios.config import load_scenario
from sim.drive import load_groundtruth, render_drive
from sim.machine import machine_info

DETECT_BENCH_SCENARIO = "dense-exit-omni-near"  # the drive `bench_detect` times


def true_motion(gt_frame: dict) -> tuple[np.ndarray, float]:
    """(x (9,), dt [s]): a ground-truth frame's motion since the previous one, as the
    surround analyzer takes an estimate (`SurroundAnalyzer.step`); zeros on the first."""
    m = gt_frame["motion_from_prev"]
    if not m:
        return np.zeros(9), 0.0
    return np.r_[m["V_mps"], m["W_rps"], m["A_rad"]], float(m["dt_s"])


def bench_detect(
    camera: str | dict[str, Any] = "omni-near",
    n_frames: int | None = None,
    cache_dir: Path = Path("renders/bench"),
    scenario: str = DETECT_BENCH_SCENARIO,
    detector: str = DEFAULT_DETECTOR,
    repeat: int = 1,
) -> dict:
    """Median ms per frame of `SurroundAnalyzer.step` (compensation, motion hypotheses,
    plan view, blobs, tracker) over a rendered dense drive, its p90 and median process CPU
    time (one core: about the wall time), the median ms of each stage (``stages_ms``:
    warps, score, blobs, refine, track; `SurroundAnalyzer.stage_seconds`) and how many
    vehicles it saw (``vehicles_in_range``: vehicle-frames within the detection range, per
    frame) and on what (``machine``, `sim.machine.machine_info`).

    n_frames: frames after the first (None: the whole drive; the first of them warms up,
    so n_frames - 1 are timed); scenario: a library name or a scenario file; detector: a
    built-in method (`DetectorConfig.method`); repeat: passes over the drive, each with a
    fresh analyzer (the same work); with more than one, each frame's time (and stage time) is
    its fastest pass's (`estimator.frame_times.passes_summary`: on a shared machine, the code's
    own cost), and ``passes`` lists every pass's median and p90.
    """
    if detector not in DETECTOR_METHODS:
        raise ValueError(f"detector {detector!r}: choose one of {', '.join(DETECTOR_METHODS)}")
    if repeat < 1:
        raise ValueError(f"repeat must be 1 or more, got {repeat}")

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
    camera_model = with_folder_body_mask(cam, out)
    images = [read_png(out / "frames" / f"{k:06d}.png") for k in range(len(gt))]
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    passes, pass_stages = [], []
    try:
        for _ in range(repeat):
            # as `omnibench run`
            sa = SurroundAnalyzer(camera_model, mount, DetectorConfig(method=detector))
            clock, stages = FrameTimes(), []
            for k, img in enumerate(images):
                x, dt = true_motion(gt[k])
                ego = gt[k]["ego"]
                clock.start()
                sa.step(k, gt[k]["t_s"], img, x, dt, ego["speed_mps"], ego["yaw_rate_rps"])
                clock.stop(keep=k >= 2)
                if k >= 2:
                    stages.append(sa.stage_seconds)
            passes.append(clock)
            pass_stages.append(stages)
    finally:
        cv2.setNumThreads(threads)
    # each frame's stage times from its fastest pass, (frames, stages) [s]
    names = list(pass_stages[0][0])
    stage_s = np.min(
        [[[st.get(n, 0.0) for n in names] for st in stages] for stages in pass_stages], axis=0
    )
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
        **passes_summary(passes),
        "stages_ms": {n: 1000.0 * float(np.median(stage_s[:, i])) for i, n in enumerate(names)},
        "width": cam.width,
        "height": cam.height,
        "camera": camera,
        "machine": machine_info(),
    }


def bench_estimate(
    scenario: str = "highway-omni-near",
    n_frames: int = 40,
    warmup: int = 3,
    camera: str | dict[str, Any] | None = None,
    cache_dir: Path | None = None,
    progress: bool = True,
    repeat: int = 1,
) -> dict:
    """Median and 90th percentile time of `DirectEstimator.step` per frame over
    ``n_frames`` rendered frames of library drive ``scenario`` after ``warmup`` pairs;
    ``repeat`` passes, each frame's fastest kept (`estimator.egomotion.bench.time_steps`).

    camera: the drive's camera instead of the scenario's (a preset name or a camera dict,
    e.g. a smaller one for a quick check). The first ``n_frames + warmup + 1`` frames are
    rendered into ``cache_dir`` (default the suites' render cache) unless already there.
    Returns bench, ms_per_frame, p90_ms_per_frame (wall clock), cpu_ms_per_frame (median
    process CPU time: what one dedicated core would take), frames, scenario, camera,
    width, height, speed_error_pct (median |error| of the forward speed), blas_threads,
    repeat, passes (each pass's median and p90) and machine (`sim.machine.machine_info`).
    """
    from estimator.egomotion.baselines import make_estimator
    from estimator.recording import read_can_csv, read_timestamps_csv
    from scenarios.suite import render_key_for
    from scenarios.suite_runner import DEFAULT_CACHE, drive_complete, file_lock

    if n_frames < 1 or warmup < 0:
        raise ValueError(f"n_frames must be >= 1 and warmup >= 0, got {n_frames}, {warmup}")
    if repeat < 1:
        raise ValueError(f"repeat must be 1 or more, got {repeat}")
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
    R = mount.R_car_cam
    truth = [math.nan] + [
        float((R @ np.asarray(g["motion_from_prev"]["V_mps"]))[0]) for g in gt[1:total]
    ]
    res = time_steps(
        lambda: make_estimator("direct", cam, mount),
        images,
        t_s,
        [can.at(float(t)) for t in t_s],
        truth,
        warmup=warmup,
        repeat=repeat,
    )
    return {
        "bench": "estimate",
        **{
            k: res[k]
            for k in (
                "ms_per_frame",
                "p90_ms_per_frame",
                "cpu_ms_per_frame",
                "frames",
                "repeat",
                "passes",
            )
        },
        "scenario": sc.name,
        "camera": sc.camera if isinstance(sc.camera, str) else "inline",
        "width": cam.width,
        "height": cam.height,
        "speed_error_pct": res["speed_error_pct"],
        "blas_threads": res["blas_threads"],
        "machine": machine_info(),
    }
