"""`omnibench results`: docs/RESULTS.md generated from suite runs and benchmark outputs.

Every figure of the page comes from a file a command wrote: a suite run's
``summary.json`` (`omnibench suite`), or its results record (`record_of`, written by
``omnibench results --records DIR``: the summary cut to what the page reads, small enough
to keep in the repository, so that the page can be regenerated with some suites run
again and the others from their records), or the JSON line of an ``omnibench bench ...
--json`` command saved to a file. The page states the command that made it, the
commit and the date, so that no figure is typed by hand.
"""

from __future__ import annotations

import json
import math
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from scenarios.history import git_commit
from scenarios.regression import BaselineError, read_summary
from scenarios.suite import DEFAULT_DETECTOR, ROLE_MEANING
from sim.machine import describe, machines_line

# (flattened metrics.json key, column head, format)
EGO_COLUMNS = (
    ("ego.speed_rmse_pct", "speed RMSE [%]", "{:.2f}"),
    ("ego.prior_speed_rmse_pct", "CAN prior [%]", "{:.2f}"),
    ("ego.yaw_rate_rmse_dps", "yaw rate RMSE [deg/s]", "{:.3f}"),
    ("ego.angle_rmse_deg", "A roll/pitch RMSE [deg]", "{:.3f}"),
)
# the vehicle tracks over the frames where the ego car moves (the surround figures' set,
# docs/SUITES.md), then the per-frame detections' own recall over every frame
_MOVING = "surround.tracks.ego_state.moving."
DETECTION_COLUMNS = (
    (_MOVING + "detection.gt_count", "vehicle-frames, ego moving", "{:.0f}"),
    (_MOVING + "detection.recall", "recall", "{:.2f}"),
    (_MOVING + "detection.precision", "precision", "{:.2f}"),
    (_MOVING + "tracking.mota", "MOTA", "{:.2f}"),
    (_MOVING + "tracking.idf1", "IDF1", "{:.2f}"),
    (_MOVING + "tracking.hota", "HOTA", "{:.2f}"),
    (_MOVING + "localization.median_error_m", "median position error [m]", "{:.2f}"),
    (_MOVING + "localization.centre_median_error_m", "median box-centre error [m]", "{:.2f}"),
    (
        "surround.track_state.ego_state.moving.velocity.median_error_mps",
        "median velocity error [m/s]",
        "{:.2f}",
    ),
    (
        "surround.track_state.ego_state.moving.position_nees.mean",
        "position NEES (2: honest)",
        "{:.1f}",
    ),
    *(
        (_MOVING + f"sizes.{size}.recall", f"recall, {size} (COCO)", "{:.2f}")
        for size in ("small", "medium", "large")
    ),
    (
        "surround.tracks.ego_state.stopped.detection.gt_count",
        "vehicle-frames, ego stopped",
        "{:.0f}",
    ),
    ("surround.tracker.lost_share", "share of the candidates' finds the tracker lost", "{:.2f}"),
    ("detection.recall", "detections' recall, all frames", "{:.2f}"),
    ("surround.segmentation.pixel_recall", "mask pixel recall", "{:.2f}"),
    ("surround.segmentation.pixel_precision", "mask pixel precision", "{:.2f}"),
)


class ResultsError(ValueError):
    """A suite folder or benchmark file that cannot be read; names the path."""


