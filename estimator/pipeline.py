"""Run an ego-motion estimator over a recording and write ``egomotion.csv``.

Columns: frame, t_s, V_x..V_z [m/s], W_x..W_z [rad/s], A_x..A_z [rad] (nominal
camera frame), P_00..P_88 (diagonal of the covariance), speed_mps and
yaw_rate_dps (car frame), inliers, degraded (0/1), reason.
The estimate of frame k is the motion from frame k-1 to k (row 0 is the prior).
"""

from __future__ import annotations

import csv
import io as _io
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.fileio import write_text
from estimator.progress import track
from estimator.recording import CanTrack

HEADER = (
    ["frame", "t_s"]
    + [f"{q}_{a}" for q in "VWA" for a in "xyz"]
    + [f"P_{i}{i}" for i in range(9)]
    + ["speed_mps", "yaw_rate_dps", "inliers", "degraded", "reason"]
)


@dataclass
class EstimateRun:
    records: list
    ms_per_frame: float


def record_row(rec, mount: CameraMount) -> list:
    x = np.asarray(rec.x, dtype=float)
    P = np.asarray(rec.P, dtype=float)
    R = mount.R_car_cam
    speed = float((R @ x[0:3])[0])
    yaw_dps = math.degrees(float((R @ x[3:6])[2]))
    reason = getattr(rec, "reason", "") or ""
    return (
        [rec.frame, f"{rec.t_s:.6f}"]
        + [f"{v:.6g}" for v in x]
        + [f"{v:.4g}" for v in np.diag(P)]
        + [
            f"{speed:.4f}",
            f"{yaw_dps:.4f}",
            int(getattr(rec, "n_inliers", 0)),
            int(bool(getattr(rec, "degraded", False))),
            reason,
        ]
    )


def write_egomotion_csv(path: Path, records: list, mount: CameraMount) -> None:
    buf = _io.StringIO()
    w = csv.writer(buf)
    w.writerow(HEADER)
    for rec in records:
        w.writerow(record_row(rec, mount))
    write_text(path, buf.getvalue())


def estimate_frames(
    frames: Iterable[np.ndarray],
    times_s: Sequence[float] | np.ndarray | Iterable[float],
    can: CanTrack,
    camera: CameraModel,
    mount: CameraMount,
    estimator: str = "direct",
    progress: bool = False,
    keep_images: bool = False,
    road_masks: Iterable[np.ndarray] | None = None,
    n_frames: int | None = None,
    on_frame: Callable[[int, float, np.ndarray, object], None] | None = None,
    **config,
) -> EstimateRun:
    """Step the named estimator over frames; returns every per-frame record.

    times_s: each frame's time [s], an array or a lazy iterable (e.g.
    `estimator.recording.frame_times`: any number of frames); there must be one for
    every frame. n_frames: the number of frames, for the progress bar (default: the
    number of times, when they have a length).
    road_masks: optional (H, W) bool road mask per frame (`estimator.recording.
    iter_road_masks`); there must be one for every frame.
    on_frame: called with (k, t_s, image, record) after each frame is estimated (e.g. the
    surround analysis of a recording); its time is not the estimator's.
    """
    from estimator.egomotion.baselines import make_estimator

    est = make_estimator(estimator, camera, mount, **config)
    records, times = [], []
    masks = iter(road_masks) if road_masks is not None else None
    if n_frames is None and hasattr(times_s, "__len__"):
        n_frames = len(times_s)
    frame_times = iter(times_s)
    # one BLAS thread: the estimator's matrices are small, and OpenBLAS's extra threads
    # spin on the cores that a suite's other jobs use (two rectilinear drives at once on
    # two cores: 11.5-18.8 s against 19.0-25.2 s; the same estimates)
    with threadpool_limits(limits=1, user_api="blas"):
        for k, img in track(enumerate(frames), n_frames, f"estimate ({estimator})", progress):
            t_k = next(frame_times, None)
            if t_k is None:
                raise ValueError(f"more frames than timestamps ({k})")
            t_k = float(t_k)
            mask = None
            if masks is not None:
                mask = next(masks, None)
                if mask is None:
                    raise ValueError(f"fewer road masks than frames: none for frame {k}")
            t0 = time.perf_counter()
            try:
                given = {"road_mask": mask} if mask is not None else {}  # plug-ins may take none
                rec = est.step(img, t_k, can.at(t_k), **given)
            except ValueError as e:
                if mask is None or "road_mask" not in str(e):
                    raise
                raise ValueError(f"frame {k}: {e}") from None
            times.append(time.perf_counter() - t0)
            if not keep_images and hasattr(rec, "compensated"):
                rec.compensated = None
            records.append(rec)
            if on_frame is not None:
                on_frame(k, t_k, img, rec)
    ms = 1000.0 * float(np.median(times[1:])) if len(times) > 1 else float("nan")
    return EstimateRun(records, ms)
