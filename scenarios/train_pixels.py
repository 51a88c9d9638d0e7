"""Fit the surround detector's pixel classifier to rendered drives' id images.

For every ``every``-th frame of each drive, the direct estimator's ego-motion drives the
detector's motion hypotheses (`estimator.surround.detection`), whose evidence per pixel
(`estimator.surround.pixel_classifier.pixel_features`) is labelled from the id image: a
pixel sees a vehicle or not (any vehicle but the ego car, at the working scale). Every
vehicle pixel of the analysed area is kept and a share ``negative_rate`` of the rest,
weighted back by its inverse. `fit_classifier` fits the model, which is written with
what it was fitted to.

``omnibench train-pixels --suite surround-train --out FILE`` renders (or reuses, in the
render cache) a suite's drives and fits the model to them; ``omnibench train-pixels
DRIVE_DIR ... --out FILE`` fits it to rendered drives (``omnibench render``).
"""

from __future__ import annotations

import argparse
import datetime
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from estimator.camera.files import load_camera, with_folder_body_mask
from estimator.egomotion.baselines import make_estimator
from estimator.progress import track
from estimator.recording import iter_frames, read_can_csv, read_timestamps_csv
from estimator.surround.analyzer import SurroundAnalyzer
from estimator.surround.detection import DetectorConfig
from estimator.surround.pixel_classifier import PixelClassifier, feature_names, fit_classifier
from scenarios.point_audit import gt_vehicle_ids


@dataclass(frozen=True)
class TrainConfig:
    """How samples are drawn and the model is sized (units beside each value)."""

    every: int = 4  # [frames] one frame of this many is sampled, >= 1
    negative_rate: float = 0.1  # [-] share of the non-vehicle pixels kept, 0..1
    max_samples: int = 600_000  # [-] samples fitted at most (drawn evenly at random)
    hidden: int = 24  # [-] hidden units
    l2: float = 1e-4  # [-] weight decay
    max_iter: int = 400  # [-] L-BFGS iterations
    seed: int = 0  # [-] sampling and initialisation

    def __post_init__(self) -> None:
        if self.every < 1 or not (0 < self.negative_rate <= 1) or self.hidden < 1:
            raise ValueError(
                f"TrainConfig: every >= 1, 0 < negative_rate <= 1 and hidden >= 1 needed, got "
                f"{self.every}, {self.negative_rate}, {self.hidden}"
            )


def describe_drive(drive_dir: Path) -> str:
    """ "NAME camera CAMERA seed SEED" of a rendered drive (its scenario.yaml), else its
    folder's name."""
    try:
        sc = yaml.safe_load((Path(drive_dir) / "scenario.yaml").read_text())
        camera = sc["camera"] if isinstance(sc["camera"], str) else "inline"
        return f"{sc['name']} camera {camera} seed {sc['seed']}"
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return Path(drive_dir).name


def check_drive(drive_dir: Path) -> None:
    """A clear error before any work for a folder that is not a rendered drive with ids."""
    for name in ("camera.yaml", "timestamps.csv", "can.csv", "frames", "ids"):
        if not (drive_dir / name).exists():
            raise ValueError(f"{drive_dir}: not a rendered drive with id images (no {name})")


def suite_drives(suite: str, cache_dir: Path, progress: bool = True) -> list[Path]:
    """The rendered drives of a suite's jobs (one per render), rendered into ``cache_dir``
    (as `omnibench suite` does) where missing."""
    from scenarios.suite import load_suite
    from sim.drive import render_drive

    s = load_suite(suite)
    out: dict[str, Path] = {}
    for job in s.jobs:
        if job.render_key not in out:
            d = Path(cache_dir) / job.render_key
            render_drive(job.scenario, d, progress=progress, max_frames=job.frames)
            out[job.render_key] = d
    return list(out.values())


