"""Regression test on detection recall: the `smoke` suite against its committed baseline.

Runs scenarios/suites/smoke.yaml for real (24 short jobs: render, estimate, detect, track;
~4 minutes on 2 cores) and fails, naming the job, the metric and the delta, when recall,
precision, MOTA, the speed, yaw-rate or A RMSE is worse than scenarios/baselines/smoke.json
by more than `TOLERANCE`. A change that makes them worse on purpose updates the baseline on purpose:
``omnibench suite scenarios/suites/smoke.yaml --out DIR && omnibench baseline update DIR``.
"""

from __future__ import annotations

import json
from pathlib import Path

from scenarios.regression import BASELINE_METRICS, Tolerance, check_baseline, render_note
from scenarios.suite import load_suite
from scenarios.suite_runner import run_suite

# worse by more than 5 % of the baseline value and by more than 0.05 (absolute: one
# detection of the ~29 per drive moves recall by 0.034, renders of another CPU may
# differ by a pixel here and there; the yaw-rate and A RMSEs have their own floors,
# `scenarios.regression.ABS_TOLERANCES`) is a regression
TOLERANCE = Tolerance(rel=0.05, abs_=0.05)


def test_smoke_suite_holds_its_baseline(tmp_path: Path) -> None:
    run_dir = tmp_path / "smoke"
    res = run_suite(
        load_suite("smoke"),
        run_dir,
        workers=2,
        history=tmp_path / "history.sqlite",
        cache_dir=tmp_path / "cache",
        progress=False,
    )
    errors = [f"{o.job.label}: {o.error}" for o in res.outcomes if o.status != "ok"]
    assert not errors, "smoke jobs failed:\n" + "\n".join(errors)
    # the recall guard stands on many vehicles: at least 5 distinct ones and 150
    # vehicle-frames in the direct estimator's jobs (the dense drives bring most)
    direct = [
        json.loads((run_dir / o.job.describe()["dir"] / "metrics.json").read_text())
        for o in res.outcomes
        if o.job.estimator == "direct"
    ]
    assert sum(m["detection"]["gt_count"] for m in direct) >= 150
    assert max(m["surround"]["gt_vehicles"] for m in direct) >= 5
    cmp = check_baseline(run_dir, TOLERANCE)
    assert not cmp.only_base, f"baseline jobs not run: {cmp.only_base}"
    assert len(cmp.deltas) == len(BASELINE_METRICS) * len(res.outcomes)
    problems = [d.describe() for d in cmp.regressions] + [
        f"{label}: failed: {err}" for _, label, err in cmp.failed
    ]
    assert cmp.ok, (
        f"{len(problems)} regression(s) against scenarios/baselines/smoke.json "
        f"({TOLERANCE.describe()}):\n" + "\n".join(problems) + f"\n{render_note(run_dir) or ''}"
    )
