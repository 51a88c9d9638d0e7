"""What a suite run leaves in its folder besides the jobs.

- ``summary.json``: the run and every job (description, status, error, flat
  metrics with NaN as null, threshold checks, passed);
- ``junit.xml``: one testcase per job, failing when the job misses its suite's
  thresholds, erroring when the job raised;
- ``report.html`` (opens from disk: relative links, no script, no network): the
  metrics table (scenario x camera x estimator), plots (``plots/*.png``: ego
  speed error against time per scenario x camera, recall by range and by
  bearing, estimator comparison bars, sweeps as curves), each job's
  ``surround.png`` still and links to its videos and page;
- per job (`write_job_extras`): ``trajectory.tum`` and ``groundtruth.tum``
  (`scenarios.tum`) and ``recall_bins.json``.

Recall by range and by bearing are of the *tracks* (tracks.csv), the runner's
``tracking`` evaluation set: the runner does not save its per-frame detections.
The evaluation set is rebuilt with `scenarios.runner.gt_evaluation_set` on the
frames the runner evaluated (frame >= 1 with a finite estimate).
"""

from __future__ import annotations

import html
import json
import math
import os
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from estimator.fileio import atomic_write, write_json, write_text
from scenarios.suite import ROLE_MEANING, Job, Suite, Threshold
from sim.machine import machines_line

RANGE_STEP_M = 5.0  # [m] recall-by-range bin width
BEARING_EDGES_DEG = tuple(range(-180, 181, 30))  # [deg]

# columns of the metrics table: (flat key, header)
TABLE_METRICS = (
    ("ego.speed_rmse_pct", "speed RMSE [%]"),
    ("ego.speed_rmse_mps", "speed RMSE [m/s]"),
    ("ego.yaw_rate_rmse_dps", "yaw-rate RMSE [deg/s]"),
    ("ego.yaw_rate_rmse_exposure_dps", "yaw-rate RMSE vs exposure means [deg/s]"),
    ("ego.angle_rmse_deg", "A roll/pitch RMSE [deg]"),
    ("points_above_road.speed_info_share", "speed info above road"),
    ("point_pull.speed_pull_pct", "speed pull at truth [%]"),
    ("point_pull.yaw_rate_pull_dps", "yaw pull at truth [deg/s]"),
    ("surround.candidates.detection.recall", "candidate recall"),
    ("surround.tracker.lost_share", "tracker lost (of candidate finds)"),
    ("detection.recall", "recall"),
    ("detection.precision", "precision"),
    ("tracking.mota", "MOTA"),
    ("tracking.idf1", "IDF1"),
    ("tracking.hota", "HOTA"),
    ("localization.median_error_m", "loc. median [m]"),
    ("localization.centre_median_error_m", "box centre median [m]"),
    ("surround.segmentation.pixel_recall", "mask pixel recall"),
    ("surround.segmentation.pixel_precision", "mask pixel precision"),
)

_CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1800px}
table{border-collapse:collapse;margin:0.5em 0;font-size:13px}
td,th{border:1px solid #bbb;padding:3px 6px}th{background:#eee;text-align:left}
td.num{text-align:right;font-variant-numeric:tabular-nums}
tr.error td{background:#fdd}td.fail{background:#fdd;font-weight:bold}td.pass{background:#dfd}
img{max-width:100%;border:1px solid #ccc}.grid{display:flex;flex-wrap:wrap;gap:12px}
.grid figure{margin:0;width:440px}figcaption{font-size:12px}
pre{background:#f6f6f6;padding:6px;overflow-x:auto;font-size:11px}"""


# ------------------------------------------------------------------ outcomes
@dataclass
class Outcome:
    """One job of the run: its description, result and threshold checks."""

    job: Job
    status: str  # "ok" | "error" | "pending"
    metrics: dict[str, float] = field(default_factory=dict)
    error: str | None = None
    traceback: str | None = None
    wall_s: float | None = None
    checks: list[dict[str, Any]] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return self.status == "ok" and all(c["ok"] for c in self.checks)

    def summary(self) -> dict[str, Any]:
        return {
            **self.job.describe(),
            "status": self.status,
            "passed": self.passed,
            "error": self.error,
            "wall_s": self.wall_s,
            "metrics": {k: _json_num(v) for k, v in sorted(self.metrics.items())},
            "thresholds": self.checks,
        }


def _json_num(v: float | None) -> float | None:
    return None if v is None or (isinstance(v, float) and math.isnan(v)) else v


def check_thresholds(metrics: dict[str, float], thresholds: dict[str, Threshold]) -> list[dict]:
    """One check per threshold: {metric, min, max, value, ok}; NaN or missing fails."""
    out = []
    for key, t in thresholds.items():
        v = metrics.get(key, math.nan)
        ok = v is not None and math.isfinite(v)
        if ok and t.min is not None:
            ok = v >= t.min
        if ok and t.max is not None:
            ok = v <= t.max
        out.append({"metric": key, "min": t.min, "max": t.max, "value": _json_num(v), "ok": ok})
    return out


def collect_outcomes(suite: Suite, rows: dict[str, dict[str, Any]]) -> list[Outcome]:
    """Outcomes of the suite's jobs from history rows {job_id: row} (`History.jobs`)."""
    out = []
    for job in suite.jobs:
        r = rows.get(job.job_id)
        if r is None:
            out.append(Outcome(job, "pending"))
            continue
        o = Outcome(
            job,
            r["status"],
            dict(r.get("metrics") or {}),
            r.get("error"),
            r.get("traceback"),
            r.get("wall_s"),
        )
        if o.status == "ok":
            o.checks = check_thresholds(o.metrics, suite.thresholds_for(job))
        out.append(o)
    return out


# ------------------------------------------------------------------ per-job extras
def write_job_extras(job_dir: Path, drive_dir: Path, force: bool = False) -> None:
    """trajectory.tum, groundtruth.tum and recall_bins.json of a finished job.

    Skipped when they are newer than the job's metrics.json (unless ``force``).
    """
    from scenarios.metrics import read_egomotion_csv
    from scenarios.tum import write_estimated_tum, write_groundtruth_tum
    from sim.drive import load_groundtruth

    job_dir, drive_dir = Path(job_dir), Path(drive_dir)
    metrics_p = job_dir / "metrics.json"
    outputs = [job_dir / n for n in ("trajectory.tum", "groundtruth.tum", "recall_bins.json")]
    if not force and all(
        p.exists() and p.stat().st_mtime_ns >= metrics_p.stat().st_mtime_ns for p in outputs
    ):
        return
    ego = read_egomotion_csv(job_dir / "egomotion.csv")
    gt = load_groundtruth(drive_dir)
    write_estimated_tum(ego, outputs[0])
    write_groundtruth_tum(gt, outputs[1])
    metrics = json.loads(metrics_p.read_text())
    write_json(outputs[2], recall_bins(gt, job_dir / "tracks.csv", metrics))


def recall_bins(gt: list[dict], tracks_csv: Path, metrics: dict) -> dict:
    """Track recall by range and by bearing (`scenarios.detection_metrics`), over the
    frames the run scored its tracks on (`scenarios.evaluate.track_frames`)."""
    from scenarios.detection_metrics import MetricsConfig, recall_by_bearing, recall_by_range
    from scenarios.evaluate import read_tracks_input, track_frames

    ev = metrics.get("evaluation", {})
    max_range = float(ev.get("max_range_m", 25.0))
    gate = float(ev.get("gate_m", 1.5))
    frames = track_frames(read_tracks_input(tracks_csv, len(gt)), gt, max_range)
    cfg = MetricsConfig(gate_m=gate)
    edges = np.arange(0.0, max_range + RANGE_STEP_M - 1e-9, RANGE_STEP_M)
    return {
        "source": "tracks",
        "frames": len(frames),
        "range": recall_by_range(frames, edges.tolist(), cfg),
        "bearing": recall_by_bearing(frames, list(BEARING_EDGES_DEG), cfg),
    }


# ------------------------------------------------------------------ summary, junit
def write_summary(
    out_dir: Path, suite: Suite, run: dict[str, Any], outcomes: list[Outcome]
) -> dict[str, Any]:
    counts = {
        "jobs": len(outcomes),
        "ok": sum(o.status == "ok" for o in outcomes),
        "error": sum(o.status == "error" for o in outcomes),
        "pending": sum(o.status == "pending" for o in outcomes),
        "passed": sum(o.passed for o in outcomes),
        "failed_thresholds": sum(o.status == "ok" and not o.passed for o in outcomes),
    }
    data = {
        **run,
        "suite": suite.name,
        "description": suite.spec.description,
        "role": suite.spec.role,
        "thresholds": {
            k: t.model_dump(exclude_none=True) for k, t in suite.spec.thresholds.items()
        },
        "counts": counts,
        "jobs": [o.summary() for o in outcomes],
    }
    write_json(Path(out_dir) / "summary.json", data)
    return data


def write_junit(out_dir: Path, suite: Suite, outcomes: list[Outcome], timestamp: str) -> Path:
    """JUnit XML: one testcase per job."""
    failures = sum(o.status == "ok" and not o.passed for o in outcomes)
    errors = sum(o.status != "ok" for o in outcomes)
    total = sum(o.wall_s or 0.0 for o in outcomes)
    root = ET.Element("testsuites", name=f"omnibench suite {suite.name}")
    ts = ET.SubElement(
        root,
        "testsuite",
        name=suite.name,
        tests=str(len(outcomes)),
        failures=str(failures),
        errors=str(errors),
        skipped="0",
        time=f"{total:.3f}",
        timestamp=timestamp,
    )
    for o in outcomes:
        tc = ET.SubElement(
            ts,
            "testcase",
            classname=f"omnibench.{suite.name}.{o.job.scenario.name}",
            name=o.job.label,
            time=f"{o.wall_s or 0.0:.3f}",
        )
        if o.status == "error":
            e = ET.SubElement(tc, "error", message=(o.error or "error")[:500], type="JobError")
            e.text = o.traceback or o.error or ""
        elif o.status == "pending":
            e = ET.SubElement(tc, "error", message="job did not run", type="Pending")
        elif not o.passed:
            bad = [c for c in o.checks if not c["ok"]]
            msg = "; ".join(_check_text(c) for c in bad)
            f = ET.SubElement(tc, "failure", message=msg, type="ThresholdMissed")
            f.text = msg
        out = ET.SubElement(tc, "system-out")
        out.text = json.dumps(
            {"job_id": o.job.job_id, "dir": o.job.describe()["dir"], "checks": o.checks}
        )
    path = Path(out_dir) / "junit.xml"
    ET.indent(root)
    atomic_write(
        path, lambda p: ET.ElementTree(root).write(p, encoding="utf-8", xml_declaration=True)
    )
    return path


def _check_text(c: dict) -> str:
    v = "nan" if c["value"] is None else f"{c['value']:.4g}"
    bounds = []
    if c["min"] is not None:
        bounds.append(f">= {c['min']:g}")
    if c["max"] is not None:
        bounds.append(f"<= {c['max']:g}")
    return f"{c['metric']} = {v} (needs {' and '.join(bounds)})"


# ------------------------------------------------------------------ plots
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    atomic_write(path, lambda p: fig.savefig(p, dpi=80), suffix=".png")
    _plt().close(fig)


def _variant(job: Job) -> str:
    extra = "".join(f" {k}={v}" for k, v in job.overrides.items())
    return f"{job.estimator} s{job.seed}{extra}"


def plot_speed_errors(
    out_dir: Path, outcomes: list[Outcome], drive_dir_of, max_groups: int = 40
) -> list[tuple[str, str]]:
    """One PNG per (scenario, camera): estimated minus true forward speed against time."""
    from estimator.camera.files import load_camera
    from scenarios.metrics import ego_series, read_egomotion_csv
    from sim.drive import load_groundtruth

    plt = _plt()
    groups: dict[tuple[str, str], list[Outcome]] = defaultdict(list)
    for o in outcomes:
        if o.status == "ok":
            groups[o.job.group].append(o)
    gt_cache: dict[str, tuple[list, Any]] = {}
    out = []
    for gi, (group, members) in enumerate(sorted(groups.items())[:max_groups]):
        fig, ax = plt.subplots(figsize=(6.5, 2.8))
        for o in members:
            drive = drive_dir_of(o.job)
            key = str(drive)
            try:
                if key not in gt_cache:  # one drive in memory at a time
                    gt_cache = {
                        key: (load_groundtruth(drive), load_camera(drive / "camera.yaml")[1])
                    }
                gt, mount = gt_cache[key]
                s = ego_series(
                    read_egomotion_csv(out_dir / o.job.describe()["dir"] / "egomotion.csv"),
                    gt,
                    mount,
                )
            except Exception:  # a job without its files only thins the plot
                continue
            ax.plot(s["t_s"], s["speed_est"] - s["speed_gt"], lw=1.2, label=_variant(o.job))
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("speed error [m/s]")
        ax.set_title(f"{group[0]} | {group[1]}", fontsize=10)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
        fig.tight_layout()
        name = f"plots/speed_error_{gi:03d}.png"
        _save(fig, out_dir / name)
        out.append((name, f"ego speed error against time: {group[0]} | {group[1]}"))
    return out


def plot_recall_bins(out_dir: Path, outcomes: list[Outcome]) -> list[tuple[str, str]]:
    """Track recall by range and by bearing, pooled over scenarios per camera x estimator."""
    plt = _plt()
    pooled: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for o in outcomes:
        p = out_dir / o.job.describe()["dir"] / "recall_bins.json"
        if o.status != "ok" or not p.exists():
            continue
        bins = json.loads(p.read_text())
        key = f"{o.job.camera} | {o.job.estimator}"
        slot = pooled.setdefault(key, {})
        for kind in ("range", "bearing"):
            b = bins[kind]
            e = slot.setdefault(
                kind,
                {
                    "edges": np.array(b["bin_edges"]),
                    "gt": np.zeros(len(b["gt_count"])),
                    "hit": np.zeros(len(b["gt_count"])),
                },
            )
            if len(e["gt"]) == len(b["gt_count"]):
                e["gt"] += b["gt_count"]
                e["hit"] += b["matched"]
    if not pooled:
        return []
    out = []
    for kind, xlabel in (("range", "range [m]"), ("bearing", "bearing [deg] (0 ahead, +90 left)")):
        fig, ax = plt.subplots(figsize=(6.5, 3.2))
        for key, slot in sorted(pooled.items()):
            e = slot[kind]
            centres = 0.5 * (e["edges"][1:] + e["edges"][:-1])
            with np.errstate(invalid="ignore", divide="ignore"):
                rec = np.where(e["gt"] > 0, e["hit"] / np.maximum(e["gt"], 1), np.nan)
            ax.plot(centres, rec, "o-", label=key)
        ax.set_ylim(-0.02, 1.02)
        edges = next(iter(pooled.values()))[kind]["edges"]
        ax.set_xlim(edges[0], edges[-1])
        ax.set_xlabel(xlabel)
        ax.set_ylabel("track recall")
        ax.set_title(f"recall by {kind} (pooled over scenarios)", fontsize=10)
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        name = f"plots/recall_by_{kind}.png"
        _save(fig, out_dir / name)
        out.append((name, f"track recall by {kind}, per camera and estimator"))
    return out


def pool_recall_polar(
    out_dir: Path, outcomes: list[Outcome]
) -> dict[tuple[str, str, str], dict[str, Any]]:
    """Track recall grids around the car (`metrics.json` "surround.recall_polar") summed
    over the jobs of each (camera, estimator, detector); jobs without vehicles left out."""
    pooled: dict[tuple[str, str, str], dict[str, Any]] = {}
    for o in outcomes:
        p = out_dir / o.job.describe()["dir"] / "metrics.json"
        if o.status != "ok" or not p.exists():
            continue
        polar = json.loads(p.read_text()).get("surround", {}).get("recall_polar")
        if not polar or not np.sum(polar["gt_count"]):
            continue
        key = (o.job.camera, o.job.estimator, o.job.detector)
        slot = pooled.get(key)
        if slot is None:
            pooled[key] = {**polar, "gt_count": np.array(polar["gt_count"]),
                           "matched": np.array(polar["matched"])}  # fmt: skip
        elif slot["range_edges_m"] == polar["range_edges_m"]:
            slot["gt_count"] = slot["gt_count"] + polar["gt_count"]
            slot["matched"] = slot["matched"] + polar["matched"]
    return pooled


def plot_recall_polar_pooled(out_dir: Path, outcomes: list[Outcome]) -> list[tuple[str, str]]:
    """One polar picture of track recall per camera x estimator x detector, pooled over
    the drives (`pool_recall_polar`)."""
    from scenarios.visualize import plot_recall_polar

    out = []
    for i, (key, polar) in enumerate(sorted(pool_recall_polar(out_dir, outcomes).items())):
        name = f"plots/recall_polar_{i:02d}.png"
        label = " | ".join(key)
        plot_recall_polar(polar, out_dir / name, f"{label}: track recall, pooled over drives")
        out.append((name, f"track recall around the car: {label}, pooled over the drives"))
    return out


BAR_METRICS = (
    ("ego.speed_rmse_pct", "speed RMSE [%]"),
    ("ego.yaw_rate_rmse_dps", "yaw-rate RMSE [deg/s]"),
    ("detection.recall", "recall"),
    ("tracking.mota", "MOTA"),
)


def plot_estimator_bars(out_dir: Path, outcomes: list[Outcome]) -> list[tuple[str, str]]:
    """Bars per estimator for each (scenario, camera), means over seeds and overrides."""
    plt = _plt()
    ok = [o for o in outcomes if o.status == "ok"]
    groups = sorted({o.job.group for o in ok})
    ests = list(dict.fromkeys(o.job.estimator for o in ok))
    if not groups:
        return []
    width_in = max(6.5, 0.5 * len(groups) * max(2, len(ests)))
    fig, axes = plt.subplots(len(BAR_METRICS), 1, figsize=(width_in, 10))
    x = np.arange(len(groups))
    width = 0.8 / max(1, len(ests))
    for ax, (key, title) in zip(axes, BAR_METRICS, strict=True):
        for i, est in enumerate(ests):
            vals = []
            for g in groups:
                v = [
                    o.metrics.get(key, math.nan)
                    for o in ok
                    if o.job.group == g and o.job.estimator == est
                ]
                v = [a for a in v if a is not None and math.isfinite(a)]
                vals.append(float(np.mean(v)) if v else math.nan)
            ax.bar(x + (i - (len(ests) - 1) / 2) * width, vals, width, label=est)
        ax.set_ylabel(title, fontsize=8)
        ax.set_xticks(x)
        ax.set_xticklabels([f"{s}\n{c.replace('(', chr(10) + '(')}" for s, c in groups], fontsize=7)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle("estimator comparison", fontsize=10)
    fig.tight_layout()
    name = "plots/estimators.png"
    _save(fig, out_dir / name)
    return [(name, "estimator comparison per scenario and camera")]


SWEEP_METRICS = (("ego.speed_rmse_pct", "speed RMSE [%]"), ("detection.recall", "recall"))


def plot_sweeps(out_dir: Path, suite: Suite, outcomes: list[Outcome]) -> list[tuple[str, str]]:
    """For each swept override: metrics against its value, one curve per other setting."""
    plt = _plt()
    out = []
    ok = [o for o in outcomes if o.status == "ok"]
    for si, key in enumerate(suite.spec.swept_keys()):
        curves: dict[str, list[tuple[Any, Outcome]]] = defaultdict(list)
        for o in ok:
            rest = {k: v for k, v in o.job.overrides.items() if k != key}
            label = f"{o.job.scenario.name} | {o.job.camera} | {o.job.estimator} s{o.job.seed}"
            label += "".join(f" {k}={v}" for k, v in rest.items())
            curves[label].append((o.job.overrides.get(key), o))
        fig, axes = plt.subplots(1, len(SWEEP_METRICS), figsize=(11, 3.4))
        for ax, (mkey, title) in zip(axes, SWEEP_METRICS, strict=True):
            for label, pts in sorted(curves.items()):
                numeric = all(isinstance(v, int | float) for v, _ in pts)
                pts = sorted(pts, key=lambda p: p[0]) if numeric else pts
                xs = [v for v, _ in pts] if numeric else list(range(len(pts)))
                ax.plot(xs, [o.metrics.get(mkey, math.nan) for _, o in pts], "o-", label=label)
            ax.set_xlabel(key)
            ax.set_ylabel(title)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=6, loc="best")
        fig.suptitle(f"sweep of {key}", fontsize=10)
        fig.tight_layout()
        name = f"plots/sweep_{si:02d}.png"
        _save(fig, out_dir / name)
        out.append((name, f"sweep of {key}"))
    return out


# ------------------------------------------------------------------ the page
def _fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return html.escape(str(v))


def _rel(target: Path, start: Path) -> str:
    return Path(os.path.relpath(target, start)).as_posix()


def write_report(
    out_dir: Path,
    suite: Suite,
    run: dict[str, Any],
    outcomes: list[Outcome],
    drive_dir_of,
) -> Path:
    """``out_dir/report.html`` with its plots under ``out_dir/plots/``."""
    out_dir = Path(out_dir)
    plots: list[tuple[str, str]] = []
    plot_errors: list[str] = []
    for what, make in (
        ("estimator bars", lambda: plot_estimator_bars(out_dir, outcomes)),
        ("sweeps", lambda: plot_sweeps(out_dir, suite, outcomes)),
        ("recall bins", lambda: plot_recall_bins(out_dir, outcomes)),
        ("recall around the car", lambda: plot_recall_polar_pooled(out_dir, outcomes)),
        ("speed errors", lambda: plot_speed_errors(out_dir, outcomes, drive_dir_of)),
    ):
        try:
            plots += make()
        except Exception as e:  # the page still opens, and says what is missing
            plot_errors.append(f"{what}: {type(e).__name__}: {e}")
    ordered = sorted(
        outcomes,
        key=lambda o: (
            o.job.scenario.name,
            o.job.camera,
            o.job.estimator,
            o.job.detector,
            o.job.seed,
            str(o.job.overrides),
        ),
    )
    n_ok = sum(o.status == "ok" for o in outcomes)
    n_err = sum(o.status == "error" for o in outcomes)
    n_pass = sum(o.passed for o in outcomes)
    parts = [
        f"<h1>omnibench suite: {html.escape(suite.name)}</h1>",
        f"<p>{html.escape(suite.spec.description)}</p>" if suite.spec.description else "",
        f"<p><b>A {ROLE_MEANING[suite.spec.role]}.</b></p>" if suite.spec.role else "",
        f"<p>run <code>{_fmt(run.get('run_id'))}</code>, commit <code>{_fmt(run.get('commit'))}"
        f"</code>, finished {_fmt(run.get('finished_at'))}; {len(outcomes)} jobs: "
        f"<b>{n_ok}</b> ok, <b>{n_err}</b> errors, <b>{n_pass}</b> passed their thresholds</p>",
        f"<p>{html.escape(machines_line(run.get('machine'), run.get('render_machines')))}</p>",
    ]
    if suite.spec.thresholds:
        items = "".join(
            f"<li>{html.escape(k)}: {_fmt(t.min) + ' &le; ' if t.min is not None else ''}value"
            f"{' &le; ' + _fmt(t.max) if t.max is not None else ''}"
            f"{' (' + ', '.join(t.estimators) + ')' if t.estimators else ''}</li>"
            for k, t in suite.spec.thresholds.items()
        )
        parts.append(f"<h2>thresholds</h2><ul>{items}</ul>")
    head = "".join(
        f"<th>{h}</th>"
        for h in ("scenario", "camera", "estimator", "detector", "seed", "overrides", "status")
    )
    head += "".join(f"<th>{html.escape(h)}</th>" for _, h in TABLE_METRICS)
    head += "<th>thresholds</th><th>files</th>"
    rows = []
    for o in ordered:
        jdir = o.job.describe()["dir"]
        cells = [
            _fmt(o.job.scenario.name),
            _fmt(o.job.camera),
            _fmt(o.job.estimator),
            _fmt(o.job.detector),
            _fmt(o.job.seed),
            _fmt(", ".join(f"{k}={v}" for k, v in o.job.overrides.items())),
            _fmt(o.status if o.status != "error" else f"error: {o.error}"),
        ]
        tds = "".join(f"<td>{c}</td>" for c in cells)
        tds += "".join(f"<td class=num>{_fmt(o.metrics.get(k))}</td>" for k, _ in TABLE_METRICS)
        if o.status != "ok":
            tds += "<td class=fail>–</td>"
        elif not o.checks:
            tds += "<td>none</td>"
        else:
            bad = [c for c in o.checks if not c["ok"]]
            cls = "fail" if bad else "pass"
            text = "; ".join(_check_text(c) for c in bad) if bad else "pass"
            tds += f"<td class={cls}>{html.escape(text)}</td>"
        links = [
            f"<a href='{jdir}/{n}'>{n.split('.')[0]}</a>"
            for n in ("report.html", "analysis.mp4", "metrics.json", "trajectory.tum")
            if (out_dir / jdir / n).exists()
        ]
        tds += f"<td>{' '.join(links)}</td>"
        rows.append(f"<tr class='{o.status}'>{tds}</tr>")
    parts.append(
        "<h2>metrics</h2><table id=metrics><thead><tr>"
        + head
        + "</tr></thead><tbody>"
        + "".join(rows)
        + "</tbody></table>"
    )
    if plots:
        parts.append("<h2>plots</h2><div class=grid>")
        for name, caption in plots:
            parts.append(
                f"<figure style='width:640px'><img src='{name}' alt='{html.escape(caption)}'>"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
        parts.append("</div>")
    for err in plot_errors:
        parts.append(f"<p class=fail>plot failed: {html.escape(err)}</p>")
    stills = []
    for o in ordered:
        jdir = o.job.describe()["dir"]
        if not (out_dir / jdir / "surround.png").exists():
            continue
        vids = (
            [f"<a href='{jdir}/analysis.mp4'>analysis.mp4</a>"]
            if (out_dir / jdir / "analysis.mp4").exists()
            else []
        )
        drive_mp4 = drive_dir_of(o.job) / "drive.mp4"
        if drive_mp4.exists():
            vids.append(f"<a href='{_rel(drive_mp4, out_dir)}'>drive.mp4</a>")
        stills.append(
            f"<figure><a href='{jdir}/report.html'><img src='{jdir}/surround.png' "
            f"alt='surround {html.escape(o.job.label)}'></a><figcaption>"
            f"{html.escape(o.job.label)}<br>{' · '.join(vids)}</figcaption></figure>"
        )
    if stills:
        parts.append("<h2>stills</h2><div class=grid>" + "".join(stills) + "</div>")
    errs = [o for o in ordered if o.status == "error"]
    if errs:
        parts.append("<h2>errors</h2>")
        for o in errs:
            text = html.escape(o.traceback or o.error or "")
            parts.append(f"<h3>{html.escape(o.job.label)}</h3><pre>{text}</pre>")
    names = ("summary.json", "junit.xml", "suite.yaml", "run.json")
    links = [f"<a href='{n}'>{n}</a>" for n in names if (out_dir / n).exists()]
    parts.append("<h2>files</h2><p>" + " · ".join(links) + "</p>")
    page = (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>omnibench suite {html.escape(suite.name)}</title><style>{_CSS}</style>"
        "</head><body>" + "\n".join(p for p in parts if p) + "</body></html>\n"
    )
    path = out_dir / "report.html"
    write_text(path, page)
    return path
