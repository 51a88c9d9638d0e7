"""`FrameTimes`: the per-frame wall and CPU times of the benchmarks."""

import time

from estimator.frame_times import FrameTimes


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
