"""Direction-aware comparison and baselines, on synthetic metrics dicts."""

import json
import math
import subprocess
import sys

import pytest

from scenarios.regression import (
    BASELINE_METRICS,
    BASELINES_DIR,
    BaselineError,
    Tolerance,
    check_baseline,
    compare_jobs,
    is_regression,
    render_note,
    update_baseline,
)

MACHINE = {"cpu": "AMD EPYC", "cpus": 2, "gl_renderer": "llvmpipe (LLVM 15.0.6, 256 bits)"}

TOL = Tolerance(rel=0.05, abs_=0.005)


def job(label: str, status: str = "ok", error: str | None = None, **metrics) -> dict:
    return {"label": label, "status": status, "error": error, "metrics": metrics}


@pytest.mark.parametrize(
    "metric, base, new, regressed",
    [
        ("detection.recall", 0.80, 0.70, True),  # recall down: bad
        ("detection.recall", 0.80, 0.90, False),  # recall up: good
        ("detection.recall", 0.80, 0.79, False),  # -1.25 % < 5 %
        ("ego.speed_rmse_mps", 0.50, 0.60, True),  # RMSE up: bad
        ("ego.speed_rmse_mps", 0.50, 0.30, False),  # RMSE down: good
        ("ego.speed_rmse_mps", 0.50, 0.52, False),  # +4 % < 5 %
        ("ego.speed_rmse_mps", 0.000, 0.004, False),  # under the absolute floor
        ("tracking.mota", -0.50, -0.60, True),  # negative MOTA going down
        ("tracking.id_switches", 2.0, 5.0, True),
        ("timing.estimate_ms_per_frame", 10.0, 50.0, False),  # no direction
        ("detection.precision", 0.5, math.nan, True),  # became NaN
        ("detection.precision", math.nan, 0.5, False),
        ("detection.precision", math.nan, math.nan, False),
    ],
)
def test_is_regression_knows_the_direction(metric, base, new, regressed):
    assert is_regression(metric, base, new, TOL)[0] is regressed


def test_tolerance_checks_and_describes():
    assert TOL.allowed(1.0) == pytest.approx(0.05)
    assert TOL.allowed(0.01) == pytest.approx(0.005)
    assert "5 %" in TOL.describe() and "0.005" in TOL.describe()
    with pytest.raises(ValueError):
        Tolerance(rel=-0.1)


def test_compare_jobs_reports_deltas_failures_and_unmatched():
    base = {
        "a": job("A", **{"detection.recall": 0.8, "ego.speed_rmse_mps": 0.5}),
        "b": job("B", **{"detection.recall": 0.6}),
        "c": job("C", **{"detection.recall": 0.6}),
        "gone": job("gone"),
    }
    new = {
        "a": job("A", **{"detection.recall": 0.7, "ego.speed_rmse_mps": 0.4}),
        "b": job("B", status="error", error="RuntimeError: boom"),
        "c": job("C", **{"detection.recall": 0.61}),
        "added": job("added"),
    }
    cmp = compare_jobs(base, new, TOL)
    assert [(d.job_id, d.metric) for d in cmp.regressions] == [("a", "detection.recall")]
    d = cmp.regressions[0]
    assert d.delta == pytest.approx(-0.1)
    assert "detection.recall 0.8 -> 0.7" in d.describe() and "-12.5 %" in d.describe()
    better = [x for x in cmp.deltas if x.improved]
    assert {(x.job_id, x.metric) for x in better} == {
        ("a", "ego.speed_rmse_mps"),
        ("c", "detection.recall"),
    }
    assert cmp.failed == [("b", "B", "RuntimeError: boom")]
    assert cmp.only_base == [("gone", "gone")] and cmp.only_new == [("added", "added")]
    assert not cmp.ok


def test_compare_limited_to_metrics():
    base = {"a": job("A", **{"detection.recall": 0.8, "tracking.idf1": 0.9})}
    new = {"a": job("A", **{"detection.recall": 0.8, "tracking.idf1": 0.1})}
    assert not compare_jobs(base, new, TOL).ok
    assert compare_jobs(base, new, TOL, metrics=BASELINE_METRICS).ok


# ------------------------------------------------------------------ baselines
def summary(run_id: str, jobs: dict[str, dict]) -> dict:
    return {
        "suite": "synthetic",
        "run_id": run_id,
        "commit": "abc",
        "render_machines": [MACHINE],
        "jobs": [
            {"job_id": jid, "label": f"job {jid}", "status": "ok", "metrics": m}
            for jid, m in jobs.items()
        ],
    }


GOOD = {
    "detection.recall": 0.8,
    "detection.precision": 0.7,
    "tracking.mota": 0.5,
    "ego.speed_rmse_mps": 0.4,
    "timing.render_ms_per_frame": 100.0,
}


def write_run(path, run_id: str, jobs: dict[str, dict]):
    path.mkdir(parents=True, exist_ok=True)
    (path / "summary.json").write_text(json.dumps(summary(run_id, jobs)))
    return path


