"""Run an example's ``run_example.py`` as a user would: its own process, the project
importable from the checkout."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def run_example(name: str, out: Path, frames: int, timeout_s: float) -> subprocess.CompletedProcess:
    """``python examples/NAME/run_example.py --out OUT --frames FRAMES``; its output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    script = ROOT / "examples" / name / "run_example.py"
    return subprocess.run(
        [sys.executable, str(script), "--out", str(out), "--frames", str(frames)],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=env,
    )
