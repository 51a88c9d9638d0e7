"""The ``omnibench`` command line."""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import typer  # noqa: E402
from rich.console import Console  # noqa: E402

from scenarios.export import FORMATS as EXPORT_FORMATS  # noqa: E402

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Simulation bench for omni-camera ego-motion and surround vehicle detection.",
)
bench_app = typer.Typer(no_args_is_help=True, help="Speed benchmarks (median ms or frames/s).")
app.add_typer(bench_app, name="bench")
console = Console(stderr=True, soft_wrap=True)  # no hard wraps inside error messages


def _fail(msg: str) -> None:
    console.print(f"[red]error:[/red] {msg}")
    raise typer.Exit(2)


@app.command("scenarios")
def list_scenarios() -> None:
    """List the shipped scenarios."""
    from scenarios.config import known_scenarios

    for name in known_scenarios():
        print(name)


@app.command()
def render(
    scenario: str = typer.Argument(..., help="scenario name or path to a YAML file"),
    out: Path = typer.Option(
        ..., "--out", help="output folder (resumes if it holds a partial render)"
    ),
    frames: int | None = typer.Option(
        None, help="render only the first N frames (the whole drive's first N, file for file)"
    ),
    face_px: int | None = typer.Option(None, help="cube-map face size [px]"),
    renderer: str = typer.Option(
        "plane", help="plane (road drawn per pixel, the default) or cube (all by cube faces)"
    ),
) -> None:
    """Render a scenario: frames, ids, range, groundtruth.jsonl, camera.yaml, drive.mp4."""
    from scenarios.config import ScenarioError, load_scenario
    from sim.drive import DriveError, render_drive

    try:
        sc = load_scenario(scenario)
        res = render_drive(sc, out, face_px=face_px, max_frames=frames, renderer=renderer)
    except (ScenarioError, DriveError, ValueError) as e:
        _fail(str(e))
    console.print(
        f"{res.n_frames} frames in {out} ({res.rendered} rendered now, "
        f"{res.render_ms_per_frame:.0f} ms/frame)"
    )


@app.command()
def calibrate(
    points: Path = typer.Argument(..., help="CSV of world/image correspondences"),
    out: Path = typer.Option(..., "--out", help="camera YAML to write"),
    boundary: Path | None = typer.Option(None, help="CSV u,v of field-of-view boundary points"),
    width: int = typer.Option(640),
    height: int = typer.Option(640),
    max_elevation_deg: float = typer.Option(5.0),
    body_mask_deg: float = typer.Option(75.0),
) -> None:
    """Calibrate a hyperbolic omni camera (paper section 3.2) and write camera.yaml."""
    from estimator.camera.calibration import CalibrationError, calibrate_csv
    from estimator.camera.files import save_camera
    from estimator.camera.mount import CameraMount

    try:
        cam, report = calibrate_csv(
            points,
            boundary_csv=boundary,
            width=width,
            height=height,
            max_elevation_deg=max_elevation_deg,
            body_mask_deg=body_mask_deg,
        )
    except (CalibrationError, ValueError, FileNotFoundError) as e:
        _fail(str(e))
    save_camera(out, cam, CameraMount())
    print(report.summary() if hasattr(report, "summary") else report)
    console.print(f"wrote {out}")


