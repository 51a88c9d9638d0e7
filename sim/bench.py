"""`omnibench bench render`: frames/s of omni frame production on this machine."""

from __future__ import annotations

import numpy as np

from estimator.frame_times import FrameTimes
from sim.drive import prepare_drive
from sim.machine import machine_info
from sim.scenario import Scenario


def bench_render(
    n_frames: int = 60,
    camera: str = "omni-far",
    vehicles: int = 30,
    warmup: int = 3,
    renderer: str = "plane",
    face_px: int | None = None,
    shadows: bool = False,
) -> dict:
    """Time between frames produced one after the other (render, ray map, ids, range,
    every sensor effect on; `DriveRenderer.produce_many`, as a render does), no disk I/O,
    on a highway-v0 drive with ``vehicles`` cars (casting ``shadows`` on the road).

    Returns frames_per_s (at the median), ms_per_frame (median), ms_p90, the median CPU
    time of the process per frame ``cpu_ms_per_frame`` (all its threads: with the
    stages running side by side, the work a frame takes whatever the cores), and per
    stage (`estimator.frame_times.StageClock`) its median ms in ``stages_ms`` (the motion
    and sensor stages of a frame run beside the rendering of the next), and the machine
    (``machine``, `sim.machine.machine_info`, with its OpenGL renderer).
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
        shadows=shadows,
    )
    drive = prepare_drive(sc, face_px=face_px, renderer=renderer)
    clock, stages = FrameTimes(), []
    try:
        for k, _ in drive.produce_many(range(total)):
            clock.stop(keep=k >= warmup)
            if k >= warmup:
                stages.append(drive.stage_seconds)
            clock.start()
    finally:
        drive.close()
    t = clock.summary()
    ms = t["ms_per_frame"]
    names = list(stages[0])
    return {
        "renderer": renderer,
        "frames_per_s": 1000.0 / ms,
        "ms_per_frame": ms,
        "ms_p90": t["p90_ms_per_frame"],
        "cpu_ms_per_frame": t["cpu_ms_per_frame"],
        "stages_ms": {n: 1000.0 * float(np.median([s.get(n, 0.0) for s in stages])) for n in names},
        "frames": t["frames"],
        "width": drive.camera.width,
        "height": drive.camera.height,
        "vehicles": len(drive.frames[0].others),
        "face_px": drive.face_px,
        "shadows": shadows,
        "sensor_effects": sc.sensor.model_dump(),
        "machine": machine_info(),  # with the OpenGL renderer that drew the frames
    }
