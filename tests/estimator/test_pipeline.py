"""`estimator.pipeline`: stepping an estimator over a recording."""

from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_info

import estimator.egomotion.baselines as baselines
from estimator.camera.files import load_camera
from estimator.pipeline import estimate_frames
from estimator.recording import CanTrack
from estimator.synthetic import RoadTexture, drive_poses, render_road, to_uint8


def test_estimate_frames_runs_the_blas_on_one_thread(monkeypatch) -> None:
    """The estimator's matrices are small: a second BLAS thread only spins beside it."""
    camera, mount = load_camera("omni-far")
    poses = drive_poses(mount, np.arange(3) / 15.0, 20.0, 0.0)
    tex = RoadTexture(seed=2)
    frames = [to_uint8(render_road(camera, T, tex)) for T in poses.T_world_actual]
    seen: list[int] = []
    make = baselines.make_estimator

    def spying_make(*args, **kwargs):
        est = make(*args, **kwargs)
        step = est.step

        def spying_step(*a, **k):
            seen.append(max(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"))
            return step(*a, **k)

        est.step = spying_step
        return est

    monkeypatch.setattr(baselines, "make_estimator", spying_make)
    can = CanTrack(poses.t_s, np.full(3, 21.6))
    run = estimate_frames(frames, poses.t_s, can, camera, mount, "direct")
    assert len(run.records) == 3 and seen == [1, 1, 1]