@bench_app.command("render")
def bench_render(
    frames: int = typer.Option(60, help="frames to time after warm-up"),
    camera: str = typer.Option("omni-far", help="camera preset"),
    vehicles: int = typer.Option(30, help="vehicles on the highway"),
    renderer: list[str] = typer.Option(
        ["plane", "cube"], help="renderers to time, in one run (plane, cube)"
    ),
    face_px: int | None = typer.Option(None, help="cube-face size [px] (default per renderer)"),
    shadows: bool = typer.Option(False, help="vehicles cast shadows (plane renderer only)"),
    as_json: bool = typer.Option(False, "--json", help="print a JSON line last"),
) -> None:
    """Frames/s of the full omni frame production (render, ray map, ids, range, every
    sensor effect) of a highway, per renderer, with a breakdown by stage."""
    from sim.bench import bench_render as run
    from sim.machine import describe

    if shadows and renderer != ["plane"]:
        raise typer.BadParameter("--shadows needs --renderer plane alone", param_hint="--shadows")
    results = {}
    for name in renderer:
        res = run(
            n_frames=frames,
            camera=camera,
            vehicles=vehicles,
            renderer=name,
            face_px=face_px,
            shadows=shadows,
        )
        results[name] = res
        stages = ", ".join(f"{k} {v:.0f}" for k, v in res["stages_ms"].items())
        console.print(
            f"render ({name}{', shadows' if shadows else ''}, {res['face_px']} px faces): "
            f"{res['frames_per_s']:.2f} frames/s "
            f"({res['ms_per_frame']:.0f} ms/frame median, p90 {res['ms_p90']:.0f}, CPU "
            f"{res['cpu_ms_per_frame']:.0f} ms/frame, over {res['frames']} frames, "
            f"{res['width']}x{res['height']}, {res['vehicles']} vehicles; ms: {stages}; "
            f"on {describe(res['machine'])})"
        )
    if as_json:
        first = results[renderer[0]]
        print(json.dumps({**first, "renderers": results}))


@bench_app.command("fidelity")
def bench_fidelity_cmd(
    out: Path = typer.Option(Path("renders/bench/fidelity"), help="folder for the drives"),
    camera: str = typer.Option("omni-far", help="camera preset"),
    frames: int = typer.Option(40, help="frames per drive"),
    seed: int = typer.Option(11, help="highway-v0 seed of the drive"),
    as_json: bool = typer.Option(False, "--json", help="print a JSON line last"),
) -> None:
    """Motion fidelity of the renderers, without an estimator: road patches of consecutive
    frames against the exact plane-induced motion (scenarios/motion_fidelity.py). The row
    named exact is the measurement's own floor, on exact images of a synthetic road."""
    from scenarios.motion_fidelity import bench_fidelity

    res = bench_fidelity(out, camera=camera, frames=frames, seed=seed)
    for label, s in res.items():
        console.print(
            f"{label}: {s['patches']} patches, mean error along the motion "
            f"{s['mean_along_motion_px']:+.4f} px, RMS {s['rms_px']:.4f} px, median "
            f"{s['median_abs_px']:.4f} px (motion {s['mean_motion_px']:.1f} px/frame)"
        )
    if as_json:
        print(json.dumps(res))


def _register_extensions() -> None:
    """Commands that live in their own modules (suites, history, baselines)."""
    import importlib
    import importlib.util

    if importlib.util.find_spec("scenarios.cli_suite") is not None:
        importlib.import_module("scenarios.cli_suite").register(app)


def main() -> None:
    _register_extensions()
    try:
        app()
    except KeyboardInterrupt:
        console.print("interrupted: run the same command again to resume")
        sys.exit(130)


