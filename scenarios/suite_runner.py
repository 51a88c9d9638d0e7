"""Run a suite: render each distinct drive once, run every job, record, report.

Layout of the suite folder ``out/``::

    run.json            run id, suite, fingerprint (the job ids): a rerun resumes it
    suite.yaml          the suite file as read
    jobs/<dir>/         one `scenarios.runner.run_scenario` output folder per job
                        (+ trajectory.tum, groundtruth.tum, recall_bins.json, error.txt)
    plots/  report.html summary.json junit.xml    (`scenarios.suite_report`)

Renders live in the cache (default ``renders/cache``), one folder per render key
(`scenarios.suite.render_key_for`): jobs that differ only in the estimator share
it, and so do later suites. Each render runs once, before the jobs that need it,
under a file lock (another suite may be rendering the same key).

Resuming: a job is finished when its ``metrics.json`` exists and it is recorded
in the history. A job whose metrics.json exists but is not recorded (the suite
was killed in between) is recorded from that file; jobs that errored are tried
again. Every file is written atomically, so an interrupt loses no finished job.
"""

from __future__ import annotations

import fcntl
import json
import secrets
import time
import traceback as tb
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from estimator.fileio import write_json, write_text
from scenarios.executors import available_cpus, check_executor, make_executor
from scenarios.history import History, git_commit, history_path, now_iso
from scenarios.suite import Job, Suite, SuiteError, code_version, suite_fingerprint
from sim.machine import machine_info, machine_key

DEFAULT_CACHE = Path("renders/cache")