def _fmt(value: Any, spec: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return spec.format(value)


def _metrics(job: dict[str, Any]) -> dict[str, Any]:
    m = dict(job.get("metrics") or {})
    speed = m.get("ego.mean_speed_mps")
    prior = m.get("ego.prior_speed_rmse_mps")
    if speed and prior is not None:  # the prior's RMSE in % of the mean speed, like the estimate's
        m["ego.prior_speed_rmse_pct"] = 100.0 * prior / speed
    return m


# what the page reads of a job's metrics besides its columns (`_metrics`, the headline)
_READ_KEYS = ("frames", "ego.mean_speed_mps", "ego.prior_speed_rmse_mps", "detection.gt_count")
RECORD_FORMAT = 1  # [-] version of a results record (`record_of`)


def load_summary(path: Path) -> dict[str, Any]:
    """A suite run's summary: ``summary.json`` of a run folder
    (`scenarios.regression.read_summary`), or a results record (`record_of`) file; errors
    as a ResultsError naming the path."""
    p = Path(path)
    if p.is_file():
        try:
            record = json.loads(p.read_text())
        except json.JSONDecodeError as e:
            raise ResultsError(f"{p}: not valid JSON: {e}") from None
        if not isinstance(record, dict) or record.get("record_format") != RECORD_FORMAT:
            raise ResultsError(
                f"{p}: not a results record (format {RECORD_FORMAT}; `omnibench results "
                "--records` writes them)"
            )
        return record
    try:
        return read_summary(p)
    except BaselineError as e:
        raise ResultsError(str(e)) from None


def record_of(summary: dict[str, Any]) -> dict[str, Any]:
    """A suite run's summary cut to what the results page reads: the run's provenance and
    each job's description with the metrics of the page's columns. Kept in the repository
    (`omnibench results --records`), it regenerates the run's section without the run's
    folder, with the same figures and provenance."""
    keys = {k for k, _, _ in EGO_COLUMNS + DETECTION_COLUMNS} | set(_READ_KEYS)
    jobs = []
    for j in summary.get("jobs", []):
        job = {k: v for k, v in j.items() if k not in ("metrics", "dir", "scenario_source")}
        job["metrics"] = {k: v for k, v in (j.get("metrics") or {}).items() if k in keys}
        jobs.append(job)
    top = {k: v for k, v in summary.items() if k not in ("jobs", "cache_dir")}
    return {"record_format": RECORD_FORMAT, **top, "jobs": jobs}


def record_name(summary: dict[str, Any]) -> str:
    """File name of a run's record: its suite's name (one record per suite)."""
    suite = str(summary.get("suite") or "suite")
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in suite) + ".json"


def load_bench(path: Path) -> dict[str, Any]:
    """The last JSON line of a file holding an ``omnibench bench ... --json`` output."""
    p = Path(path)
    if not p.is_file():
        raise ResultsError(f"{p}: benchmark file not found")
    for line in reversed(p.read_text().splitlines()):
        if line.strip().startswith("{"):
            try:
                return json.loads(line)
            except json.JSONDecodeError as e:
                raise ResultsError(f"{p}: last JSON line is not valid ({e})") from None
    raise ResultsError(f"{p}: no JSON line (run the bench command with --json)")