@app.command()
def run(
    scenario: str = typer.Argument(..., help="scenario name or path to a YAML file"),
    out: Path = typer.Option(..., "--out", help="output folder"),
    estimator: str = typer.Option(
        "direct", help="direct | can-only | features | a plug-in package.module:ClassName"
    ),
    frames: int | None = typer.Option(
        None, help="only the first N frames (the whole drive's first N, file for file)"
    ),
    road_mask: str | None = typer.Option(
        None, help="'gt': give the estimator the true road mask (a diagnostic ceiling)"
    ),
    detector: str = typer.Option(
        "hypotheses",
        help="surround detector: hypotheses | learned | paper (section 5 as written) | a plug-in "
        "package.module:ClassName",
    ),
    vehicle_mask: str | None = typer.Option(
        None, help="'gt': give the detector the true vehicle pixels (a diagnostic ceiling)"
    ),
    pixel_model: Path | None = typer.Option(
        None, help="--detector learned: a classifier file (omnibench train-pixels)"
    ),
) -> None:
    """Render (or reuse) a scenario, estimate ego-motion, write metrics.json and plots."""
    from estimator.egomotion.baselines import check_estimator
    from estimator.surround.plugin import check_detector, check_pixel_model

    try:  # the cheap inputs first: nothing is simulated or rendered for a bad one
        check_estimator(estimator)
        check_detector(detector)
        if frames is not None and frames < 1:
            raise ValueError(f"--frames {frames}: must be >= 1")
        if road_mask not in (None, "gt"):
            raise ValueError(f"--road-mask {road_mask!r}: the only choice is 'gt'")
        if vehicle_mask not in (None, "gt"):
            raise ValueError(f"--vehicle-mask {vehicle_mask!r}: the only choice is 'gt'")
        check_pixel_model(pixel_model, detector)
    except ValueError as e:
        _fail(str(e))

    from scenarios.config import ScenarioError, load_scenario
    from scenarios.runner import run_scenario
    from sim.drive import DriveError

    try:
        sc = load_scenario(scenario)
        m = run_scenario(
            sc,
            out,
            estimator=estimator,
            max_frames=frames,
            road_mask=road_mask,
            detector=detector,
            vehicle_mask=vehicle_mask,
            pixel_model=pixel_model,
        )
    except (ScenarioError, DriveError, ValueError) as e:
        _fail(str(e))
    e = m["ego"]
    console.print(
        f"{sc.name} [{estimator}] speed RMSE {e['speed_rmse_mps']:.3f} m/s "
        f"({e['speed_rmse_pct']:.2f} %, prior {e['prior_speed_rmse_mps']:.3f}), yaw-rate RMSE "
        f"{e['yaw_rate_rmse_dps']:.3f} deg/s (prior {e['prior_yaw_rate_rmse_dps']:.3f}), "
        f"A roll/pitch RMSE {e['angle_rmse_deg']:.3f} deg; "
        f"{m['timing']['estimate_ms_per_frame']:.1f} ms/frame -> {out}/metrics.json"
    )
    if e.get("frames_nonfinite"):
        console.print(
            f"[yellow]warning:[/yellow] {e['frames_nonfinite']} frame(s) with a NaN or infinite "
            f"estimate, left out of the RMSEs ({e['frames_compared']} frames compared)"
        )
    if math.isfinite(e.get("yaw_rate_rmse_exposure_dps", math.nan)):
        console.print(
            f"yaw-rate RMSE against the motion between the frames' exposure means (what the "
            f"blurred images show): {e['yaw_rate_rmse_exposure_dps']:.3f} deg/s"
        )
    pull = m.get("point_pull", {})
    if pull.get("pairs"):
        console.print(
            f"the images' pull at the true state: speed {pull['speed_pull_pct']:+.2f} %, yaw rate "
            f"{pull['yaw_rate_pull_dps']:+.3f} deg/s per pair (where: {out}/pull.png)"
        )


@app.command()
def evaluate(
    drive: Path = typer.Argument(..., help="a rendered drive folder (omnibench render, run)"),
    out: Path = typer.Option(..., "--out", help="output folder"),
    egomotion: Path | None = typer.Option(
        None, help="CSV with at least frame,speed_mps,yaw_rate_dps (docs/FORMATS.md)"
    ),
    tracks: Path | None = typer.Option(
        None, help="CSV with at least frame,track_id,x_m,y_m in the car frame (docs/FORMATS.md)"
    ),
) -> None:
    """Score ego-motion and tracks made by any program against a drive's ground truth."""
    from scenarios.evaluate import InputError, evaluate_drive

    try:
        m = evaluate_drive(drive, out, egomotion=egomotion, tracks=tracks)
    except (InputError, FileNotFoundError) as e:
        _fail(str(e))
    if "ego" in m:
        e = m["ego"]
        console.print(
            f"speed RMSE {e['speed_rmse_pct']:.2f} %, yaw rate RMSE "
            f"{e['yaw_rate_rmse_dps']:.3f} deg/s"
        )
    if "tracking" in m:
        t = m["tracking"]
        console.print(f"tracks: MOTA {t['mota']:.2f}, IDF1 {t['idf1']:.2f}, HOTA {t['hota']:.2f}")
    console.print(f"-> {out}/metrics.json, {out}/report.html")


