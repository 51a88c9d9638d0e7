"""One real end-to-end run: `omnibench run` on a short drive (render, estimate,
detect, track, metrics, pictures)."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

SCENARIO = {
    "name": "e2e-highway",
    "env": "highway-v0",
    "env_config": {"vehicles_count": 20, "lanes_count": 3},
    "seed": 7,
    "duration_s": 1.6,
    "fps": 15,
    "camera": {"preset": "omni-near", "width": 320, "height": 320},
    "can": {"speed_bias": 0.08, "speed_noise_mps": 0.3},
}


@pytest.mark.e2e
def test_omnibench_run_end_to_end(tmp_path: Path):
    sc = tmp_path / "e2e.yaml"
    sc.write_text(yaml.safe_dump(SCENARIO))
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "scenarios", "run", str(sc), "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 24
    for key in (
        "speed_rmse_mps",
        "speed_rmse_pct",
        "yaw_rate_rmse_dps",
        "yaw_rate_rmse_exposure_dps",  # the default sensor blurs over its exposure
        "angle_rmse_deg",
        "prior_speed_rmse_mps",
        "prior_yaw_rate_rmse_dps",
    ):
        assert math.isfinite(m["ego"][key]), key
    assert m["ego"]["speed_nees"] > 0 and m["ego"]["yaw_rate_nees"] > 0
    assert "exposure" in proc.stderr  # the diagnostic is printed beside the RMSEs (console)
    # the CAN prior is 8 % off: the images must pull the speed towards the truth
    assert m["ego"]["speed_rmse_mps"] < m["ego"]["prior_speed_rmse_mps"]
    assert set(m["detection"]) >= {"recall", "precision", "gt_count", "matched"}
    assert set(m["tracking"]) >= {"mota", "idf1", "hota", "id_switches"}
    assert set(m["localization"]) >= {
        "median_error_m", "p90_error_m", "centre_median_error_m", "centre_p90_error_m"
    }  # fmt: skip
    sur = m["surround"]  # where detection fails: every breakdown, for tracks and detections
    for part in ("tracks", "detections"):
        assert set(sur[part]) == {
            "range_bands", "sectors", "motion", "sizes", "unmatched", "ego_state"
        }  # fmt: skip
        bands = sur[part]["range_bands"]
        assert list(bands) == ["0-5 m", "5-10 m", "10-15 m", "15-25 m"]
        assert sum(b["gt_count"] for b in bands.values()) == m["detection"]["gt_count"]
        sizes = sur[part]["sizes"]  # every vehicle has its pixels from the id image
        assert list(sizes) == ["small", "medium", "large"]
        assert sum(b["gt_count"] for b in sizes.values()) == m["detection"]["gt_count"]
        assert sur[part]["ego_state"]["moving"]["frames"] >= 20
        u = sur[part]["unmatched"]  # every unmatched point is one of the three kinds
        assert u["unmatched"] == u["duplicate"] + u["misplaced"] + u["clutter"]
        assert u["hyp_count"] == sum(b["hyp_count"] for b in bands.values())
    cand = sur["candidates"]  # the detector's candidates, before the tracker
    assert list(cand["range_bands"]) == list(bands)
    assert cand["detection"]["gt_count"] == m["detection"]["gt_count"]
    assert cand["unmatched"]["hyp_count"] == cand["detection"]["hyp_count"] > 0
    assert 0.0 < cand["detection"]["recall"] <= 1.0
    assert "where vehicles are lost, stage by stage" in (out / "report.html").read_text()
    lost = sur["tracker"]  # what the candidates found and the tracks did not, by rule
    moving_cand = cand["ego_state"]["moving"]["detection"]
    assert lost["candidates_matched"] == moving_cand["matched"]  # the same matching
    assert lost["gt_count"] == moving_cand["gt_count"]
    assert lost["tracks_matched"] == sur["tracks"]["ego_state"]["moving"]["detection"]["matched"]
    assert lost["lost"] == sum(lost["lost_by_track_state"].values())
    # every candidate reaches the metric with its track's state (none refused: few tracks),
    # and a vehicle's first frames, before its track is one, are lost to the decision
    assert lost["lost_by_track_state"]["none"] == 0
    assert lost["lost_by_track_state"]["tentative"] + lost["lost_by_track_state"]["young"] > 0
    assert lost["lost"] - lost["tracks_only"] == lost["candidates_matched"] - lost["tracks_matched"]
    assert "what the candidates found and the tracks did not" in (out / "report.html").read_text()
    assert np.sum(sur["recall_polar"]["gt_count"]) == m["detection"]["gt_count"]
    state = sur["track_state"]  # the matched tracks' velocity, heading and NEES
    assert state["pairs"] == m["track_detection"]["matched"] > 0
    assert state["velocity"]["pairs"] == state["position_nees"]["pairs"] == state["pairs"]
    assert 0.0 <= state["velocity"]["median_error_mps"] < 10.0
    assert state["position_nees"]["mean"] > 0 and 0.0 <= state["heading"]["median_error_deg"] <= 90
    assert "the tracks' state against the truth" in (out / "report.html").read_text()
    assert "by motion relative to the ego car" in (out / "report.html").read_text()
    assert "by apparent size" in (out / "report.html").read_text()
    assert "what the unmatched track points are" in (out / "report.html").read_text()
    seg = sur["segmentation"]  # the motion mask against the true vehicle pixels
    assert seg["frames"] == 23 and seg["vehicle_px"] > 0 and seg["marked_px"] > 0
    assert 0.0 < seg["pixel_recall"] < 1.0 and 0.0 < seg["pixel_precision"] <= 1.0
    assert list(seg["range_bands"]) == list(bands)
    assert sum(b["vehicle_px"] for b in seg["range_bands"].values()) == seg["vehicle_px"]
    assert "the motion mask against the vehicles' pixels" in (out / "report.html").read_text()
    audit = m["points_above_road"]  # a highway with guard rails: some, not most
    assert audit["frames"] == 23 and audit["inliers"] > 0
    assert 0.0 <= audit["inlier_share"] < 0.5 and 0.0 <= audit["speed_info_share"] < 0.5
    assert "the images' pull at the true state" in proc.stdout + proc.stderr  # and pull.png
    pull = m["point_pull"]  # the images' pull at the true state: small on a highway
    assert pull["pairs"] >= 20 and abs(pull["speed_pull_pct"]) < 5.0
    assert math.isfinite(pull["yaw_rate_pull_dps"])
    assert sum(b["points_share"] for b in pull["by_range"].values()) == pytest.approx(1.0)
    for key in ("render_ms_per_frame", "estimate_ms_per_frame", "detect_track_ms_per_frame"):
        assert m["timing"][key] > 0
    for name in (
        "egomotion.csv",
        "tracks.csv",
        "ego_error.png",
        "tracks.png",
        "surround.png",
        "pull.png",
        "recall_polar.png",
        "segmentation.png",
        "analysis.mp4",
        "report.html",
        "drive/drive.mp4",
        "drive/groundtruth.jsonl",
    ):
        assert (out / name).stat().st_size > 0, name
    head = (out / "tracks.csv").read_text().splitlines()[0].split(",")
    assert head[:7] == ["frame", "t_s", "track_id", "x_m", "y_m", "vx_mps", "vy_mps"]
    assert {"var_x_m2", "cov_xy_m2", "var_y_m2"} <= set(head)
    assert head[-5:] == ["box_x_m", "box_y_m", "box_yaw_rad", "box_length_m", "box_width_m"]
    rows = (out / "egomotion.csv").read_text().splitlines()
    assert len(rows) == 25 and rows[0].startswith("frame,t_s,V_x")
    # a second run reuses the render: no frame is written again
    stamp = (out / "drive" / "frames" / "000010.png").stat().st_mtime_ns
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "drive" / "frames" / "000010.png").stat().st_mtime_ns == stamp


def test_run_reports_bad_scenario_clearly(tmp_path: Path):
    sc = tmp_path / "bad.yaml"
    sc.write_text("name: x\nfps: fast\n")
    proc = subprocess.run(
        [sys.executable, "-m", "scenarios", "run", str(sc), "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "fps" in proc.stderr and "bad.yaml" in proc.stderr
    assert not (tmp_path / "o" / "metrics.json").exists()
