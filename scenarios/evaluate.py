"""Scoring of ego-motion and track files against a rendered drive's ground truth.

`omnibench run` scores its own outputs with these functions, after writing them;
`omnibench evaluate` scores files made by any other program the same way, so the
two give the same figures under the same keys (docs/FORMATS.md, "Results made
elsewhere").

Inputs (CSV with a header; other columns are ignored):

- ego-motion: at least ``frame, speed_mps, yaw_rate_dps`` (row k: the motion from
  frame k-1 to frame k, in the car frame); with the nine state columns of
  ``egomotion.csv`` (``V_x .. A_z``) the speed and yaw rate are taken from them, as
  `omnibench run` does, and A's metrics are computed too.
- tracks: at least ``frame, track_id, x_m, y_m`` (the vehicle's point in the ego road
  frame [m]); optionally the box columns of ``tracks.csv`` (``box_x_m, box_y_m``: the
  box centre, scored against the vehicle's footprint centre; with ``box_yaw_rad,
  box_length_m, box_width_m`` too, the box, scored by the box HOTA).

Every frame 1 .. N-1 of the drive must have an ego-motion row; a track file lists only
the frames with tracks. Frames outside 0 .. N-1, a frame twice (ego-motion) or a track id
twice in one frame, values that are not finite numbers and track ids that are not
non-negative integers are refused with the file, the row and the value.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from scenarios.detection_metrics import (
    EGO_MOVING_MPS,
    EvalFrame,
    MetricsConfig,
    breakdown,
    evaluate,
    recall_polar,
)
from scenarios.metrics import STATE_COLS, ego_metrics, ego_series
from scenarios.surround_outputs import TRACK_BOX_COLUMNS, TRACK_STATE_COLUMNS
from scenarios.track_state import track_state

EGOMOTION_REQUIRED = ("frame", "speed_mps", "yaw_rate_dps")
TRACKS_REQUIRED = ("frame", "track_id", "x_m", "y_m")
ANGLE_KEYS = ("angle_rmse_deg", "roll_rmse_deg", "pitch_rmse_deg", "angle_yaw_rmse_deg")
POLAR_RING_M = 5.0  # [m] range rings of the recall-around-the-car grid
POLAR_SECTOR_DEG = 30.0  # [deg] its bearing sectors


class InputError(ValueError):
    """A result file that cannot be scored; the message names the file, row and value."""


def _rows(path: Path, required: tuple[str, ...]) -> list[tuple[int, dict]]:
    """(line number, row) of a CSV file whose header has the required columns."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        header = reader.fieldnames or []
        missing = [c for c in required if c not in header]
        if missing:
            raise InputError(f"{path}: missing column(s) {missing}; the header is {header}")
        return [(i + 2, r) for i, r in enumerate(reader)]  # line 1 is the header


def _number(path: Path, line: int, row: dict, col: str, allow_nan: bool = False) -> float:
    raw = row.get(col)
    try:
        v = float(raw)
    except (TypeError, ValueError):
        if allow_nan and (raw is None or raw.strip() == ""):
            return math.nan
        raise InputError(f"{path}, line {line}: {col}={raw!r} is not a number") from None
    if not math.isfinite(v) and not (allow_nan and math.isnan(v)):
        raise InputError(f"{path}, line {line}: {col}={raw!r} is not finite")
    return v


def _frame(path: Path, line: int, row: dict, n_frames: int) -> int:
    raw = row.get("frame")
    try:
        k = int(raw)
    except (TypeError, ValueError):
        raise InputError(f"{path}, line {line}: frame={raw!r} is not an integer") from None
    if not 0 <= k < n_frames:
        raise InputError(
            f"{path}, line {line}: frame={k} is outside the drive's frames 0..{n_frames - 1}"
        )
    return k


def read_egomotion_input(path: Path, n_frames: int) -> dict[str, np.ndarray]:
    """Columns (N,) of an ego-motion file, checked; ``frame`` as int, rows in frame order.

    The state columns are kept only when all nine are present (NaN is refused there too).
    """
    path = Path(path)
    rows = _rows(path, EGOMOTION_REQUIRED)
    header = list(rows[0][1]) if rows else []
    cols = list(EGOMOTION_REQUIRED[1:]) + (["t_s"] if "t_s" in header else [])
    if all(c in header for c in STATE_COLS):
        cols += STATE_COLS
    seen: dict[int, int] = {}
    out: dict[str, list] = {"frame": [], **{c: [] for c in cols}}
    for line, r in rows:
        k = _frame(path, line, r, n_frames)
        if k in seen:
            raise InputError(f"{path}, line {line}: frame {k} again (first on line {seen[k]})")
        seen[k] = line
        out["frame"].append(k)
        for c in cols:
            out[c].append(_number(path, line, r, c))
    missing = sorted(set(range(1, n_frames)) - set(seen))
    if missing:
        shown = ", ".join(map(str, missing[:10])) + (" ..." if len(missing) > 10 else "")
        raise InputError(f"{path}: no row for frame(s) {shown} of the drive's 1..{n_frames - 1}")
    order = np.argsort(out["frame"])
    arrays = {c: np.asarray(v, float)[order] for c, v in out.items()}
    arrays["frame"] = arrays["frame"].astype(int)
    return arrays


