"""Fitting the pixel classifier to a rendered drive's id images; the learned detector."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DetectorConfig
from estimator.surround.pixel_classifier import PixelClassifier, feature_names
from scenarios.config import load_scenario
from scenarios.point_audit import gt_vehicle_ids
from scenarios.train_pixels import TrainConfig, check_drive, drive_samples, train
from sim.drive import load_groundtruth, render_drive

LAMS = sorted(DetectorConfig().static_lambdas + DetectorConfig().moving_lambdas)


@pytest.fixture(scope="module")
def dense(tmp_path_factory):
    out = tmp_path_factory.mktemp("dense")
    render_drive(load_scenario("dense-freeway-omni-near"), out, progress=False, max_frames=7)
    return out


def test_samples_are_the_id_images_pixels(dense):
    """Every sampled vehicle pixel is one (id image), the negatives weighted back by their
    sampling rate; frames sampled every 2nd from the detector's first."""
    cfg = TrainConfig(every=2, negative_rate=0.2)
    X, y, w = drive_samples(dense, cfg, np.random.default_rng(0), progress=False)
    assert X.shape[1] == len(feature_names(LAMS)) and len(X) == len(y) == len(w)
    assert np.all(np.isfinite(X))
    assert 0 < y.mean() < 1
    assert np.all(w[y] == 1.0) and np.allclose(w[~y], 5.0)
    ids = gt_vehicle_ids(dense, 2) > 0
    assert ids.any()


def test_train_writes_a_model_the_detector_uses(dense, tmp_path):
    """A model fitted to the drive marks more of its vehicles' pixels than of the rest,
    names the drive, and `method="learned"` with it marks exactly the pixels it calls
    vehicles (p > pixel_threshold) on a frame of the drive."""
    path = tmp_path / "m.npz"
    model = train([dense], path, TrainConfig(every=2, hidden=6, max_iter=150), progress=False)
    back = PixelClassifier.load(path)
    assert back.meta["drives"] == ["dense-freeway-omni-near camera omni-near seed 7"]
    assert back.meta["features"] == feature_names(LAMS)
    camera, mount = load_camera(dense / "camera.yaml")
    cfg = DetectorConfig(method="learned", pixel_model=str(path))
    sa = SurroundAnalyzer(with_folder_body_mask(camera, dense), mount, cfg)
    sa.detector.keep_features = True
    gt = load_groundtruth(dense)
    from estimator.fileio import read_png

    frame = None
    for k in range(4):
        m = gt[k]["motion_from_prev"]
        x = np.r_[m["V_mps"], m["W_rps"], m["A_rad"]] if m else np.zeros(9)
        img = read_png(dense / "frames" / f"{k:06d}.png")
        frame = sa.step(k, gt[k]["t_s"], img, x, m["dt_s"] if m else 0.0, 25.0, 0.0)
    X, ok = sa.detector.last_features
    p = np.zeros(ok.shape)
    p[ok] = model.probability(X)
    small = frame.detection._mask
    assert np.array_equal(small, (p > cfg.pixel_threshold) & ok)
    ids = gt_vehicle_ids(dense, 3) > 0
    import cv2

    lab = cv2.resize(ids.astype(np.uint8), ok.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
    assert p[lab & ok].mean() > p[~lab & ok].mean() + 0.3


def test_bad_inputs_are_refused_before_work(tmp_path):
    with pytest.raises(ValueError, match="not a rendered drive"):
        check_drive(tmp_path)
    with pytest.raises(ValueError, match="not a rendered drive"):
        train([tmp_path], tmp_path / "m.npz", progress=False)
    with pytest.raises(ValueError, match="every"):
        TrainConfig(every=0)
    camera, mount = load_camera("omni-near")
    with pytest.raises(FileNotFoundError, match="missing.npz"):
        SurroundAnalyzer(
            camera,
            mount,
            DetectorConfig(method="learned", pixel_model=str(tmp_path / "missing.npz")),
        )


def test_a_bad_pixel_model_is_refused_before_any_work(tmp_path):
    """`run` and `estimate` name a missing classifier file, and --pixel-model without the
    learned detector, before rendering or reading anything (no drive folder exists)."""
    from typer.testing import CliRunner

    from scenarios.cli import app

    missing = tmp_path / "missing.npz"
    for extra, message in (
        (["--detector", "learned", "--pixel-model", str(missing)], "missing.npz"),
        (["--pixel-model", str(missing)], "--detector learned"),
    ):
        res = CliRunner().invoke(
            app, ["run", "highway-omni-near", "--out", str(tmp_path / "o")] + extra
        )
        assert res.exit_code == 2 and message in res.output, res.output
        args = ["estimate", str(tmp_path / "nothing.mp4"), "--camera", "omni-far"]
        res = CliRunner().invoke(
            app, args + ["--can", "x.csv", "--out", str(tmp_path / "e")] + extra
        )
        assert res.exit_code == 2 and message in res.output, res.output
    assert not (tmp_path / "o").exists()


def test_run_scenario_checks_the_pixel_model_as_the_cli_does(tmp_path):
    """The API refuses what the CLI refuses, before rendering: a model with another
    detector, and a missing file."""
    from estimator.surround.pixel_classifier import BUILTIN_MODEL
    from scenarios.config import load_scenario
    from scenarios.runner import run_scenario

    sc = load_scenario("highway-omni-near")
    with pytest.raises(ValueError, match="--pixel-model is for --detector learned"):
        run_scenario(sc, tmp_path / "a", detector="hypotheses", pixel_model=BUILTIN_MODEL)
    with pytest.raises(ValueError, match="no such file"):
        run_scenario(sc, tmp_path / "b", detector="learned", pixel_model=tmp_path / "x.npz")
    assert not (tmp_path / "a" / "drive").exists() and not (tmp_path / "b" / "drive").exists()
