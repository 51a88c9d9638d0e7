"""``omnibench suite``, ``history``, ``compare`` and ``baseline``: added to the main app
by `register` (scenarios.cli calls it when this module exists).

Exit codes: 0 fine; 1 a job errored or missed its thresholds (suite), or a
regression (compare, baseline check); 2 bad input; 130 interrupted.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import typer
from rich.console import Console

console = Console(stderr=True, soft_wrap=True)

_HISTORY_HELP = "results database (default $OMNIBENCH_HISTORY or renders/history.sqlite)"


def _fail(msg: str) -> None:
    console.print(f"[red]error:[/red] {msg}", highlight=False)
    raise typer.Exit(2)


def suite(
    suite_file: str = typer.Argument(..., help="suite YAML file, or a shipped suite's name"),
    out_dir: Path = typer.Option(..., "--out", help="suite folder (a rerun resumes it)"),
    workers: int | None = typer.Option(
        None, "--workers", min=1, help="parallel jobs (default: CPUs)"
    ),
    executor: str = typer.Option("local", "--executor", help="local | ray"),
    address: str | None = typer.Option(None, "--address", help="Ray cluster address (ray only)"),
    history: Path | None = typer.Option(None, "--history", help=_HISTORY_HELP),
    cache: Path | None = typer.Option(None, "--cache", help="render cache (default renders/cache)"),
    frames: int | None = typer.Option(
        None, "--frames", min=2, help="replace the suite's frame limit"
    ),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="progress bar"),
) -> None:
    """Run every scenario x camera x estimator x seed x override job of a suite.

    Writes OUT/report.html, summary.json, junit.xml and one folder per job; each
    job is recorded in the history. Exit 1 if a job errored or missed a threshold.
    """
    from scenarios.executors import ExecutorError, check_executor
    from scenarios.suite import SuiteError, load_suite
    from scenarios.suite_runner import run_suite

    try:
        check_executor(executor, address)
    except ExecutorError as e:
        _fail(f"--executor: {e}")
    try:
        s = load_suite(suite_file, frames=frames)
        console.print(
            f"suite {s.name}: {len(s.jobs)} jobs, {len({j.render_key for j in s.jobs})} drives"
        )
        res = run_suite(
            s,
            out_dir,
            workers=workers,
            executor=executor,
            address=address,
            history=history,
            cache_dir=cache,
            progress=progress,
            log=None if progress else lambda m: console.print(m, highlight=False),
        )
    except (SuiteError, ExecutorError) as e:
        _fail(str(e))
    except KeyboardInterrupt:
        console.print(
            f"interrupted: finished jobs are kept and recorded; run the same command again "
            f"to resume {out_dir}",
            highlight=False,
        )
        raise typer.Exit(130) from None
    n_err = sum(o.status == "error" for o in res.outcomes)
    n_fail = sum(o.status == "ok" and not o.passed for o in res.outcomes)
    print(results_table(res.outcomes))
    console.print(
        f"run {res.run_id}: {len(res.outcomes)} jobs ({res.ran} run now, {res.skipped} done "
        f"before, {res.recorded_from_disk} recorded from disk, {res.renders} renders) in "
        f"{res.wall_s:.0f} s; {n_err} errors, {n_fail} missed thresholds -> {out_dir}/report.html",
        highlight=False,
    )
    for o in res.outcomes:
        if o.status == "error":
            console.print(f"  [red]error[/red] {o.job.label}: {o.error}", highlight=False)
        elif not o.passed:
            bad = ", ".join(
                f"{c['metric']}={c['value'] if c['value'] is not None else 'nan'}"
                for c in o.checks
                if not c["ok"]
            )
            console.print(f"  [yellow]threshold[/yellow] {o.job.label}: {bad}", highlight=False)
    if not res.ok:
        raise typer.Exit(1)


def history_cmd(
    history: Path | None = typer.Option(None, "--history", help=_HISTORY_HELP),
    suite_name: str | None = typer.Option(None, "--suite", help="only runs of this suite"),
    limit: int = typer.Option(20, "--limit", min=1, help="newest N runs"),
    as_json: bool = typer.Option(False, "--json", help="JSON lines instead of a table"),
) -> None:
    """List suite runs: run id, suite, time, commit, jobs ok/failed."""
    from scenarios.history import History, history_path

    path = history_path(history)
    if not path.exists():
        _fail(f"no history at {path} (run `omnibench suite` first, or give --history)")
    with History(path) as h:
        runs = h.runs(suite=suite_name, limit=limit)
    if as_json:
        for r in runs:
            print(json.dumps(r.__dict__))
        return
    rows = [
        [
            r.run_id,
            r.suite,
            r.started_at,
            r.commit[:12] + ("+dirty" if r.dirty else ""),
            str(r.ok),
            str(r.failed),
            str(r.n_jobs),
            "yes" if r.finished_at else "no",
        ]
        for r in runs
    ]
    heads = ["run id", "suite", "started (UTC)", "commit", "ok", "failed", "jobs", "finished"]
    print(_plain_table(heads, rows))


def results_table(outcomes: list) -> str:
    """One row per job (`scenarios.suite_report.Outcome`): its label, status and the
    report's metrics (`TABLE_METRICS`; nan: not measured, e.g. no vehicle in range)."""
    from scenarios.suite_report import TABLE_METRICS

    rows = []
    for o in outcomes:
        status = o.status if o.status != "ok" else ("ok" if o.passed else "threshold")
        cells = []
        for key, _ in TABLE_METRICS:
            v = o.metrics.get(key) if o.metrics else None
            cells.append("-" if v is None else ("nan" if v != v else f"{v:.4g}"))
        rows.append([o.job.label, status, *cells])
    return _plain_table(["job", "status", *(h for _, h in TABLE_METRICS)], rows)


