"""Wall-clock and CPU time of the frames a benchmark times (`omnibench bench ...`), and
of the stages of one frame."""

from __future__ import annotations

import time

import numpy as np


class FrameTimes:
    """Per-frame wall-clock and process CPU time (all threads) between `start` and `stop`."""

    def __init__(self) -> None:
        self.wall_s: list[float] = []
        self.cpu_s: list[float] = []
        self.start()

    def start(self) -> None:
        self._t0, self._c0 = time.perf_counter(), time.process_time()

    def stop(self, keep: bool = True) -> None:
        """End a frame; keep its times unless it is a warm-up frame."""
        if keep:
            self.wall_s.append(time.perf_counter() - self._t0)
            self.cpu_s.append(time.process_time() - self._c0)

    def summary(self) -> dict:
        """ms_per_frame and cpu_ms_per_frame (medians), p90_ms_per_frame, frames."""
        ms = 1000.0 * np.asarray(self.wall_s)
        return {
            "ms_per_frame": float(np.median(ms)),
            "p90_ms_per_frame": float(np.percentile(ms, 90)),
            "cpu_ms_per_frame": float(np.median(1000.0 * np.asarray(self.cpu_s))),
            "frames": len(ms),
        }


def fastest_pass(passes: list[FrameTimes]) -> FrameTimes:
    """Each frame's least wall and CPU time over passes that timed the same frames.

    A pass over the same frames does the same work; what another process on the machine
    takes from it only adds time, so a frame's fastest pass is its own cost (as
    ``timeit`` takes the minimum of its repeats)."""
    if not passes or len({len(p.wall_s) for p in passes}) != 1:
        raise ValueError(
            f"fastest_pass needs passes over the same frames, got {[len(p.wall_s) for p in passes]}"
        )
    out = FrameTimes()
    out.wall_s = np.min([p.wall_s for p in passes], axis=0).tolist()
    out.cpu_s = np.min([p.cpu_s for p in passes], axis=0).tolist()
    return out


def passes_summary(passes: list[FrameTimes]) -> dict:
    """`FrameTimes.summary` of the `fastest_pass` of passes over the same frames, with
    ``repeat`` (how many passes) and ``passes`` (each one's median and p90, as timed)."""
    timed = [p.summary() for p in passes]
    return {
        **fastest_pass(passes).summary(),
        "repeat": len(passes),
        "passes": [{k: s[k] for k in ("ms_per_frame", "p90_ms_per_frame")} for s in timed],
    }


class StageClock:
    """Seconds spent per named stage of the last frame (`omnibench bench render`, `bench
    detect`)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._t = time.perf_counter()

    def start(self) -> None:
        self.seconds = {}
        self._t = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Charge the time since the last lap (or start) to stage."""
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._t
        self._t = now
