"""The omnibench command line: calibrate and estimate with good and bad inputs."""

import csv
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator.camera.files import load_camera
from scenarios.cli import parse_settings


def omnibench(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "scenarios", *args], capture_output=True, text=True, timeout=timeout
    )


def _points_csv(path: Path, noise_px: float = 0.5) -> None:
    cam, _ = load_camera("omni-near")
    rng = np.random.default_rng(11)
    # ground points around a tripod 1.95 m high, and a vertical pole: Z down the axis
    ang = rng.uniform(0, 2 * np.pi, 300)
    dist = rng.uniform(7.5, 40.0, 300)
    ground = np.c_[dist * np.cos(ang), dist * np.sin(ang), np.full(300, 1.95)]
    h = rng.uniform(0.0, 1.95, 60)
    pole = np.c_[np.full(60, 6.0), np.zeros(60), 1.95 - h]
    P = np.vstack([ground, pole])
    P = P[cam.valid_rays(P)]
    w = cam.project(P) + rng.normal(0, noise_px, (len(P), 2))
    with open(path, "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["X", "Y", "Z", "u", "v"])
        wr.writerows(np.c_[P, w].round(5).tolist())


def test_calibrate_writes_a_camera_and_prints_residuals(tmp_path):
    pts = tmp_path / "pts.csv"
    _points_csv(pts)
    out = tmp_path / "camera.yaml"
    proc = omnibench("calibrate", str(pts), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "rms" in (proc.stdout + proc.stderr).lower()
    cam, _ = load_camera(out)
    ref, _ = load_camera("omni-near")
    assert abs(cam.fu / ref.fu - 1) < 0.02


def test_calibrate_bad_inputs(tmp_path):
    missing = omnibench("calibrate", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "c.yaml"))
    assert missing.returncode == 2 and "nope.csv" in missing.stderr
    bad = tmp_path / "bad.csv"
    bad.write_text("X,Y,u,v\n1,2,3,4\n")
    proc = omnibench("calibrate", str(bad), "--out", str(tmp_path / "c.yaml"))
    assert proc.returncode == 2 and "Z" in proc.stderr
    assert not (tmp_path / "c.yaml").exists()


def test_estimate_bad_inputs_are_named(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    can = tmp_path / "can.csv"

    def estimate(video, camera="omni-near", *extra):
        return omnibench(
            "estimate", str(video), "--camera", camera, "--can", str(can),
            "--out", str(tmp_path / "o"), *extra,
        )  # fmt: skip

    can.write_text("t_s,speed_mps\n0,20\n0.1,nan_or_junk\n")
    proc = estimate(frames, "omni-near", "--fps", "15")
    assert proc.returncode == 2 and "can.csv" in proc.stderr and "row 3" in proc.stderr
    can.write_text("time,v\n0,20\n")
    proc = estimate(frames, "omni-near", "--fps", "15")
    assert proc.returncode == 2 and "t_s" in proc.stderr
    can.write_text("t_s,speed_mps\n0,20\n")
    proc = estimate(frames, "omni-near", "--fps", "15")
    assert proc.returncode == 2 and "no PNG/JPEG frames" in proc.stderr
    proc = estimate(tmp_path / "video.mp4", "nocam")
    assert proc.returncode == 2 and "nocam" in proc.stderr


def _noise_recording(tmp_path: Path, seed: int) -> tuple[Path, Path]:
    """(frames folder, CAN file): three frames of grey noise of omni-near's size, 10 m/s."""
    cam, _ = load_camera("omni-near")
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(seed)
    for k in range(3):
        img = rng.integers(0, 255, (cam.height, cam.width), dtype=np.uint8)
        cv2.imwrite(str(frames / f"{k:06d}.png"), img)
    can = tmp_path / "can.csv"
    can.write_text("t_s,speed_mps\n0,10\n1,10\n")
    return frames, can


def test_estimate_takes_road_masks_and_names_bad_ones(tmp_path):
    """--road-masks: one PNG per frame; too few, or of another size, is named."""
    cam, _ = load_camera("omni-near")
    frames, can = _noise_recording(tmp_path, seed=3)
    masks = tmp_path / "masks"
    masks.mkdir()

    def estimate():
        return omnibench(
            "estimate", str(frames), "--camera", "omni-near", "--can", str(can), "--fps", "15",
            "--out", str(tmp_path / "o"), "--road-masks", str(masks),
        )  # fmt: skip

    proc = estimate()
    assert proc.returncode == 2 and "no PNG road masks" in proc.stderr
    for k in range(2):
        cv2.imwrite(str(masks / f"{k:06d}.png"), np.full((cam.height, cam.width), 255, np.uint8))
    proc = estimate()
    assert proc.returncode == 2 and "none for frame 2" in proc.stderr
    cv2.imwrite(str(masks / "000002.png"), np.full((10, 10), 255, np.uint8))
    proc = estimate()
    assert proc.returncode == 2 and "frame 2" in proc.stderr and "(10, 10)" in proc.stderr
    cv2.imwrite(str(masks / "000002.png"), np.full((cam.height, cam.width), 255, np.uint8))
    proc = estimate()
    assert proc.returncode == 0, proc.stderr
    assert len((tmp_path / "o" / "egomotion.csv").read_text().splitlines()) == 4


def test_estimate_takes_a_body_mask_and_names_a_bad_one(tmp_path):
    """--body-mask: a PNG of the camera's size; another size is named before any frame is
    read; a good one runs the surround analysis to its tracks."""
    cam, _ = load_camera("omni-near")
    frames, can = _noise_recording(tmp_path, seed=4)
    body = np.zeros((cam.height, cam.width), np.uint8)
    body[200:440, 260:380] = 255  # a car body under the mirror
    cv2.imwrite(str(tmp_path / "small.png"), body[:100])
    cv2.imwrite(str(tmp_path / "body.png"), body)

    def estimate(mask):
        return omnibench(
            "estimate", str(frames), "--camera", "omni-near", "--can", str(can), "--fps", "15",
            "--out", str(tmp_path / "o"), "--body-mask", str(tmp_path / mask),
        )  # fmt: skip

    proc = estimate("small.png")
    assert proc.returncode == 2 and "small.png: body mask is 640x100" in proc.stderr
    assert not (tmp_path / "o").exists()
    proc = estimate("body.png")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "o" / "tracks.csv").exists()


def test_set_parses_dotted_keys_and_yaml_values():
    got = parse_settings(["road_appearance=true", "filter.A_tau_s=0.5", "iterations=[3, 2, 2, 1]"])
    assert got == {"road_appearance": True, "filter": {"A_tau_s": 0.5}, "iterations": [3, 2, 2, 1]}
    for bad, why in (
        ("road_appearance", "KEY=VALUE"),
        ("=1", "KEY=VALUE"),
        ("filter..x=1", "KEY=VALUE"),
        ("a=[1, 2", "not valid YAML"),
    ):
        try:
            parse_settings([bad])
        except ValueError as e:
            assert why in str(e) and repr(bad) in str(e)
        else:
            raise AssertionError(f"{bad!r} was taken")
    for pairs, why in ((["a=1", "a=2"], "set twice"), (["a=1", "a.b=2"], "a value and a group")):
        try:
            parse_settings(pairs)
        except ValueError as e:
            assert why in str(e)
        else:
            raise AssertionError(f"{pairs!r} was taken")


def test_estimate_takes_estimator_settings(tmp_path):
    """--set reaches the estimator (the rectilinear camera with its road appearance model
    on); an unknown setting or a value of the wrong kind is named, and nothing is written."""
    cam, _ = load_camera("rectilinear-rear-left")
    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(4)
    for k in range(3):
        img = rng.integers(40, 80, (cam.height, cam.width, 3), dtype=np.uint8)
        cv2.imwrite(str(frames / f"{k:06d}.png"), img)
    can = tmp_path / "can.csv"
    can.write_text("t_s,speed_mps\n0,10\n1,10\n")

    def estimate(out, *sets):
        args = [a for s in sets for a in ("--set", s)]
        return omnibench(
            "estimate", str(frames), "--camera", "rectilinear-rear-left", "--can", str(can),
            "--fps", "15", "--out", str(tmp_path / out), *args,
        )  # fmt: skip

    proc = estimate("ok", "road_appearance=true", "filter.A_tau_s=0.5")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "ok" / "egomotion.csv").exists()
    proc = estimate("bad1", "road_apperance=true")
    assert proc.returncode == 2 and "unknown setting direct.road_apperance" in proc.stderr
    proc = estimate("bad2", "road_appearance=maybe")
    assert proc.returncode == 2 and "direct.road_appearance takes a bool" in proc.stderr
    assert not (tmp_path / "bad1").exists() and not (tmp_path / "bad2").exists()