def _plain_table(heads: list[str], rows: list[list[str]]) -> str:
    """Aligned columns, whatever the terminal width (no wrapping, easy to grep)."""
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(heads)
    ]
    lines = ["  ".join(c.ljust(w) for c, w in zip(heads, widths, strict=True)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    return "\n".join(lines)


def _tolerance(rel: float, abs_: float):
    from scenarios.regression import Tolerance

    try:
        return Tolerance(rel, abs_)
    except ValueError as e:
        _fail(str(e))


def _print_comparison(cmp, show_all: bool, what: str) -> None:
    rows = []
    for d in cmp.deltas:
        changed = not (d.base == d.new or (math.isnan(d.base) and math.isnan(d.new)))
        if not (show_all or d.regression or changed):
            continue
        flag = "REGRESSION" if d.regression else ("better" if d.improved else "")
        delta = d.delta
        pct = f" ({100 * delta / abs(d.base):+.1f} %)" if d.base and math.isfinite(delta) else ""
        note = f" {d.note}" if d.note else ""
        rows.append(
            [d.label, d.metric, f"{d.base:.4g}", f"{d.new:.4g}", f"{delta:+.4g}{pct}", flag + note]
        )
    print(what)
    if rows:
        print(_plain_table(["job", "metric", "base", "new", "delta", ""], rows))
    for jid, label, err in cmp.failed:
        print(f"REGRESSION {label} ({jid}): failed: {err}")
    for jid, label in cmp.only_base:
        print(f"only in the base: {label} ({jid})")
    for jid, label in cmp.only_new:
        print(f"new (no base): {label} ({jid})")
    print(f"tolerance: {cmp.tolerance.describe()}")
    n = len(cmp.regressions) + len(cmp.failed)
    if n:
        print(f"{n} regression(s):")
        for d in cmp.regressions:
            print(f"  {d.describe()}")
    else:
        print(f"no regression ({len(cmp.deltas)} metrics compared)")


def compare(
    run_a: str = typer.Argument(
        ..., help="base run: id, unique id prefix, suite folder or 'latest'"
    ),
    run_b: str = typer.Argument(
        ..., help="new run: id, unique id prefix, suite folder or 'latest'"
    ),
    history: Path | None = typer.Option(None, "--history", help=_HISTORY_HELP),
    tolerance: float = typer.Option(0.05, "--tolerance", help="relative tolerance [-]"),
    abs_tolerance: float = typer.Option(
        0.005, "--abs-tolerance", help="absolute tolerance floor of metrics without their own"
    ),
    show_all: bool = typer.Option(False, "--all", help="also list unchanged metrics"),
) -> None:
    """Per-metric deltas of every job of two runs; exit 1 on any regression."""
    from scenarios.history import History, HistoryError, history_path
    from scenarios.regression import compare_jobs

    path = history_path(history)
    if not path.exists():
        _fail(f"no history at {path}")
    tol = _tolerance(tolerance, abs_tolerance)
    with History(path) as h:
        try:
            a, b = h.resolve_run(run_a), h.resolve_run(run_b)
        except HistoryError as e:
            _fail(str(e))
        ja = {r["job_id"]: r for r in h.jobs(a)}
        jb = {r["job_id"]: r for r in h.jobs(b)}
    if not set(ja) & set(jb):
        console.print(f"[yellow]warning:[/yellow] runs {a} and {b} share no job", highlight=False)
    cmp = compare_jobs(ja, jb, tol)
    _print_comparison(cmp, show_all, f"{a} -> {b}")
    if not cmp.ok:
        raise typer.Exit(1)


baseline_app = typer.Typer(
    no_args_is_help=True, help="Regression baselines (scenarios/baselines/)."
)


@baseline_app.command("update")
def baseline_update(
    run_dir: Path = typer.Argument(..., help="a finished suite folder (with summary.json)"),
    baselines_dir: Path | None = typer.Option(
        None, "--baselines-dir", help="default scenarios/baselines"
    ),
) -> None:
    """Write scenarios/baselines/<suite>.json from a suite run (prints what changed)."""
    from scenarios.regression import BaselineError, update_baseline

    try:
        path, changes, data = update_baseline(run_dir, baselines_dir)
    except BaselineError as e:
        _fail(str(e))
    for line in changes:
        print(f"  {line}")
    print(
        f"wrote {path}: {len(data['jobs'])} jobs, {len(changes)} change(s)"
        + ("" if changes else " (no change)")
    )


@baseline_app.command("check")
def baseline_check(
    run_dir: Path = typer.Argument(..., help="a finished suite folder (with summary.json)"),
    tolerance: float = typer.Option(0.05, "--tolerance", help="relative tolerance [-]"),
    abs_tolerance: float = typer.Option(
        0.005, "--abs-tolerance", help="absolute tolerance floor of metrics without their own"
    ),
    baselines_dir: Path | None = typer.Option(
        None, "--baselines-dir", help="default scenarios/baselines"
    ),
    show_all: bool = typer.Option(False, "--all", help="also list unchanged metrics"),
) -> None:
    """Exit 1 naming each metric (recall, precision, MOTA, speed, yaw-rate and A RMSEs) worse
    than the baseline."""
    from scenarios.regression import BaselineError, check_baseline, render_note

    tol = _tolerance(tolerance, abs_tolerance)
    try:
        cmp = check_baseline(run_dir, tol, baselines_dir)
        note = render_note(run_dir, baselines_dir)
    except BaselineError as e:
        _fail(str(e))
    _print_comparison(cmp, show_all, f"{run_dir} against its baseline")
    if note:
        print(note)
    if not cmp.ok:
        raise typer.Exit(1)


def results(
    run_dirs: list[Path] = typer.Argument(
        ..., help="finished `omnibench suite` folders, or their records (--records)"
    ),
    out: Path = typer.Option(Path("docs/RESULTS.md"), "--out", help="Markdown page to write"),
    bench: list[Path] = typer.Option(
        [], "--bench", help="file holding an `omnibench bench ... --json` output (repeatable)"
    ),
    readme: Path | None = typer.Option(
        None, "--readme", help="also rewrite this README's headline-figures block"
    ),
    records: Path | None = typer.Option(
        None,
        "--records",
        help="also write each suite run's record (SUITE.json) here, e.g. docs/results",
    ),
) -> None:
    """Write the results page (docs/RESULTS.md) from suite runs and benchmark outputs."""
    from estimator.fileio import write_json, write_text
    from scenarios.results_doc import (
        ResultsError,
        command_line,
        headline_markdown,
        load_summary,
        record_name,
        record_of,
        replace_readme_block,
        results_page,
    )

    try:
        summaries = [load_summary(d) for d in run_dirs]
        text = results_page(summaries, bench, command_line())
        if readme is not None:
            block = headline_markdown(summaries)
            new_readme = replace_readme_block(readme.read_text(), block, str(readme))
        names = [record_name(s) for s in summaries]
        if records is not None and len(set(names)) < len(names):
            raise ResultsError(f"--records: two runs of one suite ({', '.join(sorted(names))})")
    except (ResultsError, FileNotFoundError) as e:
        _fail(str(e))
    write_text(out, text)
    if readme is not None:
        write_text(readme, new_readme)
    if records is not None:
        for s, name in zip(summaries, names, strict=True):
            write_json(records / name, record_of(s))
    console.print(f"wrote {out} ({len(run_dirs)} suite runs, {len(bench)} benchmarks)")


def register(app: typer.Typer) -> None:
    """Add the suite, history, compare and baseline commands to ``app``."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    app.command("suite")(suite)
    app.command("history")(history_cmd)
    app.command("compare")(compare)
    app.command("results")(results)
    app.add_typer(baseline_app, name="baseline")
