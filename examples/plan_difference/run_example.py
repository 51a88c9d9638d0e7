"""Run the example detector plug-in through omnibench: a drive and its scoring.

    python examples/plan_difference/run_example.py --out renders/plan-difference [--frames 30]

1. ``omnibench run highway-omni-near --detector plan_difference:PlanDifferenceDetector``
   renders (or reuses) the drive and scores the plug-in's vehicles as it scores its own
   detector's (``tracks.csv``, ``metrics.json``);
2. ``omnibench evaluate`` scores the plug-in's tracks.csv again, as a file made
   elsewhere, against the same drive.

This folder is put on PYTHONPATH so that ``plan_difference`` imports, as an installed
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
PLUGIN = "plan_difference:PlanDifferenceDetector"


def omnibench(*args: str) -> None:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(HERE), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    subprocess.run([sys.executable, "-m", "scenarios", *args], check=True, env=env)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--frames", type=int, default=30, help="frames of the drive")
    a = ap.parse_args()
    run, scored = a.out / "run", a.out / "evaluated"
    omnibench("run", "highway-omni-near", "--out", str(run), "--frames", str(a.frames),
              "--detector", PLUGIN)  # fmt: skip
    omnibench("evaluate", str(run / "drive"), "--out", str(scored),
              "--tracks", str(run / "tracks.csv"))  # fmt: skip
    m = json.loads((scored / "metrics.json").read_text())
    det, trk = m["track_detection"], m["tracking"]
    print(f"{PLUGIN}: recall {det['recall']:.2f}, precision {det['precision']:.2f}, "
          f"MOTA {trk['mota']:.2f}, IDF1 {trk['idf1']:.2f}, HOTA {trk['hota']:.2f}")  # fmt: skip
    print(f"report: {run / 'report.html'}")


if __name__ == "__main__":
    main()
