"""Suite outputs: thresholds, summary.json, junit.xml, TUM trajectories, recall bins,
and report.html opened in headless Chromium."""

import csv
import json
import math
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from estimator.fileio import read_png, write_png
from scenarios.suite import Threshold, suite_from_dict
from scenarios.suite_report import (
    Outcome,
    check_thresholds,
    recall_bins,
    write_junit,
    write_report,
    write_summary,
)
from scenarios.tum import integrate_planar, read_tum, relative_planar, tum_text

MAGENTA = (255, 0, 255)


# ------------------------------------------------------------------ thresholds
def test_thresholds_min_max_and_nan():
    th = {
        "detection.recall": Threshold(min=0.5),
        "ego.speed_rmse_pct": Threshold(max=5.0),
        "tracking.mota": Threshold(min=0.0, max=1.0),
        "tracking.idf1": Threshold(min=0.1),
    }
    m = {"detection.recall": 0.5, "ego.speed_rmse_pct": 7.0, "tracking.mota": math.nan}
    checks = {c["metric"]: c for c in check_thresholds(m, th)}
    assert checks["detection.recall"]["ok"]  # bounds are inclusive
    assert not checks["ego.speed_rmse_pct"]["ok"]
    assert not checks["tracking.mota"]["ok"] and checks["tracking.mota"]["value"] is None
    assert not checks["tracking.idf1"]["ok"]  # missing


def test_thresholds_per_estimator():
    t = Threshold(max=5.0, estimators=["direct"])
    assert t.applies_to("direct") and not t.applies_to("can-only")


# ------------------------------------------------------------------ TUM
def test_straight_line_and_circle_integrate_exactly():
    t = np.arange(0, 2.0001, 0.1)
    x, y, yaw = integrate_planar(t, np.full(len(t), 10.0), np.zeros(len(t)))
    np.testing.assert_allclose(x, 10 * t, atol=1e-12)
    np.testing.assert_allclose(y, 0, atol=1e-12)
    # constant speed and yaw rate: the mid-point rule is exact on chords of a circle
    # up to O(dt^2) per step; compare with the analytic arc r (sin wt, 1 - cos wt)
    v, w = 10.0, 0.5
    x, y, yaw = integrate_planar(t, np.full(len(t), v), np.full(len(t), w))
    r = v / w
    np.testing.assert_allclose(yaw, w * t, atol=1e-12)
    np.testing.assert_allclose(x, r * np.sin(w * t), atol=2e-3)
    np.testing.assert_allclose(y, r * (1 - np.cos(w * t)), atol=2e-3)


def test_non_finite_estimates_hold_the_last_value():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    x, _, _ = integrate_planar(t, np.array([5.0, 5.0, np.nan, 5.0]), np.zeros(4))
    np.testing.assert_allclose(x, [0, 5, 10, 15])


def test_relative_poses_start_at_the_origin():
    yaw0 = 0.7
    t = np.linspace(0, 1, 5)
    xw = 100 + 3 * t * np.cos(yaw0)
    yw = -50 + 3 * t * np.sin(yaw0)
    x, y, yaw = relative_planar(xw, yw, np.full(5, yaw0))
    np.testing.assert_allclose(x, 3 * t, atol=1e-12)
    np.testing.assert_allclose(y, 0, atol=1e-12)
    np.testing.assert_allclose(yaw, 0, atol=1e-12)


def test_tum_text_round_trip(tmp_path):
    t = np.array([0.0, 0.5])
    p = tmp_path / "a.tum"
    p.write_text(
        tum_text(t, np.array([0.0, 1.0]), np.array([0.0, 2.0]), np.array([0.0, np.pi / 2]))
    )
    rows = read_tum(p)
    assert rows.shape == (2, 8)
    np.testing.assert_allclose(rows[1, :4], [0.5, 1.0, 2.0, 0.0])
    np.testing.assert_allclose(rows[1, 4:], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 4:], axis=1), 1.0)


# ------------------------------------------------------------------ recall bins
def _gt_frame(k: int) -> dict:
    """Ego at the origin heading +x; one car 10-14.5 m ahead, 2 m wide (sim format)."""
    box = [[10.0, -1.0, 0], [14.5, -1.0, 0], [14.5, 1.0, 0], [10.0, 1.0, 0]] * 2
    return {
        "frame": k,
        "t_s": k / 15,
        "ego": {"x_m": 0.0, "y_m": 0.0, "yaw_rad": 0.0},
        "T_world_cam_nominal": np.eye(4).tolist(),
        "vehicles": [{"id": 3, "box_world_m": box, "visible_px": 500}],
    }