def read_tracks_input(path: Path, n_frames: int) -> dict[int, list[tuple]]:
    """{frame: [(track id, x, y, box x, box y, box yaw, box length, box width, vx, vy,
    var_x, cov_xy, var_y, var_vx, cov_vxvy, var_vy)]} of a track file, checked ([m],
    [rad], [m/s], [m²], [m²/s²]; a box or state value NaN when the file has not its column
    or the row leaves it empty)."""
    path = Path(path)
    rows = _rows(path, TRACKS_REQUIRED)
    out: dict[int, list] = defaultdict(list)
    first: dict[tuple[int, int], int] = {}
    for line, r in rows:
        k = _frame(path, line, r, n_frames)
        raw = r.get("track_id")
        try:
            tid = int(raw)
        except (TypeError, ValueError):
            tid = -1
        if tid < 0 or str(raw).strip() != str(tid):
            raise InputError(f"{path}, line {line}: track_id={raw!r} is not an integer >= 0")
        if (k, tid) in first:
            raise InputError(
                f"{path}, line {line}: track {tid} twice in frame {k} "
                f"(first on line {first[(k, tid)]})"
            )
        first[(k, tid)] = line
        x, y = _number(path, line, r, "x_m"), _number(path, line, r, "y_m")
        box = tuple(
            _number(path, line, r, c, allow_nan=True) if c in r else math.nan
            for c in TRACK_BOX_COLUMNS + TRACK_STATE_COLUMNS
        )
        out[k].append((tid, x, y, *box))
    return dict(out)


def ego_section(est: dict[str, np.ndarray], gt: list[dict], mount, exposure_s: float):
    """(series, the ``ego`` metrics of `ego_metrics`) of an ego-motion input: from the
    state columns when present, else from ``speed_mps`` and ``yaw_rate_dps`` (A NaN)."""
    if all(c in est for c in STATE_COLS):
        series = ego_series({**est, "t_s": _times(est, gt)}, gt, mount, exposure_s=exposure_s)
        return series, ego_metrics(series)
    series = _series_from_rates(est, gt, mount, exposure_s)
    metrics = ego_metrics(series)
    for key in ANGLE_KEYS:
        metrics[key] = math.nan
    metrics["nan_reasons"] = {k: "no A columns (A_x, A_y, A_z) in the input" for k in ANGLE_KEYS}
    return series, metrics


def _series_from_rates(est: dict, gt: list[dict], mount, exposure_s: float) -> dict:
    """`ego_series` of an input with the car-frame speed and yaw rate only (the estimate's
    A, not given, is zero there: its metrics are left out by `ego_section`)."""
    R = mount.R_car_cam
    n = len(est["frame"])
    # a state that reproduces the given speed and yaw rate in the car frame
    V = np.zeros((n, 3))
    V[:, 0] = est["speed_mps"]
    W = np.zeros((n, 3))
    W[:, 2] = np.radians(est["yaw_rate_dps"])
    state = np.concatenate([V @ R, W @ R, np.zeros((n, 3))], axis=1)  # car -> camera axes
    full = {"frame": est["frame"], "t_s": _times(est, gt)}
    full.update({c: state[:, i] for i, c in enumerate(STATE_COLS)})
    return ego_series(full, gt, mount, exposure_s=exposure_s)


def _times(est: dict, gt: list[dict]) -> np.ndarray:
    if "t_s" in est:
        return est["t_s"]
    t = {g["frame"]: g["t_s"] for g in gt}
    return np.array([t[int(k)] for k in est["frame"]], float)


def track_frames(tracks: dict[int, list], gt: list[dict], max_range_m: float) -> list[EvalFrame]:
    """One `EvalFrame` per frame 1 .. N-1 of the drive (frame 0 has no motion to detect
    with): its evaluation set (`scenarios.runner.gt_evaluation_set`) and the tracks."""
    from scenarios.runner import gt_evaluation_set

    frames = []
    for k in range(1, len(gt)):
        gt_set, _ = gt_evaluation_set(gt[k], max_range_m)
        rows = tracks.get(k, [])
        speed = gt[k]["ego"].get("speed_mps")  # records without it: moving (unknown)
        frames.append(
            EvalFrame(
                gt_set,
                [r[:3] for r in rows],
                float(gt[k]["t_s"]),
                speed is None or speed > EGO_MOVING_MPS,
                [r[3:5] for r in rows],
                [r[3:8] for r in rows],
                [r[8:10] for r in rows],
                [r[10:16] for r in rows],
            )
        )
    return frames


