"""docs/RESULTS.md is generated from suite summaries and bench outputs, never typed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scenarios.results_doc import ResultsError, load_bench, record_of, results_markdown

# a benchmark line's machine (`sim.machine.machine_info`), as JSON
MACHINE = (
    '{"cpu": "AMD EPYC", "cpus": 2, "gl_renderer": "llvmpipe (LLVM 15.0.6, 256 bits)", '
    '"gl_version": "4.5"}'
)


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
    assert "The run does not record its machines." in page
    assert "| merge-omni-far | omni-far | direct | 3 | 150 | 1.23 | 8.00 | 0.346 | 0.055 |" in page
    # the tracks over the frames where the ego car moves, then the detections' own recall;
    # a figure no job has is no column (HOTA, NaN in the one job that has it, stays)
    assert "| 140 | 0.91 | 0.88 | – | 9 | 0.93 |" in page
    assert "| HOTA |" in page and "IDF1" not in page and "position NEES" not in page
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
    # timed over passes: said so, and each pass as timed beside the fastest-pass figures
    detect.write_text(
        '{"bench": "detect", "scenario": "dense-exit-omni-near", "ms_per_frame": 17.0, '
        '"p90_ms_per_frame": 19.0, "repeat": 2, "passes": [{"ms_per_frame": 18.0, '
        '"p90_ms_per_frame": 21.0}, {"ms_per_frame": 17.5, "p90_ms_per_frame": 26.0}]}'
    )
    page = results_markdown([run], [detect], "omnibench results run")
    what = "detect (dense-exit-omni-near, each frame's fastest of 2 passes)"
    assert f"| {what} | 17.0 | 19.0 |" in page
    assert f"- {what}: each pass's median / p90 18.0 / 21.0, 17.5 / 26.0 ms" in page
    assert f"- {what}: machine: not recorded" in page
    # the machine a bench ran on, and those a suite run's jobs and drives ran on
    detect.write_text('{"bench": "detect", "ms_per_frame": 17.0, "machine": ' + MACHINE + "}")
    summary = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(
        json.dumps(summary | {"machine": {"cpu": "AMD EPYC", "cpus": 2}, "render_machines": []})
    )
    page = results_markdown([run], [detect], "omnibench results run")
    assert "| detect on AMD EPYC | 17.0 |" in page  # the row names the CPU
    assert (
        "- detect on AMD EPYC: machine: AMD EPYC (2 CPUs), llvmpipe (LLVM 15.0.6, 256 bits)" in page
    )
    assert "Jobs run on AMD EPYC (2 CPUs). Drives rendered on machines not recorded." in page


def _page_with(tmp_path, metrics: dict) -> tuple[str, dict]:
    """The results page of `_summary`'s run with ``metrics`` added to its first job, and
    that run's summary."""
    run = _summary(tmp_path)
    summary = json.loads((run / "summary.json").read_text())
    summary["jobs"][0]["metrics"] |= metrics
    (run / "summary.json").write_text(json.dumps(summary))
    return results_markdown([run], [], "omnibench results run"), summary


def test_the_tracks_state_is_a_column_where_a_job_has_it(tmp_path):
    state = "surround.track_state.ego_state.moving."
    page, _ = _page_with(
        tmp_path, {state + "velocity.median_error_mps": 1.234, state + "position_nees.mean": 2.46}
    )
    assert "| median velocity error [m/s] | position NEES (2: honest) |" in page
    assert "| 140 | 0.91 | 0.88 | – | 1.23 | 2.5 | 9 | 0.93 |" in page
    assert "COCO" not in page  # no job has the recall by apparent size: no such columns


def test_the_recall_by_apparent_size_is_a_column_each_where_a_job_has_it(tmp_path):
    sizes = "surround.tracks.ego_state.moving.sizes."
    page, summary = _page_with(
        tmp_path,
        {sizes + "small.recall": 0.125, sizes + "medium.recall": 0.5, sizes + "large.recall": 1.0},
    )
    assert "| recall, small (COCO) | recall, medium (COCO) | recall, large (COCO) |" in page
    assert "| – | 0.12 | 0.50 | 1.00 | 9 |" in page
    # the record of a run keeps them (the page regenerated from it)
    assert sizes + "medium.recall" in record_of(summary)["jobs"][0]["metrics"]


