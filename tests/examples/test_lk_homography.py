"""The example plug-in, run as a user would: through run, evaluate and a suite."""

from __future__ import annotations

import json
import math
import sqlite3
from pathlib import Path

from tests.examples.example_run import run_example

PLUGIN = "lk_homography:LKHomographyEstimator"


def test_example_plugin_runs_through_run_evaluate_and_a_suite(tmp_path: Path):
    proc = run_example("lk_homography", tmp_path, 12, 900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ran = json.loads((tmp_path / "run" / "metrics.json").read_text())
    scored = json.loads((tmp_path / "evaluated" / "metrics.json").read_text())
    assert ran["estimator"] == PLUGIN
    for key in ("speed_rmse_pct", "yaw_rate_rmse_dps", "angle_rmse_deg", "frames_compared"):
        assert scored["ego"][key] == ran["ego"][key], key
    # a working estimator: tracks that lock onto the car body give 50-130 % here
    assert math.isfinite(ran["ego"]["speed_rmse_pct"]) and ran["ego"]["speed_rmse_pct"] < 15.0
    summary = json.loads((tmp_path / "suite" / "summary.json").read_text())
    estimators = sorted(j["estimator"] for j in summary["jobs"])
    assert estimators == sorted(["direct", PLUGIN])
    assert all(j["status"] == "ok" for j in summary["jobs"])
    assert PLUGIN in (tmp_path / "suite" / "report.html").read_text()
    with sqlite3.connect(tmp_path / "history.sqlite") as db:
        tables = [r[0] for r in db.execute("select name from sqlite_master where type='table'")]
        rows = "\n".join(str(r) for t in tables for r in db.execute(f"select * from {t}"))
    assert PLUGIN in rows and "direct" in rows