# ------------------------------------------------------------------ worker tasks
@contextmanager
def file_lock(path: Path) -> Iterator[None]:
    """An exclusive ``flock`` on ``path`` (released when the holder exits or dies)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _manifest(drive_dir: Path) -> dict[str, Any]:
    """A drive's manifest.json ({} where it is missing or unreadable: not finished)."""
    try:
        return json.loads((Path(drive_dir) / "manifest.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def drive_complete(drive_dir: Path, frames: int) -> bool:
    m = _manifest(drive_dir)
    return bool(m.get("complete")) and m.get("frames") == frames


def _error_record(kind: str, key: str, t0: float) -> dict[str, Any]:
    import sys

    e = sys.exc_info()[1]
    return {
        "kind": kind,
        "key": key,
        "status": "error",
        "error": f"{type(e).__name__}: {e}",
        "traceback": tb.format_exc(),
        "wall_s": time.perf_counter() - t0,
    }


def render_task(task: dict[str, Any]) -> dict[str, Any]:
    """Render one drive into the cache (a worker task; never raises)."""
    t0 = time.perf_counter()
    try:
        from scenarios.config import scenario_from_dict
        from sim.drive import render_drive

        drive = Path(task["drive_dir"])
        with file_lock(drive.with_name(drive.name + ".lock")):
            if not drive_complete(drive, task["frames"]):
                sc = scenario_from_dict(task["scenario"])
                render_drive(sc, drive, progress=False, max_frames=task["frames"])
        return {
            "kind": "render",
            "key": task["key"],
            "status": "ok",
            "wall_s": time.perf_counter() - t0,
        }
    except Exception:
        return _error_record("render", task["key"], t0)


def job_task(task: dict[str, Any]) -> dict[str, Any]:
    """Run one job into its folder (a worker task; never raises)."""
    t0 = time.perf_counter()
    try:
        from scenarios.config import scenario_from_dict
        from scenarios.runner import run_scenario
        from scenarios.suite_report import write_job_extras

        out = Path(task["out_dir"])
        out.mkdir(parents=True, exist_ok=True)
        with file_lock(out / ".lock"):
            mpath = out / "metrics.json"
            if mpath.exists():  # finished by an earlier process
                metrics = json.loads(mpath.read_text())
            else:
                (out / "error.txt").unlink(missing_ok=True)
                metrics = run_scenario(
                    scenario_from_dict(task["scenario"]),
                    out,
                    estimator=task["estimator"],
                    detector=task["detector"],
                    drive_dir=Path(task["drive_dir"]),
                    progress=False,
                    max_frames=task["frames"],
                    video=task["video"],
                )
            # which render the job used (the render key follows the code version)
            write_json(out / "job.json", {**task["describe"], "drive_dir": task["drive_dir"]})
            extras_error = None
            try:
                write_job_extras(out, Path(task["drive_dir"]))
            except Exception as e:  # the job's metrics stand; the report notes the gap
                extras_error = f"{type(e).__name__}: {e}"
        return {
            "kind": "job",
            "key": task["job_id"],
            "status": "ok",
            "metrics": metrics,
            "extras_error": extras_error,
            "wall_s": time.perf_counter() - t0,
        }
    except Exception:
        return _error_record("job", task["job_id"], t0)


# ------------------------------------------------------------------ the run
@dataclass
class SuiteRun:
    run_id: str
    out_dir: Path
    outcomes: list = field(default_factory=list)  # suite_report.Outcome
    ran: int = 0  # jobs run by this call
    recorded_from_disk: int = 0  # finished earlier, recorded now
    skipped: int = 0  # finished and recorded before
    renders: int = 0  # drives rendered by this call
    wall_s: float = 0.0

    @property
    def ok(self) -> bool:
        return all(o.passed for o in self.outcomes)


def _new_run_id(suite: Suite) -> str:
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    return f"{suite.name}-{stamp}-{secrets.token_hex(2)}"


def open_run(suite: Suite, out_dir: Path) -> dict[str, Any]:
    """run.json of ``out_dir``: created, or read back when it holds the same suite."""
    p = out_dir / "run.json"
    fp = suite_fingerprint(suite)
    if p.exists():
        run = json.loads(p.read_text())
        if run.get("fingerprint") != fp:
            raise SuiteError(
                f"{out_dir} holds run {run.get('run_id')} of suite {run.get('suite')!r} with "
                "other jobs (scenarios, cameras, overrides or frames differ): use another --out"
            )
        return run
    commit, dirty = git_commit()
    run = {
        "run_id": _new_run_id(suite),
        "suite": suite.name,
        "suite_file": str(suite.path) if suite.path else None,
        "fingerprint": fp,
        "code_version": code_version(),
        "commit": commit,
        "dirty": dirty,
        "started_at": now_iso(),
        "n_jobs": len(suite.jobs),
        "machine": machine_info(),  # what runs the jobs (`sim.machine`)
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(p, run)
    return run


def _job_task(job: Job, out_dir: Path, cache_dir: Path) -> dict[str, Any]:
    return {
        "job_id": job.job_id,
        "scenario": job.scenario.to_dict(),
        "estimator": job.estimator,
        "detector": job.detector,
        "frames": job.frames,
        "video": job.video,
        "out_dir": str(out_dir / job.describe()["dir"]),
        "drive_dir": str(cache_dir / job.render_key),
        "describe": job.describe(),
    }


def job_drive_dir(job: Job, out_dir: Path, cache_dir: Path) -> Path:
    """The render a finished job used (its job.json), else the one it would use now."""
    p = out_dir / job.describe()["dir"] / "job.json"
    try:
        return Path(json.loads(p.read_text())["drive_dir"])
    except (OSError, ValueError, KeyError):
        return cache_dir / job.render_key


class _Progress:
    """A rich progress bar over renders and jobs, or nothing."""

    def __init__(self, enabled: bool, n_renders: int, n_jobs: int, label: str) -> None:
        self.bar = None
        if not enabled:
            return
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.bar = Progress(
            "[progress.description]{task.description}",
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=Console(stderr=True),
        )
        self.bar.start()
        self.renders = self.bar.add_task(f"{label}: renders", total=n_renders)
        self.jobs = self.bar.add_task(f"{label}: jobs", total=n_jobs)

    def log(self, msg: str) -> None:
        if self.bar is not None:
            self.bar.console.print(msg, highlight=False)

    def advance(self, which: str) -> None:
        if self.bar is not None:
            self.bar.advance(self.renders if which == "render" else self.jobs)

    def stop(self) -> None:
        if self.bar is not None:
            self.bar.stop()


def run_suite(
    suite: Suite,
    out_dir: Path,
    *,
    workers: int | None = None,
    executor: str = "local",
    address: str | None = None,
    history: str | Path | None = None,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    report: bool = True,
    log: Callable[[str], None] | None = None,
) -> SuiteRun:
    """Run (or resume) every job of ``suite`` into ``out_dir``; see the module docstring."""
    from scenarios.suite_report import collect_outcomes

    check_executor(executor, address)  # before anything is written
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    cache = Path(cache_dir) if cache_dir is not None else DEFAULT_CACHE
    cache = cache.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    run = open_run(suite, out_dir)
    run_id = run["run_id"]
    if suite.path is not None and suite.path.exists():
        write_text(out_dir / "suite.yaml", suite.path.read_text())
    result = SuiteRun(run_id, out_dir)
    workers = workers or available_cpus()
    with History(history_path(history)) as hist:
        hist.ensure_run(
            run_id,
            suite.name,
            suite_file=run.get("suite_file"),
            out_dir=str(out_dir.resolve()),
            fingerprint=run["fingerprint"],
            code_version=run.get("code_version"),
            n_jobs=len(suite.jobs),
        )
        status = hist.job_status(run_id)
        pending: list[Job] = []
        for job in suite.jobs:
            jdir = out_dir / job.describe()["dir"]
            done = (jdir / "metrics.json").exists()
            if done and status.get(job.job_id) == "ok":
                result.skipped += 1
            elif done:  # finished, not recorded: record it now (no redo)
                metrics = json.loads((jdir / "metrics.json").read_text())
                hist.record_job(run_id, job.describe(), status="ok", metrics=metrics)
                result.recorded_from_disk += 1
            else:
                pending.append(job)
        if pending:
            result.renders, result.ran = _execute(
                suite.name,
                pending,
                out_dir,
                cache,
                hist,
                run_id,
                workers,
                executor,
                address,
                progress,
                log,
            )
        rows = {r["job_id"]: r for r in hist.jobs(run_id)}
        result.outcomes = collect_outcomes(suite, rows)
        if report:
            finished = _finish(suite, out_dir, cache, run, result.outcomes)
            run["finished_at"] = finished
        if all(o.status != "pending" for o in result.outcomes):
            hist.finish_run(run_id)
    result.wall_s = time.perf_counter() - t_start
    return result


def _execute(
    suite_name: str,
    pending: list[Job],
    out_dir: Path,
    cache: Path,
    hist: History,
    run_id: str,
    workers: int,
    executor_name: str,
    address: str | None,
    progress: bool,
    log: Callable[[str], None] | None,
) -> tuple[int, int]:
    """Render what the pending jobs need, then run them; returns (renders, jobs) run."""
    by_key: dict[str, list[Job]] = {}
    for job in pending:
        by_key.setdefault(job.render_key, []).append(job)
    to_render = [k for k, js in by_key.items() if not drive_complete(cache / k, js[0].frames)]
    bar = _Progress(progress, len(to_render), len(pending), suite_name)
    say = log or bar.log
    ex = make_executor(executor_name, workers, address)
    handles: dict[Any, tuple[str, Any]] = {}
    jobs_by_id = {j.job_id: j for j in pending}
    commit = git_commit()[0]
    n_rendered = n_run = 0
    try:
        for key in to_render:  # first: they unlock the jobs
            job = by_key[key][0]
            task = {
                "key": key,
                "scenario": job.scenario.to_dict(),
                "frames": job.frames,
                "drive_dir": str(cache / key),
            }
            handles[ex.submit(render_task, task)] = ("render", key)
        for key, js in by_key.items():
            if key not in to_render:
                for job in js:
                    handles[ex.submit(job_task, _job_task(job, out_dir, cache))] = (
                        "job",
                        job.job_id,
                    )
        while handles:
            for h in ex.wait(handles):
                kind, key = handles.pop(h)
                try:
                    res = ex.result(h)
                except Exception as e:  # the worker process itself died
                    res = {
                        "kind": kind,
                        "key": key,
                        "status": "error",
                        "error": f"worker died: {type(e).__name__}: {e}",
                        "traceback": tb.format_exc(),
                        "wall_s": None,
                    }
                if kind == "render":
                    bar.advance("render")
                    n_rendered += res["status"] == "ok"
                    if res["status"] == "ok":
                        say(f"rendered {by_key[key][0].scenario.name} ({res['wall_s']:.0f} s)")
                        for job in by_key[key]:
                            t = _job_task(job, out_dir, cache)
                            handles[ex.submit(job_task, t)] = ("job", job.job_id)
                    else:
                        name = by_key[key][0].scenario.name
                        say(f"[red]render failed[/red] {name}: {res['error']}")
                        for job in by_key[key]:
                            failed = {**res, "error": f"render: {res['error']}"}
                            _record(hist, run_id, job, out_dir, commit, failed)
                            n_run += 1
                            bar.advance("job")
                    continue
                job = jobs_by_id[key]
                _record(hist, run_id, job, out_dir, commit, res)
                n_run += 1
                bar.advance("job")
                if res["status"] == "ok":
                    say(f"[green]ok[/green] {job.label} ({res['wall_s']:.0f} s)")
                else:
                    say(f"[red]error[/red] {job.label}: {res['error']}")
    except BaseException:
        ex.shutdown(kill=True)
        bar.stop()
        raise
    ex.shutdown()
    bar.stop()
    return n_rendered, n_run


def _record(hist: History, run_id: str, job: Job, out_dir: Path, commit: str, res: dict) -> None:
    jdir = out_dir / job.describe()["dir"]
    if res["status"] != "ok":
        write_text(jdir / "error.txt", f"{res['error']}\n\n{res.get('traceback') or ''}")
    hist.record_job(
        run_id,
        job.describe(),
        status=res["status"],
        metrics=res.get("metrics"),
        error=res.get("error"),
        traceback=res.get("traceback"),
        wall_s=res.get("wall_s"),
        commit=commit,
        replace=True,
    )


def render_machines(drives: list[Path]) -> list[dict[str, Any]]:
    """The distinct machines that rendered these drives (their manifests' ``machine``,
    `sim.machine`), in the order first met; drives that record none are left out."""
    seen: dict[str, dict[str, Any]] = {}
    for d in drives:
        m = _manifest(d).get("machine")
        if m:
            seen.setdefault(machine_key(m), m)
    return list(seen.values())


def _finish(suite: Suite, out_dir: Path, cache: Path, run: dict, outcomes: list) -> str:
    """Fill missing per-job extras, then summary.json, junit.xml and report.html."""
    from scenarios.suite_report import write_job_extras, write_junit, write_report, write_summary

    def drive_of(job: Job) -> Path:
        return job_drive_dir(job, out_dir, cache)

    for o in outcomes:
        jdir = out_dir / o.job.describe()["dir"]
        if o.status == "ok" and (jdir / "metrics.json").exists():
            try:
                write_job_extras(jdir, drive_of(o.job))
            except Exception:  # a missing extra only thins the report
                pass
    finished = now_iso()
    info = {
        **run,
        "finished_at": finished,
        "cache_dir": str(cache),
        "render_machines": render_machines([drive_of(o.job) for o in outcomes]),
    }
    write_summary(out_dir, suite, info, outcomes)
    write_junit(out_dir, suite, outcomes, finished)
    write_report(out_dir, suite, info, outcomes, drive_of)
    return finished
