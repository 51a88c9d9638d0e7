"""Scoring of result files made elsewhere (`omnibench evaluate`)."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scenarios.evaluate import (
    TRACK_BOX_COLUMNS,
    InputError,
    evaluate_drive,
    read_egomotion_input,
)
from scenarios.runner import gt_evaluation_set
from sim.drive import load_groundtruth

FRAMES = 20


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A short run of the library's highway drive (render, estimate, detect, track)."""
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    out = tmp_path_factory.mktemp("run")
    run_scenario(
        load_scenario("highway-omni-near"), out, max_frames=FRAMES, progress=False, video=False
    )
    return out


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flat(v, key + "."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[key] = float(v)
        elif isinstance(v, list) and all(isinstance(x, (int, float)) for x in np.ravel(v)):
            for i, x in enumerate(np.ravel(v)):
                out[f"{key}[{i}]"] = float(x)
    return out


def test_scoring_the_runs_own_files_gives_its_metrics(run_dir: Path, tmp_path: Path):
    """Every figure that both write agrees to 1e-9, ego and tracks."""
    m = evaluate_drive(
        run_dir / "drive",
        tmp_path,
        egomotion=run_dir / "egomotion.csv",
        tracks=run_dir / "tracks.csv",
    )
    ran = _flat(json.loads((run_dir / "metrics.json").read_text()))
    got = _flat(json.loads((tmp_path / "metrics.json").read_text()))
    shared = sorted(set(ran) & set(got) - {"frames"})
    assert len(shared) > 100
    sections = ("ego.", "tracking.", "track_detection.", "surround.tracks.", "surround.recall_")
    for section in sections:
        assert any(k.startswith(section) for k in shared), section
    for k in shared:
        a, b = ran[k], got[k]
        assert (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-9, (k, a, b)
    assert m["frames"] == FRAMES
    for name in ("report.html", "ego_error.png", "tracks.png", "recall_polar.png"):
        assert (tmp_path / name).stat().st_size > 0, name


def _estimate(drive: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    """`omnibench estimate` on a rendered drive's frames, as on a recording."""
    cmd = [
        sys.executable, "-m", "scenarios", "estimate", str(drive / "frames"),
        "--camera", str(drive / "camera.yaml"), "--can", str(drive / "can.csv"),
        "--timestamps", str(drive / "timestamps.csv"), "--out", str(out), *extra,
    ]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def test_a_recordings_surround_analysis_is_the_runs(run_dir: Path, tmp_path: Path):
    """`omnibench estimate` on the drive's frames, CAN and timestamps (no ground truth)
    writes the run's egomotion.csv and tracks.csv byte for byte, the pictures beside them,
    and the tracks score as the run's."""
    out = tmp_path / "rec"
    proc = _estimate(run_dir / "drive", out, "--no-video")
    assert proc.returncode == 0, proc.stderr[-2000:]
    for name in ("egomotion.csv", "tracks.csv"):
        assert (out / name).read_bytes() == (run_dir / name).read_bytes(), name
    assert len({row["track_id"] for row in csv.DictReader(open(out / "tracks.csv"))}) >= 1
    for name in ("tracks.png", "surround.png", "egomotion.png"):
        assert (out / name).stat().st_size > 0, name
    assert not (out / "analysis.mp4").exists()  # --no-video
    assert "vehicle tracks" in proc.stdout + proc.stderr
    page = (out / "report.html").read_text()
    n_tracks = len({row["track_id"] for row in csv.DictReader(open(out / "tracks.csv"))})
    assert f"<th>vehicle_tracks</th><td>{n_tracks}</td>" in page
    assert "<th>frames</th><td>20</td>" in page and "src='surround.png'" in page
    m = evaluate_drive(run_dir / "drive", tmp_path / "score", tracks=out / "tracks.csv")
    ran = json.loads((run_dir / "metrics.json").read_text())
    assert m["tracking"]["mota"] == ran["tracking"]["mota"]


def test_a_recordings_analysis_without_surround_or_with_a_bad_detector(
    run_dir: Path, tmp_path: Path
):
    """--no-surround: the ego-motion only (its file, picture and page); an unknown detector
    is named before any frame is read, and nothing is written."""
    proc = _estimate(run_dir / "drive", tmp_path / "ego", "--no-surround")
    assert proc.returncode == 0, proc.stderr[-2000:]
    names = sorted(p.name for p in (tmp_path / "ego").iterdir())
    assert names == ["egomotion.csv", "egomotion.png", "report.html"]
    assert "vehicle_tracks" not in (tmp_path / "ego" / "report.html").read_text()
    bad = _estimate(run_dir / "drive", tmp_path / "bad", "--detector", "nosuch")
    assert bad.returncode == 2 and "nosuch" in bad.stderr
    assert not (tmp_path / "bad").exists()


def test_tracks_made_from_the_truth_score_one(run_dir: Path, tmp_path: Path):
    """The evaluation set's vehicles at their footprint centres, one track per vehicle:
    recall, precision, MOTA, IDF1 and box HOTA 1.0, box-centre error 0."""
    drive = run_dir / "drive"
    gt = load_groundtruth(drive)
    path = tmp_path / "true_tracks.csv"
    n = 0
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "track_id", "x_m", "y_m", *TRACK_BOX_COLUMNS])
        for k in range(1, len(gt)):
            for g in gt_evaluation_set(gt[k], 25.0)[0]:
                fp = g.footprint_xy
                c, e1, e2 = fp.mean(axis=0), fp[1] - fp[0], fp[2] - fp[1]
                box = (c[0], c[1], math.atan2(e1[1], e1[0]), *np.hypot(*np.array([e1, e2]).T))
                w.writerow([k, g.id, *(f"{v:.6f}" for v in (c[0], c[1], *box))])
                n += 1
    assert n >= 10  # the highway drive has a car in range
    m = evaluate_drive(drive, tmp_path / "out", tracks=path)
    assert m["track_detection"]["recall"] == 1.0 and m["track_detection"]["precision"] == 1.0
    assert m["tracking"]["mota"] == 1.0 and m["tracking"]["idf1"] == 1.0
    assert m["tracking"]["hota_box"] == 1.0
    assert m["track_localization"]["centre_median_error_m"] < 1e-5
    assert "ego" not in m


def test_speed_and_yaw_rate_columns_alone_are_enough(run_dir: Path, tmp_path: Path):
    """Only frame,speed_mps,yaw_rate_dps: the same speed and yaw-rate RMSE (to the CSV's
    4 decimals), A's metrics NaN with the reason."""
    rows = list(csv.DictReader(open(run_dir / "egomotion.csv")))
    path = tmp_path / "rates.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "speed_mps", "yaw_rate_dps"])
        for r in rows:
            w.writerow([r["frame"], r["speed_mps"], r["yaw_rate_dps"]])
    m = evaluate_drive(run_dir / "drive", tmp_path / "out", egomotion=path)
    ran = json.loads((run_dir / "metrics.json").read_text())["ego"]
    assert m["ego"]["speed_rmse_mps"] == pytest.approx(ran["speed_rmse_mps"], abs=2e-4)
    assert m["ego"]["yaw_rate_rmse_dps"] == pytest.approx(ran["yaw_rate_rmse_dps"], abs=2e-4)
    assert math.isnan(m["ego"]["angle_rmse_deg"])
    assert "ego.angle_rmse_deg" in m["evaluation"]["nan_reasons"]


def _write(path: Path, header: str, lines: list[str]) -> Path:
    path.write_text("\n".join([header, *lines]) + "\n")
    return path


@pytest.mark.parametrize(
    ("lines", "match"),
    [
        (["0,1,0", "1,1,0", "1,1,0"], r"line 4: frame 1 again \(first on line 3\)"),
        (["0,1,0", "1,1,0", "2,nan,0"], r"line 4: speed_mps='nan' is not finite"),
        (["0,1,0", "1,1,0", "2,fast,0"], r"line 4: speed_mps='fast' is not a number"),
        (["0,1,0", "1,1,0", "7,1,0"], r"line 4: frame=7 is outside the drive's frames 0..4"),
        (["0,1,0", "1,1,0", "2,1,0"], r"no row for frame\(s\) 3, 4"),
    ],
)
def test_bad_egomotion_rows_are_named(tmp_path: Path, lines, match):
    path = _write(tmp_path / "ego.csv", "frame,speed_mps,yaw_rate_dps", lines)
    with pytest.raises(InputError, match=match) as e:
        read_egomotion_input(path, 5)
    assert str(path) in str(e.value)


def test_bad_inputs_are_refused_before_anything_is_written(run_dir: Path, tmp_path: Path):
    drive = run_dir / "drive"
    out = tmp_path / "out"
    bad_tracks = [
        ("frame,x_m,y_m", ["1,2,3"], r"missing column\(s\) \['track_id'\]"),
        ("frame,track_id,x_m,y_m", ["1,a,2,3"], r"line 2: track_id='a' is not an integer"),
        ("frame,track_id,x_m,y_m", ["1,-3,2,3"], r"track_id='-3' is not an integer >= 0"),
        ("frame,track_id,x_m,y_m", ["1,4,2,3", "1,4,5,6"], r"line 3: track 4 twice in frame 1"),
        ("frame,track_id,x_m,y_m", ["1,4,inf,3"], r"line 2: x_m='inf' is not finite"),
        ("frame,track_id,x_m,y_m", [f"{FRAMES},4,1,3"], rf"frame={FRAMES} is outside"),
    ]
    for header, lines, match in bad_tracks:
        path = _write(tmp_path / "t.csv", header, lines)
        with pytest.raises(InputError, match=match):
            evaluate_drive(drive, out, tracks=path)
    with pytest.raises(InputError, match="nothing to score"):
        evaluate_drive(drive, out)
    with pytest.raises(InputError, match="not a complete rendered drive"):
        evaluate_drive(tmp_path, out, tracks=run_dir / "tracks.csv")
    with pytest.raises(InputError, match="no such file"):
        evaluate_drive(drive, out, tracks=tmp_path / "none.csv")
    assert not out.exists()


def test_cli_evaluate_prints_the_figures_and_names_a_bad_file(run_dir: Path, tmp_path: Path):
    cmd = [sys.executable, "-m", "scenarios", "evaluate", str(run_dir / "drive")]
    ok = subprocess.run(
        [*cmd, "--out", str(tmp_path / "o"), "--egomotion", str(run_dir / "egomotion.csv")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert "speed RMSE" in ok.stderr and (tmp_path / "o" / "metrics.json").exists()
    bad = _write(tmp_path / "b.csv", "frame,track_id,x_m,y_m", ["1,1,2"])
    fail = subprocess.run(
        [*cmd, "--out", str(tmp_path / "p"), "--tracks", str(bad)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert fail.returncode == 2 and "b.csv, line 2: y_m=None is not a number" in fail.stderr


def _trackeval_mot(gt_folder: Path, trackers_folder: Path, out: Path) -> dict:
    """Stock TrackEval (Evaluator, MotChallenge2DBox, HOTA) on exported MOT files; its
    per-sequence HOTA results of the one tracker."""
    import trackeval

    evaluator = trackeval.Evaluator(
        {
            "USE_PARALLEL": False,
            "PRINT_RESULTS": False,
            "PRINT_CONFIG": False,
            "TIME_PROGRESS": False,
            "OUTPUT_SUMMARY": False,
            "OUTPUT_DETAILED": False,
            "PLOT_CURVES": False,
            "LOG_ON_ERROR": str(out / "trackeval_error.log"),
        }
    )
    dataset = trackeval.datasets.MotChallenge2DBox(
        {
            "GT_FOLDER": str(gt_folder),
            "TRACKERS_FOLDER": str(trackers_folder),
            "OUTPUT_FOLDER": str(out),
            "BENCHMARK": "omnibench",
            "SPLIT_TO_EVAL": "all",
            "SKIP_SPLIT_FOL": True,
            "DO_PREPROC": False,
            "PRINT_CONFIG": False,
        }
    )
    res, _ = evaluator.evaluate([dataset], [trackeval.metrics.HOTA()])
    (tracker,) = res["MotChallenge2DBox"]
    return {
        seq: r["pedestrian"]["HOTA"]
        for seq, r in res["MotChallenge2DBox"][tracker].items()
        if seq != "COMBINED_SEQ"
    }


def test_trackeval_on_the_mot_export_reproduces_the_box_hota(run_dir: Path, tmp_path: Path):
    """Stock TrackEval on the exported MOT ground truth and the run's tracks gives the
    run's tracking.hota_box (and DetA, AssA) to 1e-6; the run's tracks.mot.txt is the
    exported tracker file; one gt row per vehicle of the evaluation set per frame."""
    from scenarios.export import export_drive

    files = export_drive(
        run_dir / "drive", "mot", tmp_path, progress=False, tracks=run_dir / "tracks.csv"
    )
    seq = "highway-omni-near"
    tracker_file = tmp_path / "trackers" / "tracker" / "data" / f"{seq}.txt"
    assert tracker_file in files
    assert tracker_file.read_text() == (run_dir / "tracks.mot.txt").read_text()
    ran = json.loads((run_dir / "metrics.json").read_text())
    gt_rows = (tmp_path / "mot" / seq / "gt" / "gt.txt").read_text().splitlines()
    assert len(gt_rows) == ran["track_detection"]["gt_count"] > 0
    assert min(int(r.split(",")[0]) for r in gt_rows) >= 1
    ini = (tmp_path / "mot" / seq / "seqinfo.ini").read_text()
    assert f"seqLength={FRAMES - 1}" in ini
    hota = _trackeval_mot(tmp_path / "mot", tmp_path / "trackers", tmp_path / "te")[seq]
    t = ran["tracking"]
    assert 0.0 < t["hota_box"] < 1.0  # boxes that overlap, not perfectly
    for ours, theirs in (("hota_box", "HOTA"), ("deta_box", "DetA"), ("assa_box", "AssA")):
        assert abs(float(np.mean(hota[theirs])) - t[ours]) <= 1e-6, (ours, hota[theirs], t[ours])
