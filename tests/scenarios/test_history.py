"""The results history (SQLite): one row per job of a run, runs, run references, CLI."""

import json
import math
import sqlite3
import subprocess
import sys
import threading

import pytest

from scenarios.history import History, HistoryError, flatten

JOB_A = {
    "job_id": "aaaa1111",
    "label": "highway | omni-near | direct | seed 7",
    "scenario": "highway",
    "camera": "omni-near",
    "estimator": "direct",
    "seed": 7,
    "overrides": {"can.speed_bias": 0.1},
    "frames": 30,
}
JOB_B = {**JOB_A, "job_id": "bbbb2222", "estimator": "can-only", "label": "highway | can-only"}
METRICS = {
    "scenario": "highway",
    "frames": 30,
    "ego": {"speed_rmse_pct": 2.5, "frames_compared": 29},
    "detection": {"recall": 0.8, "precision": math.nan},
    "evaluation": {"nan_reasons": {"detection.precision": "no hypothesis"}},
    "flag": True,
}


def omnibench(*args: str, timeout: int = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=timeout
    )


def test_flatten_keeps_numbers_under_dotted_keys():
    flat = flatten(METRICS)
    assert flat["ego.speed_rmse_pct"] == 2.5
    assert flat["frames"] == 30.0 and flat["flag"] == 1.0
    assert math.isnan(flat["detection.precision"])
    assert "scenario" not in flat and not any(k.startswith("evaluation") for k in flat)