def _table(heads: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(heads) + " |", "|" + " --- |" * len(heads)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def suite_section(summary: dict[str, Any]) -> list[str]:
    """Markdown lines of one suite run: its role, provenance and per-job tables."""
    jobs = [j for j in summary.get("jobs", []) if j.get("status") == "ok"]
    failed = [j for j in summary.get("jobs", []) if j.get("status") != "ok"]
    dirty = " (with uncommitted changes)" if summary.get("dirty") else ""
    lines = [
        f"## Suite `{summary.get('suite')}`",
        "",
        f"*{ROLE_MEANING.get(summary.get('role'), 'role not declared')}.* "
        f"{summary.get('description', '')}",
        "",
        f"Run `{summary.get('run_id')}`, commit `{summary.get('commit')}`{dirty}, finished "
        f"{summary.get('finished_at')}: `omnibench suite {summary.get('suite')} --out DIR`.",
        "",
        machines_line(summary.get("machine"), summary.get("render_machines")),
        "",
    ]
    key_heads = ["drive", "camera", "estimator", "seed", "frames"]

    def keys(j: dict[str, Any]) -> list[str]:
        m = j.get("metrics") or {}
        return [
            j.get("scenario", ""),
            j.get("camera", ""),
            j.get("estimator", ""),
            str(j.get("seed", "")),
            _fmt(m.get("frames"), "{:.0f}"),
        ]

    # the ego figures of a job do not depend on its surround detector: one row per estimate
    ego_jobs = [j for j in jobs if j.get("detector", DEFAULT_DETECTOR) == DEFAULT_DETECTOR]
    rows = [keys(j) + [_fmt(_metrics(j).get(k), f) for k, _, f in EGO_COLUMNS] for j in ego_jobs]
    lines += ["Ego-motion:", ""] + _table(key_heads + [h for _, h, _ in EGO_COLUMNS], rows)
    # every job that evaluated vehicles (detection runs on each estimator's compensation)
    det = [j for j in jobs if (j.get("metrics") or {}).get("detection.gt_count")]
    if det:
        # a column that no job of the run has (a figure measured since) is left out
        cols = [c for c in DETECTION_COLUMNS if any(c[0] in _metrics(j) for j in det)]
        rows = [
            keys(j)
            + [j.get("detector", DEFAULT_DETECTOR)]
            + [_fmt(_metrics(j).get(k), f) for k, _, f in cols]
            for j in det
        ]
        heads = key_heads + ["detector"] + [h for _, h, _ in cols]
        lines += [
            "",
            "Surround: the vehicle tracks over the frames where the ego car moves (the "
            "per-frame detections' recall over every frame beside):",
            "",
        ] + _table(heads, rows)
    if failed:
        lines += ["", f"{len(failed)} jobs did not finish:"]
        lines += [f"- {j.get('label')}: {j.get('status')} {j.get('error') or ''}" for j in failed]
    return lines + [""]


def _detector_note(bench: dict[str, Any]) -> str:
    """The detector a detection bench timed, after a comma (", learned"); "" for the default."""
    detector = bench.get("detector", DEFAULT_DETECTOR)
    return "" if detector == DEFAULT_DETECTOR else f", {detector}"


def _repeat_note(bench: dict[str, Any]) -> str:
    """How a bench timed over several passes counts ("each frame's fastest of 3 passes"),
    after a comma; "" for one pass."""
    n = int(bench.get("repeat", 1))
    return f", each frame's fastest of {n} passes" if n > 1 else ""


def bench_section(benches: list[tuple[Path, dict[str, Any]]]) -> list[str]:
    rows, stages = [], []
    for path, b in benches:
        # `omnibench bench render` times several renderers in one run: a row each
        runs = b.get("renderers") or {None: b}
        for name, r in runs.items():
            what = (b.get("bench") or path.stem) + (
                f" ({name}{', shadows' if r.get('shadows') else ''}, {r.get('face_px')}-px faces)"
                if name
                else f" ({b['scenario']}{_detector_note(b)}{_repeat_note(b)})"  # the drive timed
                if b.get("scenario")
                else ""
            )
            if (b.get("machine") or {}).get("cpu"):  # the same bench on two machines: two rows
                what += f" on {b['machine']['cpu']}"
            median = r.get("ms_per_frame")
            p90 = r.get("p90_ms_per_frame", r.get("ms_p90"))
            fps = r.get("frames_per_s") or (1000.0 / median if median else None)
            rows.append(
                [
                    what,
                    _fmt(median, "{:.1f}"),
                    _fmt(p90, "{:.1f}"),
                    _fmt(fps, "{:.2f}"),
                    _fmt(r.get("cpu_ms_per_frame"), "{:.0f}"),
                    str(r.get("frames", "")),
                ]
            )
            if r.get("stages_ms"):
                parts = ", ".join(f"{k} {v:.0f}" for k, v in r["stages_ms"].items())
                stages.append(f"- {what}: {parts} ms (medians by stage)")
            if len(r.get("passes", [])) > 1:  # every pass on its own, as timed
                each = ", ".join(
                    f"{q['ms_per_frame']:.1f} / {q['p90_ms_per_frame']:.1f}" for q in r["passes"]
                )
                stages.append(f"- {what}: each pass's median / p90 {each} ms")
            stages.append(f"- {what}: machine: {describe(b.get('machine'))}")
    heads = [
        "benchmark",
        "median [ms/frame]",
        "p90 [ms/frame]",
        "frames/s",
        "CPU [ms/frame]",
        "frames timed",
    ]
    lines = [
        "## Speed",
        "",
        "One `omnibench bench ... --json` each, on the machine named below.",
        "",
    ]
    lines += _table(heads, rows) + [""]
    return lines + (stages + [""] if stages else [])


def results_markdown(
    run_dirs: list[Path], bench_files: list[Path], command: str, now: datetime | None = None
) -> str:
    """The whole page. Raises ResultsError naming the first unreadable input."""
    return results_page([load_summary(d) for d in run_dirs], bench_files, command, now)


def results_page(
    summaries: list[dict[str, Any]],
    bench_files: list[Path],
    command: str,
    now: datetime | None = None,
) -> str:
    """The whole page from loaded suite summaries (`load_summary`)."""
    benches = [(Path(p), load_bench(p)) for p in bench_files]
    commit, dirty = git_commit()
    when = (now or datetime.now(UTC)).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Results",
        "",
        "Generated, not written by hand: "
        f"`{command}` at commit `{commit}`{' (with uncommitted changes)' if dirty else ''} "
        f"on {when}. Each suite's own run and commit are stated with it. Which suites are "
        "tuning and which are check suites: [SUITES.md](SUITES.md); what each figure means: "
        "[FORMATS.md](FORMATS.md).",
        "",
    ]
    if benches:
        lines += bench_section(benches)
    for s in summaries:
        lines += suite_section(s)
    return "\n".join(lines).rstrip() + "\n"


