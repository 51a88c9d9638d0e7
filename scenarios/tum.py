"""Planar trajectories in TUM format (``t x y z qx qy qz qw``), readable by ``evo``.

Both trajectories are in the car frame of the first frame (x forward, y left,
z up, docs/CONVENTIONS.md), z = 0, and the orientation is the yaw about z:
``q = (0, 0, sin(yaw/2), cos(yaw/2))``.

- estimated (``trajectory.tum``): dead reckoning of egomotion.csv's forward
  speed ``speed_mps`` and yaw rate ``yaw_rate_dps`` (car frame). Row k holds the
  motion from frame k-1 to k, integrated at the mid-point heading::

      yaw_k = yaw_{k-1} + w_k dt,   p_k = p_{k-1} + v_k dt (cos, sin)(yaw_{k-1} + w_k dt / 2)

  A non-finite estimate (a degraded frame) reuses the last finite one.
- ground truth (``groundtruth.tum``): the ego pose of groundtruth.jsonl
  (``ego.x_m``, ``ego.y_m``, ``ego.yaw_rad``, world frame), expressed in the
  first frame's car frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimator.fileio import write_text


def integrate_planar(
    t_s: np.ndarray, speed_mps: np.ndarray, yaw_rate_rps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, yaw) (N,) [m, m, rad] from per-frame speed and yaw rate (N,), starting at 0."""
    t = np.asarray(t_s, dtype=float)
    v = _hold(np.asarray(speed_mps, dtype=float))
    w = _hold(np.asarray(yaw_rate_rps, dtype=float))
    n = len(t)
    x, y, yaw = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        mid = yaw[k - 1] + 0.5 * w[k] * dt
        x[k] = x[k - 1] + v[k] * dt * np.cos(mid)
        y[k] = y[k - 1] + v[k] * dt * np.sin(mid)
        yaw[k] = yaw[k - 1] + w[k] * dt
    return x, y, yaw


def _hold(a: np.ndarray) -> np.ndarray:
    """Non-finite entries replaced by the last finite one (0 before any)."""
    out = a.copy()
    last = 0.0
    for i, v in enumerate(out):
        if np.isfinite(v):
            last = v
        else:
            out[i] = last
    return out


def relative_planar(
    x_m: np.ndarray, y_m: np.ndarray, yaw_rad: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World poses (N,) expressed in the frame of the first pose."""
    x, y, yaw = (np.asarray(a, dtype=float) for a in (x_m, y_m, yaw_rad))
    c, s = np.cos(yaw[0]), np.sin(yaw[0])
    dx, dy = x - x[0], y - y[0]
    # R(yaw0)^T (p - p0)
    xr = c * dx + s * dy
    yr = -s * dx + c * dy
    dyaw = np.angle(np.exp(1j * (yaw - yaw[0])))
    return xr, yr, np.unwrap(dyaw)


def tum_text(t_s: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> str:
    lines = [
        f"{t:.6f} {a:.6f} {b:.6f} 0.000000 0.000000 0.000000 {np.sin(h / 2):.9f} "
        f"{np.cos(h / 2):.9f}\n"
        for t, a, b, h in zip(t_s, x, y, yaw, strict=True)
    ]
    return "".join(lines)


def read_tum(path: Path) -> np.ndarray:
    """(N, 8) rows of a TUM file."""
    rows = [
        [float(v) for v in line.split()]
        for line in Path(path).read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    return np.array(rows).reshape(-1, 8)


def write_estimated_tum(egomotion: dict[str, np.ndarray], path: Path) -> None:
    """trajectory.tum from the columns of egomotion.csv (`scenarios.metrics.read_egomotion_csv`)."""
    t = egomotion["t_s"]
    x, y, yaw = integrate_planar(t, egomotion["speed_mps"], np.radians(egomotion["yaw_rate_dps"]))
    write_text(path, tum_text(t, x, y, yaw))


def write_groundtruth_tum(gt: list[dict], path: Path) -> None:
    """groundtruth.tum from the records of groundtruth.jsonl."""
    t = np.array([g["t_s"] for g in gt])
    x, y, yaw = relative_planar(
        [g["ego"]["x_m"] for g in gt],
        [g["ego"]["y_m"] for g in gt],
        [g["ego"]["yaw_rad"] for g in gt],
    )
    write_text(path, tum_text(t, x, y, yaw))