def test_recall_bins_from_tracks(tmp_path):
    gt = [_gt_frame(k) for k in range(4)]
    tracks = tmp_path / "tracks.csv"
    with open(tracks, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "t_s", "track_id", "x_m", "y_m", "vx_mps", "vy_mps"])
        w.writerow([1, 0.0667, 1, 10.0, 0.0, 0, 0])
        w.writerow([2, 0.1333, 1, 10.1, 0.0, 0, 0])
    bins = recall_bins(gt, tracks, {"evaluation": {"max_range_m": 25.0, "gate_m": 1.5}})
    assert bins["frames"] == 3  # frame 0 has no motion to detect with
    r = bins["range"]
    assert r["bin_edges"] == [0, 5, 10, 15, 20, 25]
    assert r["gt_count"] == [0, 0, 3, 0, 0] and r["matched"] == [0, 0, 2, 0, 0]
    b = bins["bearing"]
    i = b["bin_edges"].index(0)
    assert b["gt_count"][i] == 3 and b["matched"][i] == 2


# ------------------------------------------------------------------ summary, junit, report
def _synthetic(tmp_path: Path):
    """A 3-job suite (one failing a threshold, one erroring) with fake job folders."""
    suite = suite_from_dict(
        {
            "name": "synthetic",
            "scenarios": ["highway-omni-near"],
            "estimators": ["direct", "can-only", "features"],
            "overrides": {"can.speed_bias": [0.0, 0.1]},
            "frames": 5,
            "thresholds": {"ego.speed_rmse_pct": {"max": 5.0}},
        },
        where="synthetic.yaml",
    )
    outcomes = []
    rng = np.random.default_rng(0)
    for i, job in enumerate(suite.jobs):
        jdir = tmp_path / job.describe()["dir"]
        jdir.mkdir(parents=True)
        if job.estimator == "features" and job.overrides["can.speed_bias"] > 0:
            outcomes.append(
                Outcome(job, "error", error="RuntimeError: boom", traceback="Traceback\nboom")
            )
            continue
        still = np.zeros((120, 360, 3), np.uint8)
        still[:] = MAGENTA
        write_png(jdir / "surround.png", still)
        (jdir / "report.html").write_text("<html></html>")
        rmse = 2.0 + 2.0 * i + rng.uniform(0, 0.1)
        metrics = {
            "ego.speed_rmse_pct": rmse,
            "ego.yaw_rate_rmse_dps": 0.5,
            "detection.recall": 0.7,
            "tracking.mota": 0.4,
            "detection.precision": math.nan,
        }
        o = Outcome(job, "ok", metrics, wall_s=1.0 + i)
        o.checks = check_thresholds(metrics, suite.thresholds_for(job))
        outcomes.append(o)
    return suite, outcomes


