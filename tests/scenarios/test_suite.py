"""Suite files (validation, expansion, job ids, render keys) and one real suite run."""

import json
import math
import sqlite3
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from scenarios.suite import (
    SuiteError,
    check_override_key,
    code_version,
    load_suite,
    set_dotted,
    suite_from_dict,
)

TINY_CAMERA = {"preset": "omni-near", "width": 256, "height": 256}


def _suite(tmp_path: Path, **data) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(
        yaml.safe_dump({"name": "t", "scenarios": ["highway-omni-near"], **data}, sort_keys=False)
    )
    return p


# ------------------------------------------------------------------ shipped suites
@pytest.mark.parametrize(
    "name, jobs, drives",
    [
        ("smoke", 24, 8),
        ("paper", 12, 6),
        ("full", 45, 15),
        ("can-bias-sweep", 14, 7),
        ("validation-omni", 12, 6),
        ("validation-rect", 8, 8),
        ("check-rect", 8, 4),
        ("check-omni", 20, 10),
        ("surround-tune", 30, 10),
        ("surround-check", 30, 10),
        ("surround-shadows", 30, 10),
        ("surround-tune-shadows", 30, 10),
        ("surround-train", 10, 10),
        ("library-detectors", 20, 10),
    ],
)
def test_shipped_suites_load(name, jobs, drives):
    s = load_suite(name)
    assert s.name == name
    assert len(s.jobs) == jobs
    assert len({j.render_key for j in s.jobs}) == drives
    assert len({j.job_id for j in s.jobs}) == jobs
    assert s.spec.role in ("tuning", "check", "regression", "training")


@pytest.mark.parametrize(
    "plain, shaded",
    [("surround-check", "surround-shadows"), ("surround-tune", "surround-tune-shadows")],
)
def test_the_shadows_suites_are_their_surround_suites_with_shadows(plain, shaded):
    """The same drives and jobs, each with shadows: other renders."""
    check, shadows = load_suite(plain), load_suite(shaded)
    assert check.spec.role == shadows.spec.role
    assert all(j.scenario.shadows for j in shadows.jobs)
    assert not any(j.scenario.shadows for j in check.jobs)
    strip = [j.scenario.model_copy(update={"shadows": False}) for j in shadows.jobs]
    assert strip == [j.scenario for j in check.jobs]
    assert not {j.render_key for j in check.jobs} & {j.render_key for j in shadows.jobs}


def test_shipped_suite_names_match_their_role():
    """A suite named validation-* chose settings (tuning); check-* did not."""
    for name in ("validation-omni", "validation-rect", "check-rect", "check-omni"):
        assert load_suite(name).spec.role == name.split("-")[0].replace("validation", "tuning")


def test_unknown_suite_role_is_an_error_naming_it(tmp_path):
    p = tmp_path / "s.yaml"
    p.write_text("name: s\nrole: held-out\nscenarios: [highway-omni-near]\n")
    with pytest.raises(SuiteError, match="role"):
        load_suite(p)


def test_smoke_suite_is_short():
    s = load_suite("smoke")
    assert all(j.frames <= 30 for j in s.jobs)
    assert {j.estimator for j in s.jobs} == {"direct", "can-only", "features"}


def test_can_bias_sweep_spans_minus_to_plus_15_percent():
    s = load_suite("can-bias-sweep")
    biases = sorted({j.scenario.can.speed_bias for j in s.jobs})
    assert biases[0] == pytest.approx(-0.15) and biases[-1] == pytest.approx(0.15)
    assert s.spec.swept_keys() == ["can.speed_bias"]


# ------------------------------------------------------------------ expansion
def test_detectors_are_a_job_axis_and_the_default_keeps_its_job_ids(tmp_path):
    plain = load_suite(_suite(tmp_path, frames=10))
    both = load_suite(_suite(tmp_path, frames=10, detectors=["hypotheses", "paper"]))
    assert [j.detector for j in both.jobs] == ["hypotheses", "paper"]
    assert both.jobs[0].job_id == plain.jobs[0].job_id  # the default is not hashed
    assert both.jobs[1].job_id != both.jobs[0].job_id
    assert both.jobs[1].render_key == both.jobs[0].render_key  # one render for both
    assert "detector=paper" in both.jobs[1].label and both.jobs[1].dirname.count(".paper.") == 1
    with pytest.raises(SuiteError, match="unknown detector 'blobs'"):
        load_suite(_suite(tmp_path, detectors=["blobs"]))


