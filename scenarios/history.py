"""Results history: every suite run and every job's metrics, in SQLite.

Default file ``renders/history.sqlite`` (``OMNIBENCH_HISTORY`` or ``--history``
choose another). stdlib ``sqlite3`` in WAL mode; each job is recorded in one
transaction, and ``UNIQUE (run_id, job_id)`` keeps one row per job of a run (a
job that failed and is retried later replaces its own row).

Tables::

    runs     run_id, suite, suite_file, out_dir, fingerprint, commit, dirty,
             code_version, n_jobs, started_at, finished_at
    jobs     run_id, job_id, label, scenario, camera, estimator, seed,
             overrides (JSON), frames, commit, recorded_at, wall_s,
             status ('ok' | 'error'), error, traceback
    metrics  run_id, job_id, key (flattened: 'ego.speed_rmse_pct'), value (REAL, NULL = NaN)

Times are ISO 8601 UTC.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

DEFAULT_HISTORY = Path("renders/history.sqlite")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    run_id TEXT PRIMARY KEY,
    suite TEXT NOT NULL,
    suite_file TEXT,
    out_dir TEXT,
    fingerprint TEXT,
    commit_sha TEXT,
    dirty INTEGER,
    code_version TEXT,
    n_jobs INTEGER,
    started_at TEXT,
    finished_at TEXT
);
CREATE TABLE IF NOT EXISTS jobs (
    run_id TEXT NOT NULL REFERENCES runs(run_id),
    job_id TEXT NOT NULL,
    label TEXT,
    scenario TEXT,
    camera TEXT,
    estimator TEXT,
    seed INTEGER,
    overrides TEXT,
    frames INTEGER,
    commit_sha TEXT,
    recorded_at TEXT,
    wall_s REAL,
    status TEXT NOT NULL CHECK (status IN ('ok', 'error')),
    error TEXT,
    traceback TEXT,
    UNIQUE (run_id, job_id)
);
CREATE TABLE IF NOT EXISTS metrics (
    run_id TEXT NOT NULL,
    job_id TEXT NOT NULL,
    key TEXT NOT NULL,
    value REAL,
    PRIMARY KEY (run_id, job_id, key)
);
CREATE INDEX IF NOT EXISTS jobs_by_run ON jobs (run_id);
"""


class HistoryError(ValueError):
    """A run that cannot be found, or an ambiguous run reference."""


def history_path(path: str | os.PathLike | None = None) -> Path:
    """``path``, else $OMNIBENCH_HISTORY, else renders/history.sqlite."""
    if path is not None:
        return Path(path)
    return Path(os.environ.get("OMNIBENCH_HISTORY", DEFAULT_HISTORY))