def test_the_tracker_losses_are_a_column_where_a_job_has_them(tmp_path):
    page, summary = _page_with(tmp_path, {"surround.tracker.lost_share": 0.1717})
    assert "| share of the candidates' finds the tracker lost |" in page
    assert "| 0.17 |" in page
    assert "surround.tracker.lost_share" in record_of(summary)["jobs"][0]["metrics"]
    old = tmp_path / "old"  # a run made before the figure: no such column
    old.mkdir()
    page, _ = _page_with(old, {})
    assert "tracker lost" not in page


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


def test_a_record_regenerates_the_same_page_and_keeps_only_what_it_reads(tmp_path):
    """A run's record (`record_of`) stands in for its folder: the same section, figures
    and provenance; the metrics the page does not read are left out."""
    from datetime import UTC, datetime

    from scenarios.results_doc import load_summary, record_of

    run = _summary(tmp_path)
    summary = json.loads((run / "summary.json").read_text())
    summary["jobs"][0]["metrics"]["surround.tracks.range_bands.0-5 m.recall"] = 0.5
    summary["jobs"][0]["dir"] = "jobs/merge"
    summary["cache_dir"] = "/somewhere/cache"
    (run / "summary.json").write_text(json.dumps(summary))
    record = record_of(load_summary(run))
    assert "surround.tracks.range_bands.0-5 m.recall" not in record["jobs"][0]["metrics"]
    assert "cache_dir" not in record and "dir" not in record["jobs"][0]
    path = tmp_path / "check-x.json"
    path.write_text(json.dumps(record))
    now = datetime(2026, 12, 7, tzinfo=UTC)
    from_run = results_markdown([run], [], "omnibench results x", now)
    assert results_markdown([path], [], "omnibench results x", now) == from_run
    assert "| 140 | 0.91 | 0.88 |" in from_run


def test_a_json_file_that_is_no_record_is_refused_naming_it(tmp_path):
    p = tmp_path / "summary-like.json"
    p.write_text(json.dumps({"suite": "x", "jobs": []}))
    with pytest.raises(ResultsError, match="summary-like.json: not a results record"):
        results_markdown([p], [], "x")
    p.write_text("{not json")
    with pytest.raises(ResultsError, match="summary-like.json: not valid JSON"):
        results_markdown([p], [], "x")


def test_results_command_writes_one_record_per_suite(tmp_path):
    """`omnibench results RUN --records DIR` writes DIR/SUITE.json, which the command then
    reads in place of the run; two runs of one suite are refused before anything is
    written."""
    import typer
    from typer.testing import CliRunner

    from scenarios.cli_suite import register

    app = typer.Typer()
    register(app)
    run = _summary(tmp_path)
    records, page = tmp_path / "records", tmp_path / "RESULTS.md"
    res = CliRunner().invoke(
        app, ["results", str(run), "--out", str(page), "--records", str(records)]
    )
    assert res.exit_code == 0, res.output
    record = records / "check-x.json"
    assert json.loads(record.read_text())["run_id"] == "check-x-1"
    again = tmp_path / "again.md"
    res = CliRunner().invoke(app, ["results", str(record), "--out", str(again)])
    assert res.exit_code == 0, res.output
    table = [line for line in page.read_text().splitlines() if line.startswith("| merge")]
    assert table and table == [l for l in again.read_text().splitlines() if l.startswith("| merge")]
    twice = tmp_path / "twice.md"
    args = ["results", str(run), str(record), "--out", str(twice), "--records", str(records)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code != 0 and "two runs of one suite" in res.output
    assert not twice.exists()


RECORDS = sorted((Path(__file__).parents[2] / "docs" / "results").glob("*.json"))


@pytest.mark.parametrize("path", RECORDS, ids=[p.stem for p in RECORDS])
def test_kept_records_are_the_shipped_suites_jobs(path):
    """Each record in docs/results is a finished run of a shipped suite as it is now: the
    same jobs (a suite changed since its run needs a new record), from a clean commit."""
    from scenarios.results_doc import load_summary
    from scenarios.suite import load_suite

    record = load_summary(path)
    assert path.name == f"{record['suite']}.json"
    assert not record["dirty"] and len(record["commit"]) == 40
    suite = load_suite(record["suite"])
    assert {j["job_id"] for j in record["jobs"]} == {j.job_id for j in suite.jobs}
    assert all(j["status"] == "ok" and j["metrics"] for j in record["jobs"])