def test_estimate_counts_the_frames_of_a_folder_and_a_video(tmp_path, monkeypatch):
    """--fps: the progress bar's total is the recording's frame count (a folder's image
    files, a video's stated count) and every frame gets its time k / fps."""
    from typer.testing import CliRunner

    import estimator.pipeline as pipeline
    from scenarios.cli import app

    totals = []
    real_track = pipeline.track

    def spy(items, total, label, enabled=True):
        totals.append(total)
        return real_track(items, total, label, False)

    monkeypatch.setattr(pipeline, "track", spy)
    cam, _ = load_camera("omni-far")
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8) for _ in range(4)]
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, img in enumerate(images[:3]):
        cv2.imwrite(str(folder / f"{k:06d}.png"), img)
    video = tmp_path / "drive.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (cam.width, cam.height))
    for img in images:
        w.write(img)
    w.release()
    can = tmp_path / "can.csv"
    can.write_text("t_s,speed_mps\n0,10\n1,10\n")
    for source, n in ((folder, 3), (video, 4)):
        out = tmp_path / f"out-{source.name}"
        args = ["estimate", str(source), "--camera", "omni-far", "--can", str(can)]
        args += ["--fps", "15", "--estimator", "can-only", "--out", str(out)]
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        assert totals[-1] == n
        with open(out / "egomotion.csv", newline="") as fh:
            t = [float(r["t_s"]) for r in csv.DictReader(fh)]
        np.testing.assert_allclose(t, np.arange(n) / 15.0, atol=1e-6)