@app.command("train-pixels")
def train_pixels_cmd(
    drives: list[Path] = typer.Argument(None, help="rendered drive folders (or --suite)"),
    out: Path = typer.Option(..., "--out", help="model file to write (.npz)"),
    suite: str | None = typer.Option(
        None, help="fit to this suite's drives (e.g. surround-train), rendered where missing"
    ),
    cache: Path = typer.Option(Path("renders/cache"), help="the suite's render cache"),
    every: int = typer.Option(4, help="sample one frame of this many"),
    progress: bool = typer.Option(True, help="show progress bars"),
) -> None:
    """Fit the learned detector's pixel classifier to rendered drives' id images."""
    from scenarios.suite import SuiteError
    from scenarios.train_pixels import TrainConfig, check_drive, suite_drives, train
    from sim.drive import DriveError

    try:
        cfg = TrainConfig(every=every)
        if bool(drives) == bool(suite):
            raise ValueError("give either drive folders or --suite")
        for d in drives or []:
            check_drive(d)
        dirs = suite_drives(suite, cache, progress) if suite else list(drives)
        model = train(dirs, out, cfg, progress, note=f"suite {suite}" if suite else "")
    except (ValueError, SuiteError, DriveError) as e:
        _fail(str(e))
    console.print(
        f"{len(dirs)} drive(s), {model.meta['n_samples']} pixels, loss "
        f"{model.meta['loss']:.4f} -> {out}"
    )


@app.command()
def export(
    drive: Path = typer.Argument(..., help="a rendered drive folder (omnibench render, run)"),
    format: str = typer.Option(..., "--format", help=" | ".join(EXPORT_FORMATS)),
    out: Path = typer.Option(..., "--out", help="output folder"),
    tracks: Path | None = typer.Option(
        None, help="with --format mot: a track file (tracks.csv) as TrackEval's tracker file"
    ),
) -> None:
    """Write a drive's ground truth in formats other tools read (docs/FORMATS.md)."""
    from scenarios.export import ExportError, export_drive

    try:
        files = export_drive(drive, format, out, tracks=tracks)
    except (ExportError, FileNotFoundError) as e:
        _fail(str(e))
    console.print(f"{len(files)} file(s) -> {out}")