def test_product_of_cameras_estimators_seeds_and_sweeps(tmp_path):
    p = _suite(
        tmp_path,
        cameras=["omni-near", "omni-far"],
        estimators=["direct", "can-only"],
        seeds=[1, 2],
        overrides={"can.speed_bias": [0.0, 0.1, 0.2], "sensor.noise_std": 1.0},
        frames=10,
    )
    s = load_suite(p)
    assert len(s.jobs) == 2 * 2 * 2 * 3
    assert len({j.render_key for j in s.jobs}) == 2 * 2 * 3  # estimators share a render
    j = s.jobs[0]
    assert j.scenario.camera == "omni-near" and j.seed == 1 and j.frames == 10
    assert j.scenario.sensor.noise_std == 1.0
    assert {x.scenario.can.speed_bias for x in s.jobs} == {0.0, 0.1, 0.2}
    assert s.spec.swept_keys() == ["can.speed_bias"]  # a single value is no sweep


def test_job_ids_are_stable_and_depend_on_what_is_run(tmp_path):
    a = load_suite(_suite(tmp_path, estimators=["direct", "can-only"], frames=10))
    b = load_suite(_suite(tmp_path, estimators=["direct", "can-only"], frames=10))
    assert [j.job_id for j in a.jobs] == [j.job_id for j in b.jobs]
    assert a.jobs[0].job_id != a.jobs[1].job_id  # estimator
    assert a.jobs[0].render_key == a.jobs[1].render_key
    c = load_suite(_suite(tmp_path, estimators=["direct"], frames=12))
    assert c.jobs[0].job_id != a.jobs[0].job_id
    assert c.jobs[0].render_key != a.jobs[0].render_key
    d = load_suite(_suite(tmp_path, estimators=["direct"], cameras=[TINY_CAMERA], frames=10))
    assert d.jobs[0].render_key != a.jobs[0].render_key


def test_frames_beyond_the_drive_are_the_whole_drive(tmp_path):
    full = load_suite(_suite(tmp_path))
    capped = load_suite(_suite(tmp_path, frames=100000))
    assert capped.jobs[0].frames == full.jobs[0].frames == full.jobs[0].scenario.n_frames
    assert capped.jobs[0].job_id == full.jobs[0].job_id


def test_frames_option_replaces_the_suite_limit(tmp_path):
    s = load_suite(_suite(tmp_path, frames=30), frames=5)
    assert s.jobs[0].frames == 5


def test_globs_of_names_and_files(tmp_path):
    s = load_suite(_suite(tmp_path, scenarios=["highway-*"]))
    assert sorted(j.scenario.name for j in s.jobs) == [
        "highway-omni-far",
        "highway-omni-near",
        "highway-rectilinear",
    ]
    (tmp_path / "drives").mkdir()
    for n in ("a", "b"):
        (tmp_path / "drives" / f"{n}.yaml").write_text(
            yaml.safe_dump({"name": f"drive-{n}", "duration_s": 1.0})
        )
    s = load_suite(_suite(tmp_path, scenarios=["drives/*.yaml", "drives/a.yaml"]))
    assert [j.scenario.name for j in s.jobs] == ["drive-a", "drive-b"]  # no repeats


def test_camera_label_and_dirname_are_readable(tmp_path):
    s = load_suite(_suite(tmp_path, cameras=[TINY_CAMERA]))
    j = s.jobs[0]
    assert j.camera == "omni-near(width=256,height=256)"
    assert j.job_id[:10] in j.dirname and "/" not in j.dirname


def test_set_dotted_creates_sections():
    d = {"can": {"rate_hz": 50}}
    set_dotted(d, "can.speed_bias", 0.1)
    set_dotted(d, "env_config.lanes_count", 3)
    assert d == {"can": {"rate_hz": 50, "speed_bias": 0.1}, "env_config": {"lanes_count": 3}}


