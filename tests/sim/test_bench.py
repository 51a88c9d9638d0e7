"""`omnibench bench render`: what it reports (keys), not how fast."""

import time

import pytest

from sim.bench import bench_render


def test_bench_render_reports_wall_and_cpu_time_per_frame_and_its_stages():
    """Two frames after one of warm-up, a small omni camera: the median and p90 wall time,
    the process's CPU time per frame (in ms: more than any frame can cost less, and no more
    than the whole call's CPU time; both hold on a loaded machine), and every stage of the
    plane renderer and of the sensor."""
    cpu0 = time.process_time()
    res = bench_render(
        n_frames=2,
        camera={"preset": "omni-far", "width": 160, "height": 160},
        vehicles=4,
        warmup=1,
    )
    assert res["frames"] == 2 and res["width"] == res["height"] == 160
    assert 0 < res["ms_per_frame"] <= res["ms_p90"]
    assert res["frames_per_s"] == 1000.0 / res["ms_per_frame"]
    call_cpu_ms = 1000.0 * (time.process_time() - cpu0)
    assert 1.0 <= res["cpu_ms_per_frame"] and res["frames"] * res["cpu_ms_per_frame"] <= call_cpu_ms
    assert set(res["stages_ms"]) == {
        "vehicles", "objects_gl", "plane_after_gl", "composite", "motion", "sensor",
    }  # fmt: skip


def test_bench_render_times_shadows_and_refuses_them_on_the_cube_renderer():
    cam = {"preset": "omni-far", "width": 160, "height": 160}
    res = bench_render(n_frames=2, camera=cam, vehicles=4, warmup=1, shadows=True)
    assert res["shadows"] is True and res["frames"] == 2
    with pytest.raises(ValueError, match="shadows"):
        bench_render(n_frames=2, camera=cam, vehicles=4, warmup=1, renderer="cube", shadows=True)