@app.command()
def estimate(
    video: Path = typer.Argument(..., help="video file or folder of frames"),
    camera: str = typer.Option(..., help="camera YAML (intrinsics + mount) or a preset name"),
    can: Path = typer.Option(..., help="CAN CSV with columns t_s,speed_mps"),
    out: Path = typer.Option(..., "--out", help="output folder"),
    estimator: str = typer.Option(
        "direct", help="direct | can-only | features | a plug-in package.module:ClassName"
    ),
    timestamps: Path | None = typer.Option(None, help="CSV frame,t_s (default: from fps)"),
    fps: float | None = typer.Option(None, help="frame rate when the video has none"),
    road_masks: Path | None = typer.Option(
        None, help="folder of road-mask PNGs, one per frame (non-zero = road)"
    ),
    body_mask: Path | None = typer.Option(
        None,
        help="PNG of the camera's size, non-zero where it sees the car's own body: surround "
        "analysis then sees the road up to the body (default: the camera's body cone)",
    ),
    settings: list[str] = typer.Option(
        [],
        "--set",
        help="estimator setting KEY=VALUE (repeatable; dotted for nested, e.g. "
        "road_appearance=true, filter.A_tau_s=0.5; values in YAML)",
    ),
    surround: bool = typer.Option(
        True, help="also detect and track the vehicles around the car (section 5)"
    ),
    detector: str = typer.Option(
        "hypotheses",
        help="surround detector: hypotheses | learned | paper (section 5 as written) | a plug-in "
        "package.module:ClassName",
    ),
    pixel_model: Path | None = typer.Option(
        None, help="--detector learned: a classifier file (omnibench train-pixels)"
    ),
    write_video: bool = typer.Option(
        True, "--video/--no-video", help="write analysis.mp4 (the side-by-side panels)"
    ),
) -> None:
    """Estimate ego-motion of any recording, and detect and track the vehicles around the
    car; writes OUT/egomotion.csv, OUT/tracks.csv, pictures and OUT/report.html."""
    from estimator.camera.files import load_body_mask, load_camera
    from estimator.egomotion.baselines import check_estimator
    from estimator.pipeline import estimate_frames, write_egomotion_csv
    from estimator.recording import (
        RecordingError,
        count_frames,
        frame_times,
        iter_frames,
        iter_road_masks,
        read_can_csv,
        read_timestamps_csv,
        video_fps,
    )
    from estimator.surround.plugin import check_detector, check_pixel_model, make_surround

    recorder = None
    try:
        check_estimator(estimator)  # the cheap inputs first
        if surround:
            check_detector(detector)
            check_pixel_model(pixel_model, detector)
        given_times = frame_times(fps) if fps is not None else None
        config = parse_settings(settings)
        cam, mount = load_camera(camera)
        seen = cam.with_body_mask(load_body_mask(body_mask, cam)) if body_mask else cam
        can_track = read_can_csv(can)
        n_frames = count_frames(video)
        rate = None
        if timestamps is not None:
            times = read_timestamps_csv(timestamps)
        else:
            rate = video_fps(video) if given_times is None else None
            if given_times is None and rate is None:
                raise RecordingError(f"{video}: no frame rate known: give --fps or --timestamps")
            # one per frame, however many the recording has
            times = given_times if given_times is not None else frame_times(rate)
        if surround:
            from estimator.surround.detection import DetectorConfig
            from scenarios.surround_outputs import SurroundRecorder

            recorder = SurroundRecorder(
                make_surround(
                    detector, seen, mount, DetectorConfig(pixel_model=str(pixel_model or ""))
                ),
                detector,
                cam,
                mount,
                out,
                fps=_frame_rate(fps, rate, times),
                still_k=max(1, n_frames * 2 // 3) if n_frames else 1,
                video=write_video,
            )
        run = estimate_frames(
            iter_frames(video),
            times,
            can_track,
            cam,
            mount,
            estimator=estimator,
            progress=True,
            road_masks=iter_road_masks(road_masks) if road_masks is not None else None,
            n_frames=n_frames,
            on_frame=recorder.step if recorder is not None else None,
            **config,
        )
        out.mkdir(parents=True, exist_ok=True)
        write_egomotion_csv(out / "egomotion.csv", run.records, mount)
        if recorder is not None:
            recorder.finish(title=f"{Path(video).name} - {estimator}")
        _recording_report(out, str(video), camera, estimator, run, recorder, can_track)
    except (RecordingError, ValueError, FileNotFoundError) as e:
        _fail(str(e))
    finally:
        if recorder is not None:
            recorder.close()
    console.print(
        f"{len(run.records)} frames, {run.ms_per_frame:.1f} ms/frame -> {out}/egomotion.csv"
    )
    if recorder is not None:
        console.print(
            f"{recorder.n_tracks} vehicle tracks, {recorder.ms_per_frame:.1f} ms/frame "
            f"-> {out}/tracks.csv, {out}/surround.png"
            + (f", {out}/analysis.mp4" if write_video else "")
        )
    console.print(f"report: {out}/report.html")


def _recording_report(
    out: Path, name: str, camera: str, estimator: str, run, recorder, can_track
) -> None:
    """egomotion.png and report.html of a recording's analysis in out."""
    import numpy as np

    from scenarios.metrics import plot_egomotion, read_egomotion_csv
    from scenarios.report import write_recording_report

    ego = read_egomotion_csv(out / "egomotion.csv")
    can_at = np.array([can_track.at(t) for t in ego["t_s"]])
    known = np.isfinite(can_at)
    plot_egomotion(ego, can_at, out / "egomotion.png", title=f"{Path(name).name} - {estimator}")
    summary = {
        "recording": name,
        "camera": camera,
        "estimator": estimator,
        "frames": len(run.records),
        "duration_s": float(ego["t_s"][-1] - ego["t_s"][0]) if len(ego["t_s"]) else 0.0,
        "frames_images_not_used": int(np.sum(ego["degraded"] > 0)),
        "median_speed_mps": float(np.nanmedian(ego["speed_mps"])),
        "median_can_speed_mps": float(np.median(can_at[known])) if known.any() else math.nan,
        "estimate_ms_per_frame": run.ms_per_frame,
    }
    if recorder is not None:
        summary["detector"] = recorder.name
        summary["vehicle_tracks"] = recorder.n_tracks
        summary["detect_track_ms_per_frame"] = recorder.ms_per_frame
    write_recording_report(out, summary)


def _frame_rate(fps: float | None, rate: float | None, times) -> float:
    """Frames per second of a recording for its analysis video: the given rate, the
    video's, or the median step of its timestamps."""
    if fps is not None:
        return float(fps)
    if rate is not None:
        return float(rate)
    import numpy as np

    steps = np.diff(np.asarray(times, float))
    return 1.0 / float(np.median(steps)) if len(steps) else 10.0  # one frame: any rate


def parse_settings(pairs: list[str]) -> dict:
    """``["a.b=1", "c=true"]`` -> ``{"a": {"b": 1}, "c": True}`` (values parsed as YAML);
    ValueError naming the pair that is not KEY=VALUE or sets a key twice."""
    import yaml

    out: dict = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        parts = key.strip().split(".")
        if not sep or not all(p.strip() for p in parts):
            raise ValueError(f"--set {pair!r}: expected KEY=VALUE, e.g. road_appearance=true")
        try:
            value = yaml.safe_load(text) if text.strip() else None
        except yaml.YAMLError as e:
            raise ValueError(f"--set {pair!r}: value is not valid YAML ({e})") from None
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p.strip(), {})
            if not isinstance(node, dict):
                raise ValueError(f"--set {pair!r}: {p} is set to a value and a group")
        last = parts[-1].strip()
        if last in node:
            raise ValueError(f"--set {pair!r}: {key.strip()} is set twice")
        node[last] = value
    return out