def test_code_version_is_a_stable_hash():
    v = code_version()
    assert len(v) == 16 and int(v, 16) >= 0
    assert code_version() == v


# ------------------------------------------------------------------ bad suites
@pytest.mark.parametrize(
    "data, needles",
    [
        ({"colour": "red"}, ["key 'colour'", "Extra inputs"]),
        ({"estimators": ["direkt"]}, ["key 'estimators'", "direkt"]),
        ({"frames": 1}, ["key 'frames'"]),
        ({"thresholds": {"detection.recal": {"min": 0.5}}}, ["key 'thresholds'", "recal"]),
        ({"thresholds": {"detection.recall": {}}}, ["give min, max or both"]),
        ({"thresholds": {"detection.recall": {"mni": 0.5}}}, ["mni"]),
        ({"overrides": {"can.speed_biass": [0.1]}}, ["can.speed_biass", "speed_bias"]),
        ({"overrides": {"camera": "omni-far"}}, ["cameras"]),
        ({"overrides": {"can.speed_bias": []}}, ["empty sweep"]),
        ({"overrides": {"can.speed_bias": [0.1, 5.0]}}, ["can.speed_bias", "5.0", "s.yaml"]),
        ({"scenarios": ["no-such-drive"]}, ["scenarios.0", "no-such-drive"]),
        ({"scenarios": ["nope-*"]}, ["nope-*", "matches no scenario"]),
        ({"scenarios": ["missing/drive.yaml"]}, ["missing/drive.yaml", "not found"]),
        ({"cameras": ["omni-middle"]}, ["omni-middle", "camera"]),
        ({"name": "bad name!"}, ["key 'name'"]),
    ],
)
def test_bad_suites_name_file_key_and_value(tmp_path, data, needles):
    with pytest.raises(SuiteError) as e:
        load_suite(_suite(tmp_path, **data))
    msg = str(e.value)
    assert "s.yaml" in msg, msg
    for n in needles:
        assert n in msg, (n, msg)