def track_sections(frames: list[EvalFrame], cfg: MetricsConfig, max_range_m: float) -> dict:
    """{"tracking", "track_detection" (recall, precision of the tracks),
    "track_localization", "surround": {"tracks", "track_state", "recall_polar",
    "gt_vehicles"}, "nan_reasons"} of the tracks' frames."""
    m = evaluate(frames, cfg)
    rings = np.arange(0.0, max_range_m + POLAR_RING_M - 1e-9, POLAR_RING_M)
    sectors = np.arange(-180.0, 180.0 + 1e-9, POLAR_SECTOR_DEG)
    return {
        "tracking": m["tracking"],
        "track_detection": m["detection"],
        "track_localization": m["localization"],
        "surround": {
            "tracks": breakdown(frames, cfg),
            "track_state": track_state(frames, cfg),
            "recall_polar": recall_polar(frames, rings.tolist(), sectors.tolist(), cfg),
            "gt_vehicles": len({g.id for f in frames for g in f.gt}),
        },
        "nan_reasons": m.get("nan_reasons", {}),
    }


def evaluate_drive(
    drive_dir: Path,
    out_dir: Path,
    egomotion: Path | None = None,
    tracks: Path | None = None,
) -> dict:
    """Score result files against a rendered drive; writes metrics.json, the plots and
    report.html to ``out_dir`` and returns the metrics.

    The inputs are checked (`read_egomotion_input`, `read_tracks_input`) before anything
    is written. Keys are those of `omnibench run`'s metrics.json that the inputs allow:
    ``ego`` (as there, less the estimator's own consistency figures), ``tracking``,
    ``track_detection``, ``track_localization``, ``surround`` (``tracks``,
    ``recall_polar``, ``gt_vehicles``)."""
    from estimator.camera.files import load_camera
    from estimator.fileio import write_json
    from scenarios import visualize as viz
    from scenarios.config import load_scenario
    from scenarios.metrics import plot_ego_errors
    from scenarios.report import write_run_report
    from scenarios.runner import GATE_M, VISIBLE_PX_MIN
    from sim.drive import DriveError, load_groundtruth

    if egomotion is None and tracks is None:
        raise InputError("nothing to score: give an ego-motion file, a track file or both")
    drive_dir = Path(drive_dir)
    try:
        gt = load_groundtruth(drive_dir)
    except (DriveError, OSError, ValueError) as e:
        raise InputError(f"{drive_dir}: not a complete rendered drive: {e}") from None
    _, mount = load_camera(drive_dir / "camera.yaml")
    scenario = load_scenario(drive_dir / "scenario.yaml")
    max_range = scenario.detection_range_m
    est = read_egomotion_input(egomotion, len(gt)) if egomotion is not None else None
    trk = read_tracks_input(tracks, len(gt)) if tracks is not None else None
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    metrics: dict = {
        "scenario": scenario.name,
        "camera": scenario.camera if isinstance(scenario.camera, str) else "inline",
        "estimator": "evaluated",
        "drive": str(drive_dir),
        "inputs": {
            "egomotion": str(egomotion) if egomotion is not None else None,
            "tracks": str(tracks) if tracks is not None else None,
        },
        "frames": len(gt),
    }
    reasons: dict = {}
    if est is not None:
        sensor = scenario.sensor
        exposure = sensor.exposure_s if sensor.motion_blur else 0.0
        series, ego = ego_section(est, gt, mount, exposure)
        reasons.update({f"ego.{k}": v for k, v in ego.pop("nan_reasons", {}).items()})
        metrics["ego"] = ego
        plot_ego_errors(series, out_dir / "ego_error.png", title=f"{scenario.name} - evaluated")
    if trk is not None:
        cfg = MetricsConfig(gate_m=GATE_M)
        sec = track_sections(track_frames(trk, gt, max_range), cfg, max_range)
        keys = ("tracking", "track_detection", "track_localization", "surround")
        metrics.update({k: sec[k] for k in keys})
        reasons.update(sec["nan_reasons"])
        t_s = {g["frame"]: g["t_s"] for g in gt}
        rows = [(k, t_s[k], *r[:3]) for k in sorted(trk) for r in trk[k]]
        viz.plot_tracks(rows, out_dir / "tracks.png", title=f"{scenario.name} - evaluated")
        viz.plot_recall_polar(
            sec["surround"]["recall_polar"],
            out_dir / "recall_polar.png",
            f"{scenario.name} - evaluated: track recall",
        )
    metrics["evaluation"] = {
        "gate_m": GATE_M,
        "visible_px_min": VISIBLE_PX_MIN,
        "max_range_m": max_range,
        "nan_reasons": reasons,
    }
    write_run_report(out_dir, metrics)
    write_json(out_dir / "metrics.json", metrics)
    return metrics
