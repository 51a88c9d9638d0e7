"""`omnibench run`: render (or reuse) a drive, estimate ego-motion, detect and
track vehicles, and measure everything against ground truth.

Writes into ``out/``: ``drive/`` (the render, see sim.drive), ``egomotion.csv``,
``tracks.csv``, ``tracks.mot.txt`` (the tracks with a box as MOTChallenge rows,
`scenarios.mot`; none when no track has a box), ``ego_error.png``, ``tracks.png``,
``surround.png`` (a still of the side-by-side panels), ``segmentation.png`` (the
built-in detectors' motion mask of that frame against the vehicles' true pixels,
`scenarios.segmentation`), ``analysis.mp4`` (the side-by-side video), ``report.html``
and ``metrics.json`` (written last).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.egomotion.baselines import check_estimator, make_estimator
from estimator.egomotion.homography import homography, make_state
from estimator.fileio import write_json, write_png
from estimator.geometry import rot_z
from estimator.pipeline import write_egomotion_csv
from estimator.progress import track
from estimator.recording import iter_frames, read_can_csv, read_timestamps_csv
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DEFAULT_DETECTOR, DETECTOR_METHODS, DetectorConfig
from estimator.surround.plugin import check_detector, check_pixel_model, make_surround
from scenarios import visualize as viz
from scenarios.config import Scenario
from scenarios.detection_metrics import (
    EGO_MOVING_MPS,
    EvalFrame,
    GtVehicle,
    MetricsConfig,
    breakdown,
    evaluate,
    motion_class,
)
from scenarios.evaluate import read_tracks_input, track_frames, track_sections
from scenarios.metrics import (
    ego_consistency,
    ego_metrics,
    ego_series,
    plot_ego_errors,
    read_egomotion_csv,
)
from scenarios.mot import write_tracks as write_mot_tracks
from scenarios.point_audit import (
    PullMap,
    camera_unit_rays,
    gt_road_mask,
    gt_vehicle_ids,
    points_above_road,
)
from scenarios.report import write_run_report
from scenarios.road_residual import road_residuals
from scenarios.segmentation import SegmentationAudit
from scenarios.surround_outputs import SurroundRecorder, box_centres
from scenarios.tracker_losses import tracker_losses
from sim.drive import load_groundtruth, render_drive

VISIBLE_PX_MIN = 50  # a ground-truth vehicle is in the evaluation set from this many pixels
GATE_M = 1.5  # a detection matches a vehicle within this distance of its footprint [m]


def ego_road_frame(gt_frame: dict) -> tuple[np.ndarray, np.ndarray]:
    """(R_world_ego (2, 2), origin (2,)) of the ego road frame of a GT record."""
    T = np.asarray(gt_frame["T_world_cam_nominal"])
    yaw = gt_frame["ego"]["yaw_rad"]
    return rot_z(yaw)[:2, :2], T[:2, 3]


def vehicle_footprint(gt_frame: dict, vehicle: dict) -> np.ndarray:
    """(4, 2) footprint corners [m] of a GT record's vehicle in the ego road frame."""
    R, o = ego_road_frame(gt_frame)
    box = np.asarray(vehicle["box_world_m"])[:4, :2]  # bottom corners (sim.scene convention)
    return (box - o) @ R  # R^T (p - o)


