"""`omnibench run`: render (or reuse) a drive, estimate ego-motion, measure it.

Writes into ``out/``: ``drive/`` (the render, see sim.drive), ``egomotion.csv``,
``ego_error.png`` and ``metrics.json`` (written last).
"""

from __future__ import annotations

import json
from pathlib import Path

from estimator.camera_io import load_camera
from estimator.fileio import write_json
from estimator.pipeline import estimate_frames, write_egomotion_csv
from estimator.recording import iter_frames, read_can_csv, read_timestamps_csv
from scenarios.config import Scenario
from scenarios.metrics import ego_metrics, ego_series, plot_ego_errors, read_egomotion_csv
from sim.drive import load_groundtruth, render_drive


def run_scenario(scenario: Scenario, out_dir: Path, estimator: str = "direct",
                 drive_dir: Path | None = None, progress: bool = True,
                 max_frames: int | None = None) -> dict:
    """Render (resuming), estimate and measure one scenario; returns metrics.json's content."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    drive_dir = Path(drive_dir) if drive_dir is not None else out_dir / "drive"
    drive = render_drive(scenario, drive_dir, progress=progress, max_frames=max_frames)
    gt = load_groundtruth(drive_dir)
    camera, mount = load_camera(drive_dir / "camera.yaml")
    times = read_timestamps_csv(drive_dir / "timestamps.csv")
    can = read_can_csv(drive_dir / "can.csv")
    run = estimate_frames(iter_frames(drive_dir / "frames"), times, can, camera, mount,
                          estimator=estimator, progress=progress)
    write_egomotion_csv(out_dir / "egomotion.csv", run.records, mount)
    series = ego_series(read_egomotion_csv(out_dir / "egomotion.csv"), gt, mount)
    plot_ego_errors(series, out_dir / "ego_error.png",
                    title=f"{scenario.name} - {estimator}")
    manifest = json.loads((drive_dir / "manifest.json").read_text())
    metrics = {
        "scenario": scenario.name,
        "camera": scenario.camera if isinstance(scenario.camera, str) else "inline",
        "estimator": estimator,
        "frames": drive.n_frames,
        "ego": ego_metrics(series),
        "timing": {
            "render_ms_per_frame": manifest.get("render_ms_per_frame"),
            "estimate_ms_per_frame": run.ms_per_frame,
        },
    }
    write_json(out_dir / "metrics.json", metrics)
    return metrics