def _one_core() -> None:
    """Pin this process to one CPU core (the speed targets are per core)."""
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):
        pass


@bench_app.command("estimate")
def bench_estimate(
    frames: int = typer.Option(40, help="frames to time after warm-up (rendered and synthetic)"),
    scenario: str = typer.Option(
        "highway-omni-near", help="library drive whose rendered frames are timed"
    ),
    camera: str = typer.Option("omni-near", help="camera preset of the synthetic road frames"),
    cache: Path | None = typer.Option(None, "--cache", help="render cache (default renders/cache)"),
    repeat: int = typer.Option(
        1, help="passes over the frames; each frame's fastest pass is kept (a shared machine)"
    ),
    as_json: bool = typer.Option(False, "--json", help="print a JSON line last"),
) -> None:
    """Median and p90 ms per frame of the direct estimator on one core: on rendered frames of a
    library drive (the headline), and on synthetic road frames (synthetic_* keys)."""
    from estimator.egomotion.bench import bench_direct
    from scenarios.benchmarks import bench_estimate as run_rendered
    from scenarios.config import ScenarioError
    from sim.drive import DriveError
    from sim.machine import describe

    if repeat < 1:
        _fail(f"--repeat must be 1 or more, got {repeat}")
    _one_core()
    try:
        res = run_rendered(scenario=scenario, n_frames=frames, cache_dir=cache, repeat=repeat)
        syn = bench_direct(camera_name=camera, n_frames=frames, repeat=repeat)
    except (ScenarioError, DriveError, ValueError) as e:
        _fail(str(e))
    res.update(
        {
            "synthetic_ms_per_frame": syn["ms_per_frame"],
            "synthetic_p90_ms_per_frame": syn["p90_ms_per_frame"],
            "synthetic_cpu_ms_per_frame": syn["cpu_ms_per_frame"],
            "synthetic_frames": syn["frames"],
            "synthetic_camera": camera,
        }
    )
    console.print(
        f"estimate (direct, {res['scenario']} rendered, {res['width']}x{res['height']}): "
        f"{res['ms_per_frame']:.1f} ms/frame median, {res['p90_ms_per_frame']:.1f} p90 "
        f"(CPU {res['cpu_ms_per_frame']:.1f} median) over {res['frames']} frames on one core"
        + (f" (each frame's fastest of {repeat} passes)" if repeat > 1 else "")
    )
    console.print(
        f"estimate (direct, synthetic road, {camera}): {syn['ms_per_frame']:.1f} ms/frame "
        f"median, {syn['p90_ms_per_frame']:.1f} p90 (CPU {syn['cpu_ms_per_frame']:.1f} median) "
        f"over {syn['frames']} frames; on {describe(res['machine'])}"
    )
    if as_json:
        print(json.dumps(res))


