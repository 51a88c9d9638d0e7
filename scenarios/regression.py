"""Direction-aware comparison of job metrics: deltas, regressions, baselines.

Each compared metric has a direction: +1 when higher is better (recall,
precision, MOTA, IDF1, HOTA), -1 when lower is better (RMSEs, localisation
errors, id switches, the compensation residual ratio). A metric is a
*regression* when it moved the bad way by more than the tolerance::

    worse = -direction * (new - base)
    regression  <=>  worse > max(rel_tol * |base|, abs_tol(metric))

``abs_tol(metric)`` is the metric's own absolute floor (`ABS_TOLERANCES`, in its unit)
where it has one, else the general floor.

A finite value that became NaN is a regression; NaN on both sides is equal; a
job that errored where the baseline has metrics is a regression of every metric.

Baselines: ``scenarios/baselines/<suite>.json`` holds, per job id, the job's
label and flat metrics; `update_baseline` writes one from a suite run's
summary.json (on purpose: it reports what changed), `check_baseline` compares a
run against it on `BASELINE_METRICS` (recall, precision, MOTA, speed, yaw-rate and A
RMSEs).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from estimator.fileio import write_json
from scenarios.history import now_iso

BASELINES_DIR = Path(__file__).parent / "baselines"

# +1: higher is better; -1: lower is better.
DIRECTIONS: dict[str, int] = {
    "detection.recall": +1,
    "detection.precision": +1,
    "tracking.mota": +1,
    "tracking.idf1": +1,
    "tracking.hota": +1,
    "tracking.hota_box": +1,
    "ego.speed_rmse_mps": -1,
    "ego.speed_rmse_pct": -1,
    "ego.yaw_rate_rmse_dps": -1,
    "ego.yaw_rate_rmse_exposure_dps": -1,
    "ego.angle_rmse_deg": -1,
    "ego.roll_rmse_deg": -1,
    "ego.pitch_rmse_deg": -1,
    "ego.angle_yaw_rmse_deg": -1,
    "ego.frames_nonfinite": -1,
    "localization.median_error_m": -1,
    "localization.p90_error_m": -1,
    "tracking.id_switches": -1,
    "compensation.ratio": -1,
}

# what `omnibench baseline check` guards by default
BASELINE_METRICS = (
    "detection.recall",
    "detection.precision",
    "tracking.mota",
    "ego.speed_rmse_mps",
    "ego.yaw_rate_rmse_dps",
    "ego.angle_rmse_deg",
)

# absolute floors of metrics whose unit the general floor (`Tolerance.abs_`) does not suit
ABS_TOLERANCES: dict[str, float] = {
    "ego.yaw_rate_rmse_dps": 0.05,  # [deg/s] >= 0; ~7 % of the direct estimator's 0.6-0.9
    "ego.angle_rmse_deg": 0.01,  # [deg] >= 0; ~5 % of the direct estimator's A RMSE 0.16-0.25
    "ego.frames_nonfinite": 0.5,  # [frames] >= 0; one more non-finite estimate regresses
}


@dataclass(frozen=True)
class Tolerance:
    """A metric regresses when worse by more than max(rel * |base|, its absolute floor):
    ``per_metric[metric]`` where it has one, else ``abs_``."""

    rel: float = 0.05  # [-] >= 0, fraction of the baseline value
    abs_: float = 0.005  # [metric units] >= 0, floor for values near 0 (no own floor)
    per_metric: dict[str, float] = field(default_factory=lambda: dict(ABS_TOLERANCES), hash=False)

    def __post_init__(self) -> None:
        if not (self.rel >= 0 and self.abs_ >= 0):
            raise ValueError(f"tolerances must be >= 0, got rel={self.rel}, abs={self.abs_}")
        bad = {k: v for k, v in self.per_metric.items() if not v >= 0}
        if bad:
            raise ValueError(f"absolute tolerances must be >= 0, got {bad}")

    def abs_for(self, metric: str | None) -> float:
        """The absolute floor of ``metric`` [its unit]."""
        return self.per_metric.get(metric, self.abs_) if metric else self.abs_

    def allowed(self, base: float, metric: str | None = None) -> float:
        return max(self.rel * abs(base), self.abs_for(metric))

    def describe(self) -> str:
        own = ", ".join(f"{k} {v:g}" for k, v in self.per_metric.items())
        return (
            f"a metric regresses when worse by more than {100 * self.rel:g} % of the "
            f"baseline value and more than {self.abs_:g} (absolute"
            + (f"; own floors: {own})" if own else ")")
        )


@dataclass(frozen=True)
class Delta:
    job_id: str
    label: str
    metric: str
    base: float
    new: float
    direction: int
    regression: bool
    note: str = ""

    @property
    def delta(self) -> float:
        return self.new - self.base

    @property
    def improved(self) -> bool:
        if self.regression:
            return False
        if math.isnan(self.base) and not math.isnan(self.new):
            return True
        return math.isfinite(self.delta) and self.direction * self.delta > 0

    def describe(self) -> str:
        d = self.delta
        pct = f", {100 * d / abs(self.base):+.1f} %" if self.base and math.isfinite(d) else ""
        return (
            f"{self.label}: {self.metric} {self.base:.4g} -> {self.new:.4g} "
            f"(delta {d:+.4g}{pct}){' ' + self.note if self.note else ''}"
        )


def is_regression(metric: str, base: float, new: float, tol: Tolerance) -> tuple[bool, str]:
    """(regressed, note) of one metric; metrics without a direction never regress."""
    direction = DIRECTIONS.get(metric, 0)
    if direction == 0:
        return False, ""
    base_nan, new_nan = _isnan(base), _isnan(new)
    if base_nan and new_nan:
        return False, ""
    if new_nan:
        return True, "became NaN"
    if base_nan:
        return False, "was NaN"
    worse = -direction * (new - base)
    return worse > tol.allowed(base, metric), ""


def _isnan(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _num(v: Any) -> float:
    return math.nan if v is None else float(v)


@dataclass
class Comparison:
    """Deltas of the jobs present in both sides, plus the jobs on one side only."""

    deltas: list[Delta]
    failed: list[tuple[str, str, str]]  # (job_id, label, error) ok in base, error in new
    only_base: list[tuple[str, str]]  # (job_id, label)
    only_new: list[tuple[str, str]]
    tolerance: Tolerance

    @property
    def regressions(self) -> list[Delta]:
        return [d for d in self.deltas if d.regression]

    @property
    def ok(self) -> bool:
        return not self.regressions and not self.failed


def compare_jobs(
    base: dict[str, dict[str, Any]],
    new: dict[str, dict[str, Any]],
    tol: Tolerance | None = None,
    metrics: tuple[str, ...] | None = None,
) -> Comparison:
    """Compare two {job_id: {"label", "status", "metrics": {flat key: value}}} maps.

    ``metrics`` limits the comparison to those keys (default: every metric with
    a direction). ``status`` 'error' in ``new`` for a job that is 'ok' in ``base``
    is a failure.
    """
    tol = tol or Tolerance()
    keys = metrics if metrics is not None else tuple(DIRECTIONS)
    deltas, failed = [], []
    for jid, b in base.items():
        if jid not in new:
            continue
        n = new[jid]
        label = n.get("label") or b.get("label") or jid
        if n.get("status", "ok") != "ok":
            if b.get("status", "ok") == "ok":
                failed.append((jid, label, n.get("error") or "error"))
            continue
        if b.get("status", "ok") != "ok":
            continue
        bm, nm = b.get("metrics", {}), n.get("metrics", {})
        for key in keys:
            if key not in bm or key not in nm:
                continue
            bv, nv = _num(bm[key]), _num(nm[key])
            reg, note = is_regression(key, bv, nv, tol)
            deltas.append(Delta(jid, label, key, bv, nv, DIRECTIONS.get(key, 0), reg, note))
    only_base = [(j, base[j].get("label", j)) for j in base if j not in new]
    only_new = [(j, new[j].get("label", j)) for j in new if j not in base]
    return Comparison(deltas, failed, only_base, only_new, tol)


# ----------------------------------------------------------------- baselines
class BaselineError(ValueError):
    """A missing or unreadable baseline or suite run folder."""


def read_summary(run_dir: Path) -> dict[str, Any]:
    """summary.json of a suite run folder."""
    p = Path(run_dir) / "summary.json"
    if not p.is_file():
        raise BaselineError(f"{run_dir}: no summary.json: not a finished suite run folder")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as e:
        raise BaselineError(f"{p}: not valid JSON: {e}") from None


def summary_jobs(summary: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """{job_id: {"label", "status", "error", "metrics"}} of a summary.json."""
    return {
        j["job_id"]: {
            "label": j.get("label", j["job_id"]),
            "status": j.get("status", "ok"),
            "error": j.get("error"),
            "metrics": {k: _num(v) for k, v in (j.get("metrics") or {}).items()},
        }
        for j in summary.get("jobs", [])
    }


def baseline_path(suite: str, baselines_dir: Path | None = None) -> Path:
    return Path(baselines_dir or BASELINES_DIR) / f"{suite}.json"


def read_baseline(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise BaselineError(
            f"no baseline {path}: write one with `omnibench baseline update SUITE_RUN_DIR`"
        )
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise BaselineError(f"{path}: not valid JSON: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("jobs"), dict):
        raise BaselineError(f"{path}: key 'jobs': missing or not a mapping")
    return data


def _json_num(v: float) -> float | None:
    return None if _isnan(v) else v


def update_baseline(
    run_dir: Path, baselines_dir: Path | None = None
) -> tuple[Path, list[str], dict[str, Any]]:
    """Write the baseline of the run's suite from its ok jobs; returns (path, changes, data).

    ``changes`` are lines: jobs added or removed and every metric whose value changed.
    """
    summary = read_summary(run_dir)
    suite = summary["suite"]
    path = baseline_path(suite, baselines_dir)
    old = read_baseline(path)["jobs"] if path.is_file() else {}
    jobs = {  # timing is the machine's, not the code's: left out
        jid: {
            "label": j["label"],
            "metrics": {
                k: _json_num(v) for k, v in j["metrics"].items() if not k.startswith("timing.")
            },
        }
        for jid, j in summary_jobs(summary).items()
        if j["status"] == "ok"
    }
    changes = []
    for jid, j in jobs.items():
        if jid not in old:
            changes.append(f"added {j['label']}")
            continue
        om = old[jid]["metrics"]
        for k in sorted(set(om) | set(j["metrics"])):
            if k.startswith("timing."):
                continue
            a, b = _num(om.get(k)), _num(j["metrics"].get(k))
            if not (a == b or (_isnan(a) and _isnan(b))):
                changes.append(f"{j['label']}: {k} {a:.6g} -> {b:.6g}")
    changes += [f"removed {o['label']}" for jid, o in old.items() if jid not in jobs]
    data = {
        "suite": suite,
        "updated_at": now_iso(),
        "from_run": summary.get("run_id"),
        "commit": summary.get("commit"),
        # what rendered its drives: another machine's renders differ (`render_note`)
        "render_machines": summary.get("render_machines"),
        "jobs": dict(sorted(jobs.items(), key=lambda kv: kv[1]["label"])),
    }
    write_json(path, data)
    return path, changes, data


def check_baseline(
    run_dir: Path,
    tol: Tolerance | None = None,
    baselines_dir: Path | None = None,
    metrics: tuple[str, ...] = BASELINE_METRICS,
) -> Comparison:
    """Compare a suite run folder with its suite's committed baseline."""
    summary = read_summary(run_dir)
    path = baseline_path(summary["suite"], baselines_dir)
    base = {
        jid: {"label": j["label"], "status": "ok", "metrics": j["metrics"]}
        for jid, j in read_baseline(path)["jobs"].items()
    }
    new = summary_jobs(summary)
    if base and new and not set(base) & set(new):
        raise BaselineError(
            f"no job of {run_dir} is in {path}: the suite's jobs changed (scenarios, "
            "cameras, overrides or frames); update the baseline on purpose"
        )
    return compare_jobs(base, new, tol, metrics)


def render_note(run_dir: Path, baselines_dir: Path | None = None) -> str | None:
    """A sentence when a run's drives were rendered on other machines than its baseline's
    (renders are bit-identical on one machine only: docs/DESIGN.md, "Reading the
    figures"), else None (the same machines, or either not recorded)."""
    summary = read_summary(run_dir)
    base = read_baseline(baseline_path(summary["suite"], baselines_dir)).get("render_machines")
    new = summary.get("render_machines")
    from sim.machine import describe, machine_key

    if not base or not new or sorted(map(machine_key, base)) == sorted(map(machine_key, new)):
        return None

    return (
        f"note: the baseline's drives were rendered on {'; '.join(map(describe, base))}, "
        f"this run's on {'; '.join(map(describe, new))}: renders differ from machine to "
        "machine, so its figures may move within the tolerance without a change of code"
    )
