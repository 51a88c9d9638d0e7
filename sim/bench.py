"""`omnibench bench render`: frames/s of omni frame production on this machine."""

from __future__ import annotations

import time

import numpy as np

from sim.drive import prepare_drive
from sim.scenario import Scenario


def bench_render(
    n_frames: int = 20, camera: str = "omni-far", vehicles: int = 30, warmup: int = 3
) -> dict:
    """Median time to produce one frame (faces, ray map, ids, range, sensor), no disk I/O.

    Uses a highway-v0 drive with ``vehicles`` cars; returns frames_per_s, ms_per_frame.
    """
    total = n_frames + warmup
    sc = Scenario(
        name="bench-render",
        env="highway-v0",
        env_config={"vehicles_count": vehicles, "lanes_count": 4},
        seed=1,
        duration_s=total / 15.0 + 0.01,
        fps=15.0,
        camera=camera,
    )
    drive = prepare_drive(sc)
    times = []
    faces = None
    try:
        for k in range(total):
            t0 = time.perf_counter()
            drive.produce(k)
            if k >= warmup:
                times.append(time.perf_counter() - t0)
        faces = len(drive._renderer.lookup.faces) - len(drive._renderer.lookup.body_only)
    finally:
        drive.close()
    ms = 1000.0 * float(np.median(times))
    n_visible = len(drive.frames[0].others)
    return {
        "frames_per_s": 1000.0 / ms,
        "ms_per_frame": ms,
        "frames": len(times),
        "width": drive.camera.width,
        "height": drive.camera.height,
        "vehicles": n_visible,
        "faces_rendered_per_frame": faces,
        "face_px": drive.face_px,
    }