def test_summary_and_junit(tmp_path):
    suite, outcomes = _synthetic(tmp_path)
    data = write_summary(tmp_path, suite, {"run_id": "r1"}, outcomes)
    text = (tmp_path / "summary.json").read_text()
    strict = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert strict["counts"] == data["counts"]
    c = data["counts"]
    assert (c["jobs"], c["error"], c["ok"]) == (6, 1, 5)
    assert c["failed_thresholds"] == sum(
        1 for o in outcomes if o.status == "ok" and o.metrics["ego.speed_rmse_pct"] > 5
    )
    job0 = strict["jobs"][0]
    assert job0["metrics"]["detection.precision"] is None
    assert {"job_id", "label", "scenario", "camera", "estimator", "seed", "overrides"} <= set(job0)

    write_junit(tmp_path, suite, outcomes, "2026-01-01T00:00:00+00:00")
    root = ET.parse(tmp_path / "junit.xml").getroot()
    ts = root.find("testsuite")
    cases = ts.findall("testcase")
    assert len(cases) == 6
    assert int(ts.get("errors")) == 1 and int(ts.get("failures")) == c["failed_thresholds"]
    failed = [tc for tc in cases if tc.find("failure") is not None]
    assert all("ego.speed_rmse_pct" in tc.find("failure").get("message") for tc in failed)
    errored = [tc for tc in cases if tc.find("error") is not None]
    assert "boom" in errored[0].find("error").get("message")


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _chromium_args(tmp_path: Path) -> list[str]:
    return [
        _chromium(), "--headless", "--no-sandbox", "--disable-gpu",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--no-first-run", f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ]  # fmt: skip


@pytest.mark.skipif(
    _chromium() is None,
    reason="chromium is not installed (apt-get install -y chromium; `make test` does it)",
)
def test_report_opens_in_headless_chromium(tmp_path):
    suite, outcomes = _synthetic(tmp_path)
    write_summary(tmp_path, suite, {"run_id": "r1"}, outcomes)
    write_junit(tmp_path, suite, outcomes, "2026-01-01T00:00:00+00:00")
    page = write_report(tmp_path, suite, {"run_id": "r1"}, outcomes, lambda job: tmp_path / "none")
    assert (tmp_path / "plots" / "estimators.png").exists()
    assert (tmp_path / "plots" / "sweep_00.png").exists()
    url = page.resolve().as_uri()

    dom = subprocess.run(
        [*_chromium_args(tmp_path), "--dump-dom", url], capture_output=True, text=True, timeout=120
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    html = dom.stdout
    table = re.search(r"<table id=\"metrics\">(.*?)</table>", html, re.S)
    assert table, html[:2000]
    assert len(re.findall(r"<tr class=\"(ok|error)\">", table.group(1))) == 6
    assert "error: RuntimeError: boom" in table.group(1)
    srcs = re.findall(r"<img src=\"([^\"]+)\"", html)
    assert any(s.startswith("plots/") for s in srcs)
    assert sum("surround.png" in s for s in srcs) == 5
    for s in srcs:
        assert (tmp_path / s).is_file(), s  # relative links that resolve from disk

    shot = tmp_path / "shot.png"
    proc = subprocess.run(
        [*_chromium_args(tmp_path), "--window-size=1400,5000", f"--screenshot={shot}", url],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0 and shot.exists(), proc.stderr[-2000:]
    img = read_png(shot)[..., :3].astype(int)
    # the stills (solid magenta) and the plots (matplotlib's default blue bars) were drawn
    magenta = np.all(np.abs(img - MAGENTA) <= 8, axis=-1).sum()
    assert magenta > 5 * 100 * 100, magenta
    blue = np.all(np.abs(img - (31, 119, 180)) <= 12, axis=-1).sum()
    assert blue > 500, blue


def test_recall_around_the_car_is_pooled_per_camera_estimator_and_detector(tmp_path):
    """Two drives' polar grids add up in one picture per camera x estimator x detector;
    a job without vehicles adds nothing."""
    from scenarios.suite_report import plot_recall_polar_pooled, pool_recall_polar

    suite = suite_from_dict(
        {
            "name": "s",
            "scenarios": ["highway-omni-near", "merge-omni-near"],
            "detectors": ["hypotheses", "paper"],
            "frames": 5,
        },
        where="s.yaml",
    )
    outcomes = []
    for job in suite.jobs:
        jdir = tmp_path / job.describe()["dir"]
        jdir.mkdir(parents=True)
        seen = 2 if job.scenario.name.startswith("highway") else 3
        polar = {
            "range_edges_m": [0.0, 5.0, 10.0],
            "bearing_edges_deg": [-180.0, 0.0, 180.0],
            "gt_count": [[seen, 0], [0, 4]],
            "matched": [[1, 0], [0, 4]],
        }
        (jdir / "metrics.json").write_text(json.dumps({"surround": {"recall_polar": polar}}))
        outcomes.append(Outcome(job, "ok", {}))
    pooled = pool_recall_polar(tmp_path, outcomes)
    assert set(pooled) == {("omni-near", "direct", "hypotheses"), ("omni-near", "direct", "paper")}
    for grid in pooled.values():
        assert grid["gt_count"].tolist() == [[5, 0], [0, 8]]
        assert grid["matched"].tolist() == [[2, 0], [0, 8]]
    made = plot_recall_polar_pooled(tmp_path, outcomes)
    assert len(made) == 2 and all((tmp_path / name).stat().st_size > 0 for name, _ in made)
    assert "paper" in made[1][1] and "hypotheses" in made[0][1]
