"""docs/RESULTS.md is generated from suite summaries and bench outputs, never typed."""

from __future__ import annotations

import json

import pytest

from scenarios.results_doc import ResultsError, load_bench, results_markdown


def _summary(tmp_path, role="check"):
    run = tmp_path / "run"
    run.mkdir()
    job = {
        "label": "merge | omni-far | direct | seed 3",
        "scenario": "merge-omni-far",
        "camera": "omni-far",
        "estimator": "direct",
        "seed": 3,
        "status": "ok",
        "metrics": {
            "frames": 150.0,
            "ego.speed_rmse_pct": 1.2345,
            "ego.mean_speed_mps": 20.0,
            "ego.prior_speed_rmse_mps": 1.6,
            "ego.yaw_rate_rmse_dps": 0.3456,
            "ego.angle_rmse_deg": 0.0551,
            "detection.gt_count": 149.0,
            "detection.recall": 0.93,
            "surround.tracks.ego_state.moving.detection.gt_count": 140.0,
            "surround.tracks.ego_state.moving.detection.recall": 0.91,
            "surround.tracks.ego_state.moving.tracking.mota": 0.88,
            "surround.tracks.ego_state.moving.tracking.hota": float("nan"),
            "surround.tracks.ego_state.stopped.detection.gt_count": 9.0,
        },
    }
    failed = {"label": "merge | omni-far | features | seed 3", "status": "error", "error": "boom"}
    summary = {
        "suite": "check-x",
        "role": role,
        "run_id": "check-x-1",
        "commit": "abc123",
        "dirty": False,
        "finished_at": "2026-12-04T10:00:00+00:00",
        "description": "a check",
        "jobs": [job, failed],
    }
    (run / "summary.json").write_text(json.dumps(summary))
    return run


def test_page_states_provenance_role_and_every_figure(tmp_path):
    run = _summary(tmp_path)
    bench = tmp_path / "bench.json"
    bench.write_text(
        'progress...\n{"bench": "estimate", "ms_per_frame": 12.5, '
        '"p90_ms_per_frame": 14.0, "cpu_ms_per_frame": 11.6, "frames": 40}\n'
    )
    page = results_markdown([run], [bench], "omnibench results run")
    assert "`omnibench results run`" in page
    assert "commit `abc123`" in page and "check-x-1" in page
    assert "check suite" in page
    assert "| merge-omni-far | omni-far | direct | 3 | 150 | 1.23 | 8.00 | 0.346 | 0.055 |" in page
    # the tracks over the frames where the ego car moves, then the detections' own recall
    assert "| 140 | 0.91 | – | 0.88 | – | – | – | – | 9 | 0.93 |" in page
    assert "1 jobs did not finish" in page and "boom" in page
    assert "| estimate | 12.5 | 14.0 | 80.00 | 12 | 40 |" in page
    detect = tmp_path / "detect.json"
    detect.write_text(
        '{"bench": "detect", "scenario": "dense-exit-omni-near", "ms_per_frame": 20.0}'
    )
    page = results_markdown([run], [detect], "omnibench results run")
    assert "| detect (dense-exit-omni-near) | 20.0 |" in page  # with the drive it timed
    learned = tmp_path / "learned.json"
    learned.write_text(
        '{"bench": "detect", "scenario": "dense-exit-omni-near", "detector": "learned", '
        '"ms_per_frame": 40.0}'
    )
    page = results_markdown([run], [detect, learned], "omnibench results run")
    assert "| detect (dense-exit-omni-near) | 20.0 |" in page  # the default: no name
    assert "| detect (dense-exit-omni-near, learned) | 40.0 |" in page


def test_tuning_suite_is_said_to_be_not_held_out(tmp_path):
    page = results_markdown([_summary(tmp_path, role="tuning")], [], "omnibench results run")
    assert "not held out" in page


def test_unreadable_inputs_name_the_path(tmp_path):
    with pytest.raises(ResultsError, match="no summary.json"):
        results_markdown([tmp_path], [], "x")
    p = tmp_path / "b.json"
    p.write_text("no json here\n")
    with pytest.raises(ResultsError, match="b.json"):
        load_bench(p)


def test_readme_headline_block_is_replaced_and_nothing_else(tmp_path):
    from scenarios.results_doc import (
        README_BEGIN,
        README_END,
        headline_markdown,
        load_summary,
        replace_readme_block,
    )

    block = headline_markdown([load_summary(_summary(tmp_path))])
    assert (
        "| `check-x` | check | 1 | 1.23 | 0.35 | 0.055 | 0.91 |" in block
    )  # the tracks, ego moving
    readme = f"# title\n\n{README_BEGIN}\nold figures\n{README_END}\n\nmore text\n"
    new = replace_readme_block(readme, block)
    assert "old figures" not in new and block in new
    assert new.startswith("# title\n\n") and new.endswith(f"{README_END}\n\nmore text\n")
    with pytest.raises(ResultsError, match="headline block"):
        replace_readme_block("# no block\n", block)
