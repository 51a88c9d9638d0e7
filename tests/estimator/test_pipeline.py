"""`estimator.pipeline`: stepping an estimator over a recording."""

from __future__ import annotations

import numpy as np
import pytest
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


def test_estimate_frames_takes_lazy_times_for_any_number_of_frames(monkeypatch) -> None:
    """Times from `frame_times` (no end) serve a recording of any length, here over 100000
    frames; the progress bar's total is the frame count given."""
    from types import SimpleNamespace

    import estimator.pipeline as pipeline
    from estimator.recording import frame_times

    class Stub:
        def step(self, image, t_s, can_speed_mps, road_mask=None):
            return SimpleNamespace(t_s=t_s)

    monkeypatch.setattr(baselines, "make_estimator", lambda *a, **k: Stub())
    totals = []
    real_track = pipeline.track

    def spy(items, total, label, enabled=True):
        totals.append(total)
        return real_track(items, total, label, False)

    monkeypatch.setattr(pipeline, "track", spy)
    camera, mount = load_camera("omni-far")
    n = 100_001
    image = np.zeros((2, 2), np.uint8)
    can = CanTrack(np.array([0.0]), np.array([20.0]))
    run = estimate_frames(
        (image for _ in range(n)), frame_times(15.0), can, camera, mount, "stub", n_frames=n
    )
    assert len(run.records) == n and totals == [n]
    assert run.records[-1].t_s == (n - 1) / 15.0
    try:
        estimate_frames([image] * 3, np.arange(2) / 15.0, can, camera, mount, "stub")
    except ValueError as e:
        assert "more frames than timestamps (2)" in str(e)
    else:
        raise AssertionError("a frame without a time was taken")


@pytest.mark.parametrize("fps", [0.0, -15.0, float("nan"), float("inf")])
def test_frame_times_refuses_a_bad_rate_when_called(fps):
    """The rate is checked before any frame is read, not at the first frame."""
    from estimator.recording import RecordingError, frame_times

    with pytest.raises(RecordingError, match="frame rate must be finite and > 0"):
        frame_times(fps)


def test_frame_times_are_k_over_fps():
    from itertools import islice

    from estimator.recording import frame_times

    assert list(islice(frame_times(15.0), 4)) == [0.0, 1 / 15, 2 / 15, 3 / 15]