def now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def git_commit(repo: Path | None = None) -> tuple[str, bool]:
    """(HEAD commit, working tree dirty) of the project's repository; ("unknown", False)."""
    repo = repo or Path(__file__).resolve().parents[1]
    try:
        sha = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if sha.returncode != 0:
            return "unknown", False
        st = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return sha.stdout.strip(), bool(st.stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return "unknown", False


def flatten(metrics: dict[str, Any], prefix: str = "") -> dict[str, float]:
    """Numeric leaves of a metrics dict under dotted keys ('ego.speed_rmse_pct').

    Booleans become 0/1; strings, lists and None are left out.
    """
    out: dict[str, float] = {}
    for k, v in metrics.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        elif isinstance(v, bool):
            out[key] = float(v)
        elif isinstance(v, int | float):
            out[key] = float(v)
    return out


def _db_value(v: float) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


@dataclass
class RunInfo:
    run_id: str
    suite: str
    started_at: str
    finished_at: str | None
    commit: str
    dirty: bool
    n_jobs: int
    ok: int
    failed: int
    out_dir: str | None


class History:
    """The results database; use as a context manager or call `close`."""

    def __init__(self, path: str | os.PathLike | None = None) -> None:
        self.path = history_path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.conn = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        self.conn.row_factory = sqlite3.Row
        self.conn.execute("PRAGMA journal_mode=WAL")
        self.conn.execute("PRAGMA synchronous=NORMAL")
        self.conn.execute("PRAGMA foreign_keys=ON")
        self.conn.executescript(_SCHEMA)

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> History:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        self.conn.execute("BEGIN IMMEDIATE")
        try:
            yield self.conn
        except BaseException:
            self.conn.execute("ROLLBACK")
            raise
        self.conn.execute("COMMIT")

    # -------------------------------------------------------------- writing
    def ensure_run(
        self,
        run_id: str,
        suite: str,
        *,
        suite_file: str | None = None,
        out_dir: str | None = None,
        fingerprint: str | None = None,
        code_version: str | None = None,
        n_jobs: int = 0,
    ) -> None:
        """Create the run's row unless it exists (a resumed run keeps its first row)."""
        commit, dirty = git_commit()
        with self._tx() as c:
            c.execute(
                "INSERT OR IGNORE INTO runs (run_id, suite, suite_file, out_dir, fingerprint, "
                "commit_sha, dirty, code_version, n_jobs, started_at) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    run_id,
                    suite,
                    suite_file,
                    out_dir,
                    fingerprint,
                    commit,
                    int(dirty),
                    code_version,
                    n_jobs,
                    now_iso(),
                ),
            )

    def finish_run(self, run_id: str) -> None:
        with self._tx() as c:
            c.execute("UPDATE runs SET finished_at = ? WHERE run_id = ?", (now_iso(), run_id))

    def record_job(
        self,
        run_id: str,
        job: dict[str, Any],
        *,
        status: str,
        metrics: dict[str, Any] | None = None,
        error: str | None = None,
        traceback: str | None = None,
        wall_s: float | None = None,
        commit: str | None = None,
        replace: bool = False,
    ) -> None:
        """Record one job (its description as `Job.describe`) in one transaction.

        One row per (run, job): a job already recorded as 'ok' in this run is left
        as it is unless ``replace`` (it was run again); an 'error' row is replaced.
        """
        flat = flatten(metrics or {})
        commit = commit or git_commit()[0]
        with self._tx() as c:
            row = c.execute(
                "SELECT status FROM jobs WHERE run_id = ? AND job_id = ?", (run_id, job["job_id"])
            ).fetchone()
            if row is not None and row["status"] == "ok" and not replace:
                return
            c.execute("DELETE FROM jobs WHERE run_id = ? AND job_id = ?", (run_id, job["job_id"]))
            c.execute(
                "DELETE FROM metrics WHERE run_id = ? AND job_id = ?", (run_id, job["job_id"])
            )
            c.execute(
                "INSERT INTO jobs (run_id, job_id, label, scenario, camera, estimator, seed, "
                "overrides, frames, commit_sha, recorded_at, wall_s, status, error, traceback) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    run_id,
                    job["job_id"],
                    job.get("label"),
                    job.get("scenario"),
                    job.get("camera"),
                    job.get("estimator"),
                    job.get("seed"),
                    json.dumps(job.get("overrides", {}), sort_keys=True),
                    job.get("frames"),
                    commit,
                    now_iso(),
                    wall_s,
                    status,
                    error,
                    traceback,
                ),
            )
            c.executemany(
                "INSERT INTO metrics (run_id, job_id, key, value) VALUES (?, ?, ?, ?)",
                [(run_id, job["job_id"], k, _db_value(v)) for k, v in flat.items()],
            )

    # -------------------------------------------------------------- reading
    def job_status(self, run_id: str) -> dict[str, str]:
        """{job_id: status} of the jobs recorded for a run."""
        rows = self.conn.execute("SELECT job_id, status FROM jobs WHERE run_id = ?", (run_id,))
        return {r["job_id"]: r["status"] for r in rows}

    def jobs(self, run_id: str) -> list[dict[str, Any]]:
        """Rows of the run's jobs, each with ``metrics`` (flat, NaN for NULL)."""
        out = []
        for r in self.conn.execute(
            "SELECT * FROM jobs WHERE run_id = ? ORDER BY rowid", (run_id,)
        ).fetchall():
            d = dict(r)
            d["overrides"] = json.loads(d["overrides"] or "{}")
            d["metrics"] = self.metrics(run_id, d["job_id"])
            out.append(d)
        return out

    def metrics(self, run_id: str, job_id: str) -> dict[str, float]:
        rows = self.conn.execute(
            "SELECT key, value FROM metrics WHERE run_id = ? AND job_id = ? ORDER BY key",
            (run_id, job_id),
        )
        return {r["key"]: (math.nan if r["value"] is None else r["value"]) for r in rows}

    def runs(self, suite: str | None = None, limit: int | None = None) -> list[RunInfo]:
        """Runs, newest first, with their ok/failed job counts."""
        q = (
            "SELECT r.*, "
            "(SELECT COUNT(*) FROM jobs j WHERE j.run_id = r.run_id AND j.status = 'ok') AS ok, "
            "(SELECT COUNT(*) FROM jobs j WHERE j.run_id = r.run_id AND j.status = 'error') "
            "AS failed FROM runs r"
        )
        args: list[Any] = []
        if suite:
            q += " WHERE r.suite = ?"
            args.append(suite)
        q += " ORDER BY r.started_at DESC, r.rowid DESC"
        if limit:
            q += " LIMIT ?"
            args.append(limit)
        return [
            RunInfo(
                run_id=r["run_id"],
                suite=r["suite"],
                started_at=r["started_at"],
                finished_at=r["finished_at"],
                commit=r["commit_sha"] or "unknown",
                dirty=bool(r["dirty"]),
                n_jobs=r["n_jobs"] or 0,
                ok=r["ok"],
                failed=r["failed"],
                out_dir=r["out_dir"],
            )
            for r in self.conn.execute(q, args)
        ]

    def resolve_run(self, ref: str) -> str:
        """A run id from an id, a unique id prefix, a suite run folder, or 'latest'."""
        p = Path(ref)
        if (p / "run.json").is_file():
            return json.loads((p / "run.json").read_text())["run_id"]
        if ref == "latest":
            runs = self.runs(limit=1)
            if not runs:
                raise HistoryError(f"{self.path}: no run recorded yet")
            return runs[0].run_id
        rows = [
            r["run_id"]
            for r in self.conn.execute(
                "SELECT run_id FROM runs WHERE run_id = ? OR run_id LIKE ? ESCAPE '\\'",
                (ref, ref.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"),
            )
        ]
        if ref in rows:
            return ref
        if len(rows) == 1:
            return rows[0]
        if not rows:
            raise HistoryError(f"{self.path}: no run {ref!r} (see `omnibench history`)")
        raise HistoryError(f"{self.path}: {ref!r} is ambiguous: {', '.join(sorted(rows))}")
