"""Run the example plug-in through omnibench: a drive, its scoring, and a suite.

    python examples/lk_homography/run_example.py --out renders/lk-example [--frames 40]

1. ``omnibench run highway-omni-near --estimator lk_homography:LKHomographyEstimator``
   renders (or reuses) the drive and scores the plug-in as it scores its own estimators;
2. ``omnibench evaluate`` scores the plug-in's egomotion.csv again, as a file made
   elsewhere, against the same drive;
3. ``omnibench suite examples/lk_homography/suite.yaml`` runs it beside ``direct``; the
   suite's report and history show both.

This folder is put on PYTHONPATH so that ``lk_homography`` imports, as an installed
package would.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
PLUGIN = "lk_homography:LKHomographyEstimator"


def omnibench(*args: str) -> None:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    subprocess.run([sys.executable, "-m", "scenarios", *args], check=True, env=env)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--frames", type=int, default=40, help="frames of the drive")
    a = ap.parse_args()
    run, scored, suite = a.out / "run", a.out / "evaluated", a.out / "suite"
    omnibench("run", "highway-omni-near", "--out", str(run), "--frames", str(a.frames),
              "--estimator", PLUGIN)  # fmt: skip
    omnibench("evaluate", str(run / "drive"), "--out", str(scored),
              "--egomotion", str(run / "egomotion.csv"))  # fmt: skip
    spec = HERE / "suite.yaml"
    if a.frames != 40:  # the suite file's frames, changed for a shorter try
        text = spec.read_text().replace("frames: 40", f"frames: {a.frames}")
        spec = a.out / "suite.yaml"
        spec.parent.mkdir(parents=True, exist_ok=True)
        spec.write_text(text)
    history, cache = str(a.out / "history.sqlite"), str(a.out / "cache")
    omnibench("suite", str(spec), "--out", str(suite), "--workers", "2", "--no-progress",
              "--history", history, "--cache", cache)  # fmt: skip
    ego = json.loads((scored / "metrics.json").read_text())["ego"]
    print(f"{PLUGIN}: speed RMSE {ego['speed_rmse_pct']:.2f} %, "
          f"yaw rate RMSE {ego['yaw_rate_rmse_dps']:.3f} deg/s")  # fmt: skip
    print(f"suite report: {suite / 'report.html'}")


if __name__ == "__main__":
    main()