def gt_evaluation_set(gt_frame: dict, max_range_m: float) -> tuple[list[GtVehicle], np.ndarray]:
    """Vehicles visible (>= VISIBLE_PX_MIN px) within max_range_m, as footprints in the
    ego road frame with their motion relative to the ego car (`motion_class`), their
    velocity over the ground in its axes (speed along the heading) and the pixels they
    cover; also
    (N, 2) all their footprint centres (for drawing)."""
    ego = gt_frame["ego"]
    R, _ = ego_road_frame(gt_frame)
    out, centres = [], []
    for v in gt_frame["vehicles"]:
        foot = vehicle_footprint(gt_frame, v)
        centres.append(foot.mean(axis=0))
        if v["visible_px"] < VISIBLE_PX_MIN:
            continue
        if _polygon_distance(np.zeros(2), foot) > max_range_m:
            continue
        motion = (  # "" (unknown) for a record without the vehicles' motion
            motion_class(v["speed_mps"], v["yaw_rad"], ego["speed_mps"], ego["yaw_rad"])
            if "speed_mps" in v and "speed_mps" in ego
            else ""
        )
        velocity = np.full(2, np.nan)  # over the ground, ego road axes [m/s]
        if "speed_mps" in v and "yaw_rad" in v:
            heading = np.array([np.cos(v["yaw_rad"]), np.sin(v["yaw_rad"])])
            velocity = R.T @ (v["speed_mps"] * heading)
        out.append(GtVehicle(int(v["id"]), _convex_order(foot), motion, velocity, v["visible_px"]))
    return out, np.array(centres).reshape(-1, 2)


def _convex_order(pts: np.ndarray) -> np.ndarray:
    c = pts.mean(axis=0)
    ang = np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0])
    return pts[np.argsort(ang)]


def _polygon_distance(p: np.ndarray, poly: np.ndarray) -> float:
    from scenarios.detection_metrics import point_footprint_distance

    return float(
        np.asarray(point_footprint_distance(p.reshape(1, 2), _convex_order(poly))).ravel()[0]
    )