def test_not_a_mapping_and_missing_file(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("- a\n- b\n")
    with pytest.raises(SuiteError, match="mapping"):
        load_suite(p)
    with pytest.raises(SuiteError, match="not found"):
        load_suite(tmp_path / "none.yaml")
    with pytest.raises(SuiteError, match="must be a mapping"):
        suite_from_dict([1, 2])


@pytest.mark.parametrize(
    "key", ["can.speed_bias", "env_config.vehicles_count", "duration_s", "sensor.jpeg_quality"]
)
def test_override_keys_into_the_scenario(key):
    check_override_key(key)


@pytest.mark.parametrize("key", ["can", "duration_s.x", "seed", "name", "vibration.amp"])
def test_bad_override_keys(key):
    with pytest.raises(ValueError):
        check_override_key(key)


# ------------------------------------------------------------------ a real suite
TINY_SUITE = {
    "name": "tiny",
    "scenarios": ["tiny-drive.yaml"],
    "cameras": [TINY_CAMERA],
    "estimators": ["direct", "can-only"],
    "frames": 8,
    "thresholds": {"ego.frames_compared": {"min": 7}, "ego.speed_rmse_pct": {"max": 1000.0}},
}
TINY_DRIVE = {
    "name": "tiny-drive",
    "env": "highway-v0",
    "env_config": {"vehicles_count": 15, "lanes_count": 3},
    "seed": 7,
    "duration_s": 1.0,
    "fps": 15,
    "can": {"speed_bias": 0.08, "speed_noise_mps": 0.3},
}


def _history_rows(db: Path) -> list[tuple]:
    with sqlite3.connect(db) as c:
        return c.execute("SELECT run_id, job_id, status FROM jobs ORDER BY job_id").fetchall()


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The tiny suite (2 jobs x 8 frames, one shared render) run once by the CLI."""
    d = tmp_path_factory.mktemp("suite")
    (d / "tiny-drive.yaml").write_text(yaml.safe_dump(TINY_DRIVE))
    (d / "tiny.yaml").write_text(yaml.safe_dump(TINY_SUITE))
    cmd = [
        sys.executable, "-m", "scenarios", "suite", str(d / "tiny.yaml"),
        "--out", str(d / "run"), "--history", str(d / "h.sqlite"),
        "--cache", str(d / "cache"), "--workers", "2", "--no-progress",
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    return d, proc


@pytest.mark.e2e
def test_tiny_suite_end_to_end(tiny_run):
    from scenarios.suite_runner import run_suite

    d, proc = tiny_run
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "2 run now" in proc.stderr and "1 renders" in proc.stderr
    # the results table: a header and one row per job with its metrics
    table = [ln for ln in proc.stdout.splitlines() if "tiny-drive |" in ln]
    assert "speed RMSE [%]" in proc.stdout and "recall" in proc.stdout and len(table) == 2
    assert all(" ok " in ln and "nan" not in ln.split(" ok ")[1].split()[0] for ln in table)
    run = d / "run"
    db = d / "h.sqlite"
    rows = _history_rows(db)
    assert len(rows) == 2 and {r[2] for r in rows} == {"ok"}
    assert len({r[1] for r in rows}) == 2
    for name in ("report.html", "summary.json", "junit.xml", "run.json", "plots/estimators.png"):
        assert (run / name).stat().st_size > 0, name
    summary = json.loads((run / "summary.json").read_text())
    assert summary["counts"] == {
        "jobs": 2, "ok": 2, "error": 0, "pending": 0, "passed": 2, "failed_thresholds": 0,
    }  # fmt: skip
    # the machine that ran the jobs, and the one that rendered the shared drive
    assert summary["machine"]["cpu"] and summary["machine"]["cpus"] >= 1
    assert [m["gl_renderer"] for m in summary["render_machines"]] != [] and all(
        m["gl_renderer"] for m in summary["render_machines"]
    )
    assert "Drives rendered on" in (run / "report.html").read_text()
    cases = ET.parse(run / "junit.xml").getroot().iter("testcase")
    assert len(list(cases)) == 2
    job_dirs = [run / j["dir"] for j in summary["jobs"]]
    for jd in job_dirs:
        for name in ("metrics.json", "trajectory.tum", "groundtruth.tum", "recall_bins.json"):
            assert (jd / name).stat().st_size > 0, (jd, name)
        tum = (jd / "trajectory.tum").read_text().splitlines()
        assert len(tum) == 8 and len(tum[0].split()) == 8
    m = json.loads((job_dirs[0] / "metrics.json").read_text())
    assert m["frames"] == 8 and math.isfinite(m["ego"]["speed_rmse_mps"])
    assert len([p for p in (d / "cache").iterdir() if p.is_dir()]) == 1  # one render, shared

    # a rerun redoes nothing and records nothing twice
    stamps = [(jd / "metrics.json").stat().st_mtime_ns for jd in job_dirs]
    suite = load_suite(d / "tiny.yaml")
    kw = dict(history=db, cache_dir=d / "cache", workers=2, progress=False)
    res = run_suite(suite, run, **kw)
    assert (res.ran, res.skipped, res.renders) == (0, 2, 0)
    assert [(jd / "metrics.json").stat().st_mtime_ns for jd in job_dirs] == stamps
    assert _history_rows(db) == rows

    # killed after a job wrote metrics.json, before it was recorded: recorded, not redone
    with sqlite3.connect(db) as c:
        c.execute("DELETE FROM jobs WHERE job_id = ?", (rows[0][1],))
        c.execute("DELETE FROM metrics WHERE job_id = ?", (rows[0][1],))
    res = run_suite(suite, run, **kw)
    assert (res.ran, res.recorded_from_disk, res.skipped) == (0, 1, 1)
    assert _history_rows(db) == rows
    assert [(jd / "metrics.json").stat().st_mtime_ns for jd in job_dirs] == stamps


@pytest.mark.e2e
def test_ray_executor_gives_the_same_metrics(tiny_run):
    ray = pytest.importorskip("ray", reason="ray is an optional extra (pip install ray)")
    from scenarios.suite_runner import run_suite

    d, proc = tiny_run
    assert proc.returncode == 0, proc.stderr[-3000:]
    suite = load_suite(d / "tiny.yaml")
    try:
        res = run_suite(
            suite,
            d / "run-ray",
            history=d / "h.sqlite",
            cache_dir=d / "cache",
            workers=2,
            executor="ray",
            progress=False,
        )
    finally:
        ray.shutdown()
    assert res.ran == 2 and all(o.status == "ok" for o in res.outcomes)
    local = json.loads((d / "run" / "summary.json").read_text())["jobs"]
    remote = json.loads((d / "run-ray" / "summary.json").read_text())["jobs"]
    assert [j["job_id"] for j in local] == [j["job_id"] for j in remote]
    for a, b in zip(local, remote, strict=True):
        ma = {k: v for k, v in a["metrics"].items() if not k.startswith("timing.")}
        mb = {k: v for k, v in b["metrics"].items() if not k.startswith("timing.")}
        assert ma == mb, a["label"]


@pytest.mark.e2e
def test_a_failing_job_is_isolated_and_retried(tiny_run):
    from scenarios.suite_runner import run_suite

    d, proc = tiny_run
    assert proc.returncode == 0, proc.stderr[-3000:]
    # highway-env rejects 0 lanes when the render starts: a job that fails fast
    (d / "broken.yaml").write_text(
        yaml.safe_dump({**TINY_DRIVE, "name": "broken", "env_config": {"lanes_count": 0}})
    )
    suite = suite_from_dict(
        {**TINY_SUITE, "scenarios": ["tiny-drive.yaml", "broken.yaml"], "estimators": ["can-only"]},
        where="broken-suite",
        base_dir=d,
    )
    db = d / "h-broken.sqlite"
    kw = dict(history=db, cache_dir=d / "cache", workers=2, progress=False)
    res = run_suite(suite, d / "run-broken", **kw)
    by_name = {o.job.scenario.name: o for o in res.outcomes}
    assert by_name["tiny-drive"].status == "ok" and by_name["tiny-drive"].passed
    bad = by_name["broken"]
    assert bad.status == "error" and "render: ValueError" in bad.error
    assert "Traceback" in bad.traceback and not res.ok
    assert (d / "run-broken" / bad.job.describe()["dir"] / "error.txt").exists()
    root = ET.parse(d / "run-broken" / "junit.xml").getroot()
    assert root.find("testsuite").get("errors") == "1"
    summary = json.loads((d / "run-broken" / "summary.json").read_text())
    assert (summary["counts"]["ok"], summary["counts"]["error"]) == (1, 1)
    # a rerun tries the failed job again, keeps the good one, and records each once
    res = run_suite(suite, d / "run-broken", **kw)
    assert (res.ran, res.skipped) == (1, 1)
    assert sorted(r[2] for r in _history_rows(db)) == ["error", "ok"]


def test_suite_command_rejects_bad_input(tmp_path):
    def omnibench(*args):
        where = ["--history", str(tmp_path / "h.sqlite"), "--cache", str(tmp_path / "cache")]
        return subprocess.run(
            [sys.executable, "-m", "scenarios", "suite", *args, *where],
            capture_output=True,
            text=True,
            timeout=120,
        )

    bad = _suite(tmp_path, estimators=["direkt"])
    proc = omnibench(str(bad), "--out", str(tmp_path / "o"))
    assert proc.returncode == 2 and "s.yaml" in proc.stderr and "direkt" in proc.stderr
    assert not (tmp_path / "o").exists()
    good = _suite(tmp_path)
    proc = omnibench(str(good), "--out", str(tmp_path / "o"), "--executor", "dask")
    assert proc.returncode == 2 and "dask" in proc.stderr
    proc = omnibench(str(good), "--out", str(tmp_path / "o"), "--address", "127.0.0.1:1")
    assert proc.returncode == 2 and "--address" in proc.stderr
    assert not (tmp_path / "o").exists() and not (tmp_path / "h.sqlite").exists()