def drive_samples(
    drive_dir: Path, cfg: TrainConfig, rng: np.random.Generator, progress: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X (N, F), vehicle (N,) bool, weight (N,)) of one drive's sampled pixels."""
    drive_dir = Path(drive_dir)
    camera, mount = load_camera(drive_dir / "camera.yaml")
    times = read_timestamps_csv(drive_dir / "timestamps.csv")
    can = read_can_csv(drive_dir / "can.csv")
    est = make_estimator("direct", camera, mount)
    analyzer = SurroundAnalyzer(
        with_folder_body_mask(camera, drive_dir), mount, replace(DetectorConfig())
    )
    analyzer.detector.keep_features = True
    Xs, ys, ws = [], [], []
    for k, image in track(
        enumerate(iter_frames(drive_dir / "frames")),
        len(times),
        f"sample {drive_dir.name}",
        progress,
    ):
        t = float(times[k])
        rec = est.step(image, t, can.at(t))
        analyzer.detector.last_features = None
        analyzer.step(k, t, image, rec.x, rec.dt_s, rec.speed_mps, rec.yaw_rate_rps)
        kept = analyzer.detector.last_features
        if kept is None or k % cfg.every:
            continue
        X, ok = kept  # (N, F): the analysed pixels in row-major order
        ids = gt_vehicle_ids(drive_dir, k) > 0
        label = (
            cv2.resize(ids.astype(np.uint8), ok.shape[::-1], interpolation=cv2.INTER_NEAREST) > 0
        )[ok]
        keep = label | (rng.random(len(label)) < cfg.negative_rate)
        Xs.append(X[keep])
        ys.append(label[keep])
        ws.append(np.where(label[keep], 1.0, 1.0 / cfg.negative_rate))
    if not Xs:
        raise ValueError(f"{drive_dir}: no frame to sample (too short for the detector)")
    return np.concatenate(Xs), np.concatenate(ys), np.concatenate(ws)


def train(
    drive_dirs: Sequence[Path],
    out: Path,
    cfg: TrainConfig | None = None,
    progress: bool = True,
    note: str = "",
) -> PixelClassifier:
    """Fit the classifier to ``drive_dirs`` and write it to ``out`` (.npz)."""
    cfg = cfg or TrainConfig()
    drive_dirs = [Path(d) for d in drive_dirs]
    if not drive_dirs:
        raise ValueError("train: no drive given")
    for d in drive_dirs:
        check_drive(d)
    rng = np.random.default_rng(cfg.seed)
    parts = [drive_samples(d, cfg, rng, progress) for d in drive_dirs]
    X = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    w = np.concatenate([p[2] for p in parts])
    if len(X) > cfg.max_samples:
        pick = rng.choice(len(X), cfg.max_samples, replace=False)
        X, y, w = X[pick], y[pick], w[pick]
    lams = sorted(DetectorConfig().static_lambdas + DetectorConfig().moving_lambdas)
    meta = {
        "drives": [describe_drive(d) for d in drive_dirs],
        "every": cfg.every,
        "negative_rate": cfg.negative_rate,
        "hidden": cfg.hidden,
        "features": feature_names(lams),
        "vehicle_share": float(np.average(y, weights=w)),
        "fitted": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "note": note,
    }
    model = fit_classifier(X, y, w, cfg.hidden, cfg.l2, cfg.max_iter, cfg.seed, meta)
    model.save(out)
    return model


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("drives", nargs="+", type=Path, help="rendered drive folders")
    p.add_argument("--out", type=Path, required=True, help="model file to write (.npz)")
    p.add_argument("--every", type=int, default=TrainConfig.every)
    p.add_argument("--note", default="", help="kept in the model file (e.g. the suite)")
    p.add_argument("--no-progress", action="store_true")
    a = p.parse_args(argv)
    model = train(a.drives, a.out, TrainConfig(every=a.every), not a.no_progress, a.note)
    print(f"{a.out}: {model.meta['n_samples']} samples, loss {model.meta['loss']:.4f}")


if __name__ == "__main__":
    main()