def test_update_then_check_a_baseline(tmp_path):
    bdir = tmp_path / "baselines"
    run1 = write_run(
        tmp_path / "r1", "r1", {"j1": GOOD, "j2": {**GOOD, "detection.precision": None}}
    )
    path, changes, data = update_baseline(run1, bdir)
    assert path == bdir / "synthetic.json"
    assert changes == ["added job j1", "added job j2"]
    stored = json.loads(path.read_text())
    assert stored["jobs"]["j2"]["metrics"]["detection.precision"] is None  # NaN as null
    assert stored["from_run"] == "r1"
    assert check_baseline(run1, TOL, bdir).ok
    # the machines that rendered the baseline's drives: a run rendered elsewhere is told so
    assert stored["render_machines"] == [MACHINE] and render_note(run1, bdir) is None
    other = json.loads((run1 / "summary.json").read_text())
    other["render_machines"] = [{**MACHINE, "gl_renderer": "llvmpipe (LLVM 15.0.6, 512 bits)"}]
    (tmp_path / "r3").mkdir()
    (tmp_path / "r3" / "summary.json").write_text(json.dumps(other))
    note = render_note(tmp_path / "r3", bdir)
    assert "256 bits" in note and "512 bits" in note and "renders differ" in note
    del other["render_machines"]  # not recorded: nothing to say
    (tmp_path / "r3" / "summary.json").write_text(json.dumps(other))
    assert render_note(tmp_path / "r3", bdir) is None

    worse = {**GOOD, "detection.recall": 0.7, "ego.speed_rmse_mps": 0.5}
    run2 = write_run(tmp_path / "r2", "r2", {"j1": worse, "j2": GOOD})
    cmp = check_baseline(run2, TOL, bdir)
    assert sorted(d.metric for d in cmp.regressions) == ["detection.recall", "ego.speed_rmse_mps"]
    # an update on purpose says what changed (timing is noise, not reported)
    _, changes, _ = update_baseline(run2, bdir)
    assert "job j1: detection.recall 0.8 -> 0.7" in changes
    assert not any("timing" in c for c in changes)
    assert check_baseline(run2, TOL, bdir).ok


def test_baseline_guards_the_yaw_rate_and_a_rmse_with_their_own_floors(tmp_path):
    """`omnibench baseline check` watches the yaw-rate RMSE [deg/s] and A's RMSE [deg], each
    with an absolute floor in its unit; the committed smoke baseline holds both for every
    job."""
    assert {"ego.yaw_rate_rmse_dps", "ego.angle_rmse_deg"} <= set(BASELINE_METRICS)
    loose = Tolerance(rel=0.05, abs_=0.05)  # the smoke test's general floor
    for metric, floor in (("ego.yaw_rate_rmse_dps", 0.05), ("ego.angle_rmse_deg", 0.01)):
        assert loose.abs_for(metric) == floor == TOL.abs_for(metric)
        assert not is_regression(metric, 0.0, 0.9 * floor, loose)[0]
        assert is_regression(metric, 0.0, 1.1 * floor, loose)[0]
    # A's RMSE 0.24 -> 0.28 deg (+17 %) regresses, though under the general floor of 0.05
    assert is_regression("ego.angle_rmse_deg", 0.24, 0.28, loose)[0]
    assert "ego.angle_rmse_deg 0.01" in TOL.describe()
    with pytest.raises(ValueError, match="ego.angle_rmse_deg"):
        Tolerance(per_metric={"ego.angle_rmse_deg": -1.0})

    bdir = tmp_path / "baselines"
    good = {**GOOD, "ego.yaw_rate_rmse_dps": 0.7, "ego.angle_rmse_deg": 0.2}
    update_baseline(write_run(tmp_path / "r1", "r1", {"j1": good}), bdir)
    worse = {**good, "ego.yaw_rate_rmse_dps": 0.9, "ego.angle_rmse_deg": 0.25}
    cmp = check_baseline(write_run(tmp_path / "r2", "r2", {"j1": worse}), TOL, bdir)
    assert sorted(d.metric for d in cmp.regressions) == [
        "ego.angle_rmse_deg",
        "ego.yaw_rate_rmse_dps",
    ]

    smoke = json.loads((BASELINES_DIR / "smoke.json").read_text())["jobs"]
    for jid, j in smoke.items():
        for key in BASELINE_METRICS:
            if key.startswith("ego."):
                assert math.isfinite(j["metrics"][key]), (jid, key)


def test_check_baseline_errors(tmp_path):
    bdir = tmp_path / "baselines"
    with pytest.raises(BaselineError, match="summary.json"):
        check_baseline(tmp_path, TOL, bdir)
    run = write_run(tmp_path / "r", "r", {"j1": GOOD})
    with pytest.raises(BaselineError, match="baseline update"):
        check_baseline(run, TOL, bdir)
    update_baseline(run, bdir)
    other = write_run(tmp_path / "o", "o", {"zz": GOOD})
    with pytest.raises(BaselineError, match="no job"):
        check_baseline(other, TOL, bdir)


def test_baseline_commands(tmp_path):
    def omnibench(*args):
        return subprocess.run(
            [sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=120
        )

    bdir = str(tmp_path / "baselines")
    run1 = write_run(tmp_path / "r1", "r1", {"j1": GOOD})
    up = omnibench("baseline", "update", str(run1), "--baselines-dir", bdir)
    assert up.returncode == 0, up.stderr
    assert "added job j1" in up.stdout and "synthetic.json" in up.stdout
    ok = omnibench("baseline", "check", str(run1), "--baselines-dir", bdir)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    run2 = write_run(tmp_path / "r2", "r2", {"j1": {**GOOD, "tracking.mota": 0.3}})
    bad = omnibench("baseline", "check", str(run2), "--baselines-dir", bdir)
    assert bad.returncode == 1
    assert "tracking.mota" in bad.stdout and "-0.2" in bad.stdout and "REGRESSION" in bad.stdout
    loose = omnibench("baseline", "check", str(run2), "--baselines-dir", bdir, "--tolerance", "0.5")
    assert loose.returncode == 0, loose.stdout
    missing = omnibench("baseline", "check", str(tmp_path / "nowhere"), "--baselines-dir", bdir)
    assert missing.returncode == 2 and "summary.json" in missing.stderr
