"""`FrameTimes`: the per-frame wall and CPU times of the benchmarks."""

import time

import pytest

from estimator.frame_times import FrameTimes, fastest_pass, passes_summary


def test_warm_up_frames_are_left_out_and_busy_frames_count_cpu_time():
    clock = FrameTimes()
    for k in range(4):
        clock.start()
        if k == 0:
            time.sleep(0.05)  # a warm-up frame, slow and idle: not kept
        else:
            end = time.process_time() + 0.01
            while time.process_time() < end:  # busy for 10 ms of CPU, however shared
                pass
        clock.stop(keep=k > 0)
    s = clock.summary()
    assert s["frames"] == 3
    # one busy thread: 10 ms of CPU a frame, within its wall time
    assert 10.0 <= s["cpu_ms_per_frame"] <= s["ms_per_frame"] + 0.5
    assert s["ms_per_frame"] <= s["p90_ms_per_frame"]


def test_fastest_pass_keeps_each_frames_least_time():
    a, b = FrameTimes(), FrameTimes()
    a.wall_s, a.cpu_s = [0.010, 0.030, 0.020], [0.009, 0.010, 0.019]
    b.wall_s, b.cpu_s = [0.012, 0.011, 0.025], [0.011, 0.010, 0.018]
    best = fastest_pass([a, b])
    assert best.wall_s == [0.010, 0.011, 0.020] and best.cpu_s == [0.009, 0.010, 0.018]
    assert best.summary()["frames"] == 3
    s = passes_summary([a, b])  # the fastest pass's figures, and every pass as timed
    assert s["repeat"] == 2 and s["frames"] == 3 and s["ms_per_frame"] == pytest.approx(11.0)
    assert [p["ms_per_frame"] for p in s["passes"]] == pytest.approx([20.0, 12.0])
    # a pass over other frames cannot be compared frame by frame
    b.wall_s.append(0.01)
    with pytest.raises(ValueError, match=r"same frames, got \[3, 4\]"):
        fastest_pass([a, b])
    with pytest.raises(ValueError, match="same frames"):
        fastest_pass([])