README_BEGIN = "<!-- headline figures: generated by `omnibench results --readme` -->"
README_END = "<!-- end of headline figures -->"


def _span(values: list[float], spec: str) -> str:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return "–"
    lo, hi = min(vals), max(vals)
    return spec.format(lo) if lo == hi else f"{spec.format(lo)}–{spec.format(hi)}"


def headline_markdown(summaries: list[dict[str, Any]], estimator: str = "direct") -> str:
    """One row per suite run: the range over its ``estimator`` jobs of the main figures."""
    rows = []
    for s in summaries:
        jobs = [
            _metrics(j)
            for j in s.get("jobs", [])
            if j.get("status") == "ok"
            and j.get("estimator") == estimator
            and j.get("detector", DEFAULT_DETECTOR) == DEFAULT_DETECTOR
        ]
        det = [m for m in jobs if m.get("detection.gt_count")]
        rows.append(
            [
                f"`{s.get('suite')}`",
                str(s.get("role") or "–"),
                str(len(jobs)),
                _span([m.get("ego.speed_rmse_pct") for m in jobs], "{:.2f}"),
                _span([m.get("ego.yaw_rate_rmse_dps") for m in jobs], "{:.2f}"),
                _span([m.get("ego.angle_rmse_deg") for m in jobs], "{:.3f}"),
                _span([m.get(_MOVING + "detection.recall") for m in det], "{:.2f}"),
            ]
        )
    heads = [
        "suite",
        "role",
        f"{estimator} runs",
        "speed RMSE [%]",
        "yaw rate RMSE [deg/s]",
        "A RMSE [deg]",
        "track recall, ego moving",
    ]
    return "\n".join(_table(heads, rows))


def replace_readme_block(text: str, block: str, where: str = "README") -> str:
    """``text`` with the part between README_BEGIN and README_END replaced by ``block``."""
    if README_BEGIN not in text or README_END not in text:
        raise ResultsError(
            f"{where}: no headline block (lines {README_BEGIN!r} ... {README_END!r})"
        )
    head, rest = text.split(README_BEGIN, 1)
    _, tail = rest.split(README_END, 1)
    return f"{head}{README_BEGIN}\n{block}\n{README_END}{tail}"


def command_line() -> str:
    return "omnibench " + " ".join(shlex.quote(a) for a in sys.argv[1:])