def test_a_bad_estimator_is_refused_before_any_work(tmp_path):
    """`run` and `estimate` name a bad --estimator and the known ones before rendering or
    reading anything (here: no drive folder; a missing CAN file not reached)."""
    out = tmp_path / "o"
    proc = omnibench(
        "run", "highway-omni-near", "--estimator", "nope", "--frames", "2", "--out", str(out)
    )
    assert proc.returncode == 2
    assert "'nope'" in proc.stderr and "direct, can-only, features" in proc.stderr
    assert not out.exists(), "rendered before checking the estimator"
    proc = omnibench("run", "highway-omni-near", "--frames", "0", "--out", str(out))
    assert proc.returncode == 2 and "--frames 0" in proc.stderr and not out.exists()
    proc = omnibench(
        "estimate", str(tmp_path), "--camera", "omni-near", "--can", str(tmp_path / "none.csv"),
        "--fps", "15", "--estimator", "nope", "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 2
    assert "'nope'" in proc.stderr and "direct, can-only, features" in proc.stderr
    assert "none.csv" not in proc.stderr and not out.exists()
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    sc = load_scenario("highway-omni-near")
    with pytest.raises(ValueError, match="'nope'; choose one of direct, can-only, features"):
        run_scenario(sc, out, estimator="nope", progress=False, max_frames=2)
    assert not out.exists(), "rendered before checking the estimator"