def run_scenario(
    scenario: Scenario,
    out_dir: Path,
    estimator: str = "direct",
    drive_dir: Path | None = None,
    progress: bool = True,
    max_frames: int | None = None,
    video: bool = True,
    road_mask: str | None = None,
    detector: str = DEFAULT_DETECTOR,
    vehicle_mask: str | None = None,
    pixel_model: Path | str | None = None,
) -> dict:
    """Render (resuming), estimate, detect, track and measure one scenario.

    road_mask: ``"gt"`` gives the estimator each frame's true road mask (what lies
    within ``MIN_HEIGHT_M`` of the road, from the range images): the speed it then
    reaches is what a perfect road segmentation would allow, a diagnostic ceiling.
    detector: the surround detector, `DetectorConfig.method` ("hypotheses", "learned", "paper"),
    or a plug-in (`estimator.surround.plugin`); pixel_model: the "learned" detector's
    classifier file (None: the built-in one).
    vehicle_mask: ``"gt"`` gives the detector each frame's true vehicle pixels (id
    images) instead of its motion test: the figures it then reaches are what the plan
    view, the obstacle map and the tracker allow with a perfect segmentation, a
    diagnostic ceiling.
    The cheap inputs (estimator, max_frames, road_mask, detector, vehicle_mask,
    pixel_model) are checked before any rendering.
    """
    check_estimator(estimator)
    check_detector(detector)
    if vehicle_mask is not None and detector not in DETECTOR_METHODS:
        raise ValueError(
            f"vehicle_mask is for the built-in detectors, not the plug-in {detector!r}"
        )
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be >= 1 (or None: every frame), got {max_frames}")
    if road_mask not in (None, "gt"):
        raise ValueError(f"road_mask must be 'gt' or None, got {road_mask!r}")
    if vehicle_mask not in (None, "gt"):
        raise ValueError(f"vehicle_mask must be 'gt' or None, got {vehicle_mask!r}")
    check_pixel_model(pixel_model, detector)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    drive_dir = Path(drive_dir) if drive_dir is not None else out_dir / "drive"
    drive = render_drive(scenario, drive_dir, progress=progress, max_frames=max_frames)
    gt = load_groundtruth(drive_dir)
    camera, mount = load_camera(drive_dir / "camera.yaml")
    times = read_timestamps_csv(drive_dir / "timestamps.csv")
    can = read_can_csv(drive_dir / "can.csv")
    det_cfg = replace(
        DetectorConfig(),
        max_range_m=scenario.detection_range_m,
        pixel_model=str(pixel_model or ""),
    )
    est = make_estimator(estimator, camera, mount)
    # surround analysis sees the road up to the car body's silhouette
    surround = make_surround(detector, with_folder_body_mask(camera, drive_dir), mount, det_cfg)
    # built-in analyzers have a motion mask (scored against the vehicles' true pixels) and
    # candidates that carry their track's state (the tracker's losses)
    builtin = isinstance(surround, SurroundAnalyzer)
    audit = SegmentationAudit(surround.detector.analysed_area) if builtin else None
    unit_rays = camera_unit_rays(camera) if road_mask else None
    pull = PullMap(camera, mount)  # where the images pull the estimate off the truth
    still_image = None
    records, eval_det, eval_cand, t_est = [], [], [], []
    cand_states, cand_k = [], []  # each candidate's track state, and the frame, per frame
    still_k = min(len(gt) - 1, max(1, len(gt) * 2 // 3))
    # tracks.csv, tracks.png, surround.png and analysis.mp4, as for a recording
    recorder = SurroundRecorder(
        surround, detector, camera, mount, out_dir, scenario.fps, still_k, video
    )
    frames = iter_frames(drive_dir / "frames")
    try:
        for k, image in track(
            enumerate(frames), len(gt), f"analyse {scenario.name} ({estimator})", progress
        ):
            t = float(times[k])
            given = gt_road_mask(drive_dir, k, unit_rays, gt[k]) if road_mask else None
            t0 = time.perf_counter()  # the estimator's time, without the truth's mask
            # (a plug-in's step may take no road mask: passed only when there is one)
            masks = {"road_mask": given} if given is not None else {}
            rec = est.step(image, t, can.at(t), **masks)
            t1 = time.perf_counter()
            ids = gt_vehicle_ids(drive_dir, k) if vehicle_mask or audit is not None else None
            vmask = ids > 0 if vehicle_mask else None
            gt_set, _ = gt_evaluation_set(gt[k], det_cfg.max_range_m)
            # (the detector's time, without the truth's mask: the recorder's)
            sf = recorder.step(
                k,
                t,
                image,
                rec,
                vehicle_mask=vmask,
                gt_xy=np.array([g.footprint_xy.mean(axis=0) for g in gt_set]),
            )
            if k > 0:
                t_est.append(t1 - t0)
            records.append(rec)
            truth = gt[k]["motion_from_prev"]
            if truth is not None and hasattr(est, "point_pull"):  # (None on frame 0)
                x_true = make_state(truth["V_mps"], truth["W_rps"], truth["A_rad"])
                pull.add(est.point_pull(x_true))
            if k == still_k:
                still_image = image
            if sf is None:
                continue
            if audit is not None:
                audit.add(sf.detection.motion_mask, ids, gt_set)
                if k == still_k:
                    write_png(
                        out_dir / "segmentation.png",
                        viz.segmentation_picture(
                            image, sf.detection.motion_mask, ids > 0, audit.area
                        ),
                    )
            moving = gt[k]["ego"]["speed_mps"] > EGO_MOVING_MPS
            dets = [(i, d.x_m, d.y_m) for i, d in enumerate(sf.detection.detections)]
            det_boxes = [d.box for d in sf.detection.detections]
            eval_det.append(EvalFrame(gt_set, dets, t, moving, box_centres(det_boxes)))
            cands = [(i, d.x_m, d.y_m) for i, d in enumerate(sf.detection.candidates)]
            eval_cand.append(EvalFrame(gt_set, cands, t, moving))
            cand_states.append([d.track_state for d in sf.detection.candidates])
            cand_k.append(k)
        recorder.finish(title=f"{scenario.name} - {estimator}")
    finally:
        recorder.close()
    write_egomotion_csv(out_dir / "egomotion.csv", records, mount)
    sensor = scenario.sensor
    series = ego_series(
        read_egomotion_csv(out_dir / "egomotion.csv"),
        gt,
        mount,
        exposure_s=sensor.exposure_s if sensor.motion_blur else 0.0,
    )
    plot_ego_errors(series, out_dir / "ego_error.png", title=f"{scenario.name} - {estimator}")
    est_H = {
        r.frame: homography(np.asarray(r.x, float), mount.K0, r.dt_s)
        for r in records
        if r.dt_s > 0 and np.all(np.isfinite(r.x))
    }
    every = max(1, len(gt) // 20)  # ~20 frames are enough for a median
    compensation = road_residuals(
        drive_dir, camera, mount, gt, est_H, frames=list(range(1, len(gt), every))
    )
    mcfg = MetricsConfig(gate_m=GATE_M)
    det_m = evaluate(eval_det, mcfg)
    # the tracks are scored from tracks.csv as written, as `omnibench evaluate` scores them
    trk_frames = track_frames(
        read_tracks_input(out_dir / "tracks.csv", len(gt)), gt, det_cfg.max_range_m
    )
    write_mot_tracks(trk_frames, out_dir / "tracks.mot.txt")
    trk = track_sections(trk_frames, mcfg, det_cfg.max_range_m)
    # which rule of the tracker lost what the candidates found (built-in analyzers: their
    # candidates carry their track's state); trk_frames[k - 1] is frame k
    cand_tracks = [trk_frames[k - 1] for k in cand_k]
    losses = (
        {"tracker": tracker_losses(eval_cand, cand_states, cand_tracks, mcfg)} if builtin else {}
    )
    viz.plot_recall_polar(
        trk["surround"]["recall_polar"],
        out_dir / "recall_polar.png",
        f"{scenario.name} - {estimator}: track recall",
    )
    manifest = json.loads((drive_dir / "manifest.json").read_text())
    metrics = {
        "scenario": scenario.name,
        "camera": scenario.camera if isinstance(scenario.camera, str) else "inline",
        "estimator": estimator,
        "detector": detector,
        "road_mask": road_mask or "none",
        "vehicle_mask": vehicle_mask or "none",
        "frames": drive.n_frames,
        "ego": {**ego_metrics(series), **ego_consistency(records, gt, mount)},
        "detection": det_m["detection"],
        "tracking": trk["tracking"],
        "localization": det_m["localization"],
        "track_detection": trk["track_detection"],
        "track_localization": trk["track_localization"],
        "surround": {
            "candidates": breakdown(eval_cand, mcfg, tracked=False),
            "detections": breakdown(eval_det, mcfg),
            **trk["surround"],
            **losses,
            **({"segmentation": audit.result()} if audit is not None else {}),
        },
        "compensation": compensation,
        "points_above_road": points_above_road(drive_dir, camera, gt, records),
        "point_pull": _point_pull(pull, series, out_dir / "pull.png", still_image),
        "evaluation": {
            "gate_m": GATE_M,
            "visible_px_min": VISIBLE_PX_MIN,
            "max_range_m": det_cfg.max_range_m,
            "nan_reasons": {**det_m.get("nan_reasons", {}), **trk["nan_reasons"]},
        },
        "timing": {
            "render_ms_per_frame": manifest.get("render_ms_per_frame"),
            "estimate_ms_per_frame": _median_ms(t_est),
            "detect_track_ms_per_frame": recorder.ms_per_frame,
        },
    }
    write_run_report(out_dir, metrics)
    write_json(out_dir / "metrics.json", metrics)  # last: its presence marks a finished run
    return metrics


def _point_pull(pull: PullMap, series: dict, png: Path, image) -> dict:
    """metrics.json's "point_pull" section (`PullMap.summary`: NaN, with the reason, when
    no pair told its pull) and its picture ``png`` over ``image``."""
    summary = pull.summary(float(np.nanmean(series["speed_gt"])))
    if not pull.pairs:
        summary["nan_reason"] = "no frame pair told its pull (the estimator cannot, or no fit)"
    elif image is not None:
        pull.write_png(png, image)
    return summary


def _median_ms(ts: list[float]) -> float:
    return 1000.0 * float(np.median(ts)) if ts else float("nan")
