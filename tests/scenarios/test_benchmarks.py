"""`omnibench bench estimate` and `bench detect`: what they report (keys), not how fast."""

import json
import subprocess
import sys

import pytest
import yaml

from scenarios.config import LIBRARY_DIR

KEYS = {"bench", "ms_per_frame", "p90_ms_per_frame", "cpu_ms_per_frame", "frames"}


def test_bench_estimate_times_rendered_frames_and_the_synthetic_road(tmp_path):
    """The headline is the median and p90 over rendered frames of a library drive (here
    highway-omni-near at 160 px, 2 frames after 3 of warm-up), rendered into the cache
    and reused; the synthetic road's median and p90 come as synthetic_* keys."""
    sc = yaml.safe_load((LIBRARY_DIR / "highway-omni-near.yaml").read_text())
    sc["camera"] = {"preset": "omni-near", "width": 160, "height": 160}
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(sc))
    cache = tmp_path / "cache"

    def bench():
        proc = subprocess.run(
            [sys.executable, "-m", "scenarios", "bench", "estimate", "--frames", "2",
             "--scenario", str(path), "--camera", "omni-far", "--cache", str(cache), "--json",
             "--repeat", "2"],
            capture_output=True, text=True, timeout=600,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        assert "p90" in proc.stderr and "synthetic road" in proc.stderr
        return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr

    res, log = bench()
    assert KEYS <= set(res)
    assert res["bench"] == "estimate" and res["scenario"] == "highway-omni-near"
    assert res["frames"] == 2 and res["width"] == res["height"] == 160
    assert 0 < res["ms_per_frame"] <= res["p90_ms_per_frame"]
    assert res["repeat"] == 2 and len(res["passes"]) == 2  # each frame's fastest of two
    assert all(res["ms_per_frame"] <= p["ms_per_frame"] for p in res["passes"])
    assert "fastest of 2 passes" in log
    assert res["synthetic_frames"] == 2 and res["synthetic_camera"] == "omni-far"
    assert 0 < res["synthetic_ms_per_frame"] <= res["synthetic_p90_ms_per_frame"]
    drives = [p for p in cache.iterdir() if p.is_dir()]
    assert len(drives) == 1 and len(list((drives[0] / "frames").glob("*.png"))) == 6
    stamp = (drives[0] / "manifest.json").stat().st_mtime_ns
    assert bench()[0]["frames"] == 2
    assert (drives[0] / "manifest.json").stat().st_mtime_ns == stamp, "rendered again"


def test_bench_detect_reports_the_median_and_p90(tmp_path):
    from scenarios.benchmarks import bench_detect

    camera = {"preset": "omni-near", "width": 160, "height": 160}
    res = bench_detect(camera=camera, n_frames=4, cache_dir=tmp_path)
    assert KEYS <= set(res)
    assert res["bench"] == "detect" and res["frames"] == 3
    assert res["vehicles_in_range"] >= 2  # a dense drive, not an empty road
    assert 0 < res["ms_per_frame"] <= res["p90_ms_per_frame"]
    assert res["cpu_ms_per_frame"] > 0
    assert res["scenario"] == "dense-exit-omni-near"
    assert res["machine"]["cpu"] and res["machine"]["cpus"] >= 1  # what the times are of
    stages = res["stages_ms"]  # where a frame's time goes
    assert list(stages) == ["warps", "score", "blobs", "refine", "track"]
    assert all(v >= 0 for v in stages.values()) and stages["score"] > 0
    assert res["repeat"] == 1 and len(res["passes"]) == 1
    # two passes: each frame's fastest, so neither figure exceeds either pass's
    two = bench_detect(camera=camera, n_frames=4, cache_dir=tmp_path, repeat=2)
    assert two["repeat"] == 2 and len(two["passes"]) == 2 and two["frames"] == 3
    for p in two["passes"]:
        assert two["ms_per_frame"] <= p["ms_per_frame"] <= p["p90_ms_per_frame"]
        assert two["p90_ms_per_frame"] <= p["p90_ms_per_frame"]
    with pytest.raises(ValueError, match="repeat must be 1 or more, got 0"):
        bench_detect(camera=camera, n_frames=4, cache_dir=tmp_path, repeat=0)
    with pytest.raises(ValueError, match="dense-exit-omni-near has 225 frames"):
        bench_detect(camera=camera, n_frames=225, cache_dir=tmp_path)
    with pytest.raises(ValueError, match="n_frames must be 2..224, got 1"):
        bench_detect(camera=camera, n_frames=1, cache_dir=tmp_path)  # nothing left to time
