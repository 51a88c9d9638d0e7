"""The example detector plug-in, run as a user would: through run and evaluate."""

from __future__ import annotations

import json
import math
from pathlib import Path

from tests.examples.example_run import run_example

PLUGIN = "plan_difference:PlanDifferenceDetector"


def test_example_detector_runs_through_run_and_evaluate(tmp_path: Path):
    """Its tracks are scored by the run and again by evaluate to the same figures; it finds
    the car ahead (its recall is the example's, docs/PLUGINS.md, not a detector's to
    guard); points only: no MOT file."""
    proc = run_example("plan_difference", tmp_path, 12, 300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ran = json.loads((tmp_path / "run" / "metrics.json").read_text())
    scored = json.loads((tmp_path / "evaluated" / "metrics.json").read_text())
    assert ran["detector"] == PLUGIN
    for section in ("tracking", "track_detection"):
        for key, value in ran[section].items():
            other = scored[section][key]
            assert (math.isnan(value) and math.isnan(other)) or value == other, (section, key)
    det = ran["track_detection"]
    assert det["gt_count"] == 11 and det["recall"] > 0.0
    assert math.isnan(ran["tracking"]["hota_box"])
    assert not (tmp_path / "run" / "tracks.mot.txt").exists()
    assert f"{PLUGIN}: recall" in proc.stdout