def test_wal_mode_and_schema(tmp_path):
    with History(tmp_path / "h.sqlite") as h:
        assert h.conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    with sqlite3.connect(tmp_path / "h.sqlite") as c:
        tables = {r[0] for r in c.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert {"runs", "jobs", "metrics"} <= tables


def test_a_job_is_recorded_once(tmp_path):
    with History(tmp_path / "h.sqlite") as h:
        h.ensure_run("r1", "smoke", n_jobs=2)
        h.ensure_run("r1", "smoke", n_jobs=2)  # a resumed run keeps its row
        h.record_job("r1", JOB_A, status="ok", metrics=METRICS, wall_s=1.5)
        h.record_job("r1", JOB_A, status="ok", metrics={"ego": {"speed_rmse_pct": 9.0}})
        assert h.job_status("r1") == {"aaaa1111": "ok"}
        assert h.metrics("r1", "aaaa1111")["ego.speed_rmse_pct"] == 2.5  # first kept
        # an error is replaced when the job is tried again
        h.record_job("r1", JOB_B, status="error", error="ValueError: x", traceback="tb")
        h.record_job("r1", JOB_B, status="ok", metrics=METRICS)
        jobs = {j["job_id"]: j for j in h.jobs("r1")}
        assert jobs["bbbb2222"]["status"] == "ok" and jobs["bbbb2222"]["error"] is None
        # a job run again on purpose replaces its row
        h.record_job(
            "r1", JOB_A, status="ok", metrics={"ego": {"speed_rmse_pct": 3.0}}, replace=True
        )
        assert h.metrics("r1", "aaaa1111") == {"ego.speed_rmse_pct": 3.0}
    with sqlite3.connect(tmp_path / "h.sqlite") as c:
        assert c.execute("SELECT COUNT(*) FROM jobs").fetchone()[0] == 2
        with pytest.raises(sqlite3.IntegrityError):
            c.execute("INSERT INTO jobs (run_id, job_id, status) VALUES ('r1', 'aaaa1111', 'ok')")


def test_job_rows_hold_description_commit_and_nan(tmp_path):
    with History(tmp_path / "h.sqlite") as h:
        h.ensure_run("r1", "smoke")
        h.record_job("r1", JOB_A, status="ok", metrics=METRICS, wall_s=2.0, commit="abc123")
        (row,) = h.jobs("r1")
    assert row["overrides"] == {"can.speed_bias": 0.1}
    assert row["commit_sha"] == "abc123" and row["wall_s"] == 2.0
    assert (row["scenario"], row["camera"], row["estimator"], row["seed"], row["frames"]) == (
        "highway", "omni-near", "direct", 7, 30,
    )  # fmt: skip
    assert math.isnan(row["metrics"]["detection.precision"])  # stored as NULL
    assert row["recorded_at"].endswith("+00:00")


def test_runs_list_counts_and_resolve(tmp_path):
    with History(tmp_path / "h.sqlite") as h:
        h.ensure_run("smoke-20260101-aa", "smoke", n_jobs=2)
        h.ensure_run("smoke-20260102-bb", "smoke", n_jobs=2)
        h.ensure_run("paper-20260103-cc", "paper", n_jobs=1)
        h.record_job("smoke-20260101-aa", JOB_A, status="ok", metrics=METRICS)
        h.record_job("smoke-20260101-aa", JOB_B, status="error", error="boom")
        runs = {r.run_id: r for r in h.runs()}
        assert (runs["smoke-20260101-aa"].ok, runs["smoke-20260101-aa"].failed) == (1, 1)
        assert [r.suite for r in h.runs(suite="paper")] == ["paper"]
        assert len(h.runs(limit=2)) == 2
        assert h.resolve_run("paper") == "paper-20260103-cc"
        assert h.resolve_run("smoke-20260102-bb") == "smoke-20260102-bb"
        with pytest.raises(HistoryError, match="ambiguous"):
            h.resolve_run("smoke-2026")
        with pytest.raises(HistoryError, match="no run"):
            h.resolve_run("nothing")
        with pytest.raises(HistoryError, match="no run"):
            h.resolve_run("smoke_2026")  # '_' is no LIKE wildcard here
        run_dir = tmp_path / "run"
        run_dir.mkdir()
        (run_dir / "run.json").write_text(json.dumps({"run_id": "paper-20260103-cc"}))
        assert h.resolve_run(str(run_dir)) == "paper-20260103-cc"
        assert h.resolve_run("latest") in runs


def test_two_writers_do_not_lose_jobs(tmp_path):
    db = tmp_path / "h.sqlite"
    with History(db) as h:
        h.ensure_run("r", "s")

    def write(prefix: str) -> None:
        with History(db) as h:
            for i in range(20):
                h.record_job("r", {**JOB_A, "job_id": f"{prefix}{i}"}, status="ok", metrics=METRICS)

    threads = [threading.Thread(target=write, args=(p,)) for p in ("x", "y")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    with History(db) as h:
        assert len(h.job_status("r")) == 40


def _two_runs(db, recall_b: float) -> None:
    with History(db) as h:
        for run, recall in (("base-run", 0.8), ("new-run", recall_b)):
            h.ensure_run(run, "smoke", n_jobs=1)
            m = {"detection": {"recall": recall}, "ego": {"speed_rmse_mps": 0.5}}
            h.record_job(run, JOB_A, status="ok", metrics=m)


def test_history_and_compare_commands(tmp_path):
    db = tmp_path / "h.sqlite"
    _two_runs(db, recall_b=0.6)
    proc = omnibench("history", "--history", str(db))
    assert proc.returncode == 0, proc.stderr
    assert "base-run" in proc.stdout and "new-run" in proc.stdout and "smoke" in proc.stdout
    proc = omnibench("compare", "base-run", "new-run", "--history", str(db))
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "REGRESSION" in proc.stdout and "detection.recall" in proc.stdout
    assert "-0.2" in proc.stdout and "tolerance" in proc.stdout
    proc = omnibench("compare", "new-run", "base-run", "--history", str(db))
    assert proc.returncode == 0, proc.stdout + proc.stderr  # recall up is good
    assert "better" in proc.stdout and "no regression" in proc.stdout


def test_compare_within_tolerance_and_bad_references(tmp_path):
    db = tmp_path / "h.sqlite"
    _two_runs(db, recall_b=0.79)  # -1.25 %: inside the default 5 %
    assert omnibench("compare", "base-run", "new-run", "--history", str(db)).returncode == 0
    tight = omnibench(
        "compare", "base-run", "new-run", "--history", str(db), "--tolerance", "0.001",
        "--abs-tolerance", "0",
    )  # fmt: skip
    assert tight.returncode == 1
    bad = omnibench("compare", "base-run", "nope", "--history", str(db))
    assert bad.returncode == 2 and "nope" in bad.stderr
    missing = omnibench("history", "--history", str(tmp_path / "none.sqlite"))
    assert missing.returncode == 2 and "none.sqlite" in missing.stderr