@bench_app.command("detect")
def bench_detect_cmd(
    frames: int | None = typer.Option(None, help="frames to time (default: the whole drive)"),
    camera: str = typer.Option("omni-near", help="camera preset"),
    scenario: str | None = typer.Option(
        None, help="the drive: a library name or a scenario file (default: the dense exit)"
    ),
    detector: str = typer.Option(
        "hypotheses", help="built-in surround detector: hypotheses | learned | paper"
    ),
    repeat: int = typer.Option(
        1, help="passes over the drive; each frame's fastest pass is kept (a shared machine)"
    ),
    as_json: bool = typer.Option(False, "--json", help="print a JSON line last"),
) -> None:
    """Median and p90 ms per frame of detection + tracking on one core (by default the
    dense exit: the library's densest traffic around the car)."""
    from estimator.surround.detection import DETECTOR_METHODS
    from scenarios.benchmarks import bench_detect
    from sim.machine import describe

    if detector not in DETECTOR_METHODS:
        _fail(f"--detector {detector!r}: choose one of {', '.join(DETECTOR_METHODS)}")
    if repeat < 1:
        _fail(f"--repeat must be 1 or more, got {repeat}")
    _one_core()
    res = bench_detect(
        camera=camera,
        n_frames=frames,
        detector=detector,
        repeat=repeat,
        **({"scenario": scenario} if scenario else {}),
    )
    console.print(
        f"detect+track ({camera}, {detector}): {res['ms_per_frame']:.1f} ms/frame median, "
        f"{res['p90_ms_per_frame']:.1f} p90 (CPU {res['cpu_ms_per_frame']:.1f}) over "
        f"{res['frames']} frames on one core"
        + (f" (each frame's fastest of {repeat} passes)" if repeat > 1 else "")
        + "; by stage (median): "
        + ", ".join(f"{k} {v:.1f}" for k, v in res["stages_ms"].items())
        + f" ms; on {describe(res['machine'])}"
    )
    if as_json:
        print(json.dumps(res))
