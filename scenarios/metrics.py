"""Ground-truth metrics of the ego-motion estimate.

The estimate of frame k describes the motion from frame k-1 to k, with A the
angular displacement at k-1 (docs/CONVENTIONS.md); ground truth gives the same
quantities in ``motion_from_prev``. Speeds and yaw rates are compared in the car
frame: forward speed = (R_car_cam V)_x, yaw rate = (R_car_cam W)_z.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from estimator.camera.mount import CameraMount

STATE_COLS = ["V_x", "V_y", "V_z", "W_x", "W_y", "W_z", "A_x", "A_y", "A_z"]


def read_egomotion_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of egomotion.csv as arrays (frame as int)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return {}
    out = {
        k: np.array([float(r[k]) if r[k] != "" else np.nan for r in rows])
        for k in rows[0]
        if k != "reason"
    }
    out["reason"] = np.array([r.get("reason", "") for r in rows])
    out["frame"] = out["frame"].astype(int)
    return out


def _rmse(e: np.ndarray) -> float:
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2))) if e.size else float("nan")


def exposure_yaw_rates(gt: list[dict], mount: CameraMount, exposure_s: float) -> dict[int, float]:
    """{frame: yaw rate [deg/s]} between the exposure-mean headings of frame k-1 and k.

    A blurred frame shows the average of the images over its exposure (`sim.sensor`: at
    `exposure_times`, centred on the frame's time), so what the images can tell is the
    motion between those averages. The simulator turns the car evenly between frames
    (`sim.drive.DriveRenderer._moved`): the yaw rate is w_k over (t_k-1, t_k) and steps
    at each frame. Frame k's mean heading is then off its heading at t_k by ``c (w_k+1 -
    w_k)``, c = mean(max(tau, 0)) over the exposure's sample times tau (T / 8 for a
    continuous exposure T; 0 at the first and the last frame, which the simulator
    extrapolates). A steering step of 80 deg/s moves the motion the images show by
    1.5 deg/s at 15 fps and 10 ms, on the frames either side of it. The mean image is
    the mean pose's image only while the blur is small; on validation-rect's merge
    s1's swerve (-100 deg/s at 20 m/s: blurs of pixels) the estimates follow the
    frame-time motion instead (-100.06 deg/s; -100.17 at the frame times, -97.66 for
    the means).
    """
    from sim.sensor import exposure_times

    c = float(np.mean(np.maximum(exposure_times(exposure_s), 0.0))) if exposure_s > 0 else 0.0
    frames = sorted((g for g in gt if g["motion_from_prev"] is not None), key=lambda g: g["frame"])
    t = {g["frame"]: float(g["t_s"]) for g in gt}
    yaw_axis = mount.R_car_cam[2]  # yaw rate = (R_car_cam W)_z
    w = {
        g["frame"]: float(np.degrees(yaw_axis @ np.asarray(g["motion_from_prev"]["W_rps"])))
        for g in frames
    }

    def offset(k: int) -> float:  # [deg] mean heading of frame k minus its heading at t_k
        return c * (w[k + 1] - w[k]) if k in w and k + 1 in w else 0.0

    return {k: w[k] + (offset(k) - offset(k - 1)) / (t[k] - t[k - 1]) for k in w if k - 1 in t}


def ego_series(
    est: dict[str, np.ndarray], gt: list[dict], mount: CameraMount, exposure_s: float = 0.0
) -> dict:
    """Aligned time series (frames with both estimate and truth) in car-frame units.

    Returns t_s, speed (est, gt, prior) [m/s], yaw rate (est, gt, prior) [deg/s],
    A (est, gt) (N, 3) [deg] in car axes: roll (about the car's x), pitch (y) and the
    mount's yaw (z) of the camera's angular displacement (``R_car_cam A``; the state
    holds it in camera axes, which mix all three on a tilted or turned camera); with
    exposure_s > 0 (the frames' motion blur) also
    yaw_gt_exposure, the yaw rate between the frames' exposure-mean headings
    (`exposure_yaw_rates`).
    """
    R = mount.R_car_cam
    by_frame = {g["frame"]: g for g in gt}
    rows = [
        i
        for i, f in enumerate(est["frame"])
        if f in by_frame and by_frame[f]["motion_from_prev"] is not None
    ]
    V = np.stack([est[c][rows] for c in STATE_COLS[0:3]], axis=1)
    W = np.stack([est[c][rows] for c in STATE_COLS[3:6]], axis=1)
    A = np.stack([est[c][rows] for c in STATE_COLS[6:9]], axis=1)
    g = [by_frame[int(est["frame"][i])]["motion_from_prev"] for i in rows]
    Vg = np.array([m["V_mps"] for m in g])
    Wg = np.array([m["W_rps"] for m in g])
    Ag = np.array([m["A_rad"] for m in g])
    prior = np.array([by_frame[int(est["frame"][i])]["can_speed_mps"] for i in rows])
    extra = {}
    if exposure_s > 0:
        w_exp = exposure_yaw_rates(gt, mount, exposure_s)
        extra["yaw_gt_exposure"] = np.array([w_exp.get(int(est["frame"][i]), np.nan) for i in rows])
    return {
        "t_s": est["t_s"][rows],
        "speed_est": (V @ R.T)[:, 0],
        "speed_gt": (Vg @ R.T)[:, 0],
        "speed_prior": prior,
        "yaw_est": np.degrees((W @ R.T)[:, 2]),
        "yaw_gt": np.degrees((Wg @ R.T)[:, 2]),
        "yaw_prior": np.zeros(len(rows)),
        "A_est": np.degrees(A @ R.T),
        "A_gt": np.degrees(Ag @ R.T),
        **extra,
    }


def ego_metrics(series: dict) -> dict:
    """The ``ego`` section of metrics.json.

    ``angle_rmse_deg`` is the RMSE of A's roll and pitch (car axes x and y, over both and
    every frame): the camera's vibration, what A is estimated for; the
    mount's yaw about the car's z axis is ``angle_yaw_rmse_deg``, apart. CAN-only keeps A
    at the mount (A = 0), so its ``prior_angle_rmse_deg`` is the truth's RMS. Every RMSE
    is over the ``frames_compared`` frames whose estimate is finite; ``frames_nonfinite``
    counts the frames with truth whose estimate is NaN or infinite (`finite_estimates`).
    """
    s = finite_estimates(series)
    mean_speed = float(np.nanmean(np.abs(s["speed_gt"]))) if len(s["t_s"]) else float("nan")
    speed_rmse = _rmse(s["speed_est"] - s["speed_gt"])
    dA = s["A_est"] - s["A_gt"]  # (N, 3) [deg] roll, pitch, yaw (car axes)
    return {
        "speed_rmse_mps": speed_rmse,
        "speed_rmse_pct": 100.0 * speed_rmse / mean_speed if mean_speed > 0 else float("nan"),
        "yaw_rate_rmse_dps": _rmse(s["yaw_est"] - s["yaw_gt"]),
        "angle_rmse_deg": _rmse(dA[:, :2].ravel()),
        "prior_speed_rmse_mps": _rmse(s["speed_prior"] - s["speed_gt"]),
        "prior_yaw_rate_rmse_dps": _rmse(s["yaw_prior"] - s["yaw_gt"]),
        "prior_angle_rmse_deg": _rmse(s["A_gt"][:, :2].ravel()),
        "roll_rmse_deg": _rmse(dA[:, 0]),
        "pitch_rmse_deg": _rmse(dA[:, 1]),
        "angle_yaw_rmse_deg": _rmse(dA[:, 2]),
        # diagnostic: against the motion the blurred frames show (`exposure_yaw_rates`)
        "yaw_rate_rmse_exposure_dps": _rmse(s["yaw_est"] - s["yaw_gt_exposure"])
        if "yaw_gt_exposure" in s
        else float("nan"),
        "mean_speed_mps": mean_speed,
        "frames_compared": len(s["t_s"]),
        "frames_nonfinite": len(series["t_s"]) - len(s["t_s"]),
    }


def finite_estimates(series: dict) -> dict:
    """The frames of an `ego_series` whose estimate (speed, yaw rate and A) is finite.

    A NaN or infinite estimate has no error to square: `ego_metrics` leaves such frames
    out of every RMSE (the prior's too, so that both are over the same frames) and out of
    ``frames_compared``, and counts them in ``frames_nonfinite``.
    """
    ok = (
        np.isfinite(series["speed_est"])
        & np.isfinite(series["yaw_est"])
        & np.all(np.isfinite(series["A_est"]), axis=1)
    )
    return {k: np.asarray(v)[ok] for k, v in series.items()}


def ego_consistency(records: list, gt: list[dict], mount: CameraMount) -> dict:
    """Mean NEES of the forward speed, the yaw rate and A's roll and pitch: error² over the
    estimator's own variance (its full P, car axes), over the frames with truth; about 1
    when the covariance the estimator prints is honest, much larger when it is
    overconfident. The roll/pitch NEES is ``eᵀ S⁻¹ e / 2`` (2 dof) with S the 2 x 2 block
    of A's covariance in car axes. A frame whose variance is not finite and positive (an
    estimator that does not know it, e.g. a plug-in's NaN) is left out of that NEES."""
    R = mount.R_car_cam
    h_v, h_w = R[0], R[2]  # forward speed = h_v . V, yaw rate = h_w . W
    H_a = R[:2]  # (roll, pitch) = H_a A
    by_frame = {g["frame"]: g for g in gt}
    nv, nw, na = [], [], []
    for rec in records:
        g = by_frame.get(int(rec.frame))
        if g is None or g["motion_from_prev"] is None or not np.all(np.isfinite(rec.x)):
            continue
        m = g["motion_from_prev"]
        ev = float(h_v @ (rec.x[0:3] - np.asarray(m["V_mps"])))
        ew = float(h_w @ (rec.x[3:6] - np.asarray(m["W_rps"])))
        var_v = float(h_v @ rec.P[0:3, 0:3] @ h_v)
        var_w = float(h_w @ rec.P[3:6, 3:6] @ h_w)
        if np.isfinite(var_v) and var_v > 0:
            nv.append(ev**2 / var_v)
        if np.isfinite(var_w) and var_w > 0:
            nw.append(ew**2 / var_w)
        S = H_a @ rec.P[6:9, 6:9] @ H_a.T
        if "A_rad" in m and np.all(np.isfinite(S)) and np.linalg.det(S) > 0:
            ea = H_a @ (rec.x[6:9] - np.asarray(m["A_rad"]))
            na.append(float(ea @ np.linalg.solve(S, ea)) / 2.0)
    return {"speed_nees": _mean(nv), "yaw_rate_nees": _mean(nw), "angle_nees": _mean(na)}


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def plot_ego_errors(series: dict, path: Path, title: str = "") -> None:
    """Speed, yaw rate and A against ground truth and the CAN prior (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.fileio import atomic_write

    s = series
    fig, ax = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    t = s["t_s"]
    ax[0].plot(t, s["speed_gt"], "k-", lw=2, label="ground truth")
    ax[0].plot(t, s["speed_prior"], "-", color="tab:orange", lw=1, label="CAN prior")
    ax[0].plot(t, s["speed_est"], "-", color="tab:blue", lw=1.2, label="estimate")
    ax[0].set_ylabel("forward speed [m/s]")
    ax[0].legend(loc="best", fontsize=8)
    ax[1].plot(t, s["yaw_gt"], "k-", lw=2, label="ground truth")
    ax[1].plot(t, s["yaw_est"], "-", color="tab:blue", lw=1.2, label="estimate")
    ax[1].set_ylabel("yaw rate [deg/s]")
    for i, (name, col) in enumerate((("roll", "tab:red"), ("pitch", "tab:green"))):
        # A's roll and pitch (car axes), what the camera's vibration moves
        ax[2].plot(t, s["A_gt"][:, i], "-", color=col, lw=2, alpha=0.5, label=f"{name} truth")
        ax[2].plot(t, s["A_est"][:, i], "--", color=col, lw=1, label=f"{name} estimate")
    ax[2].set_ylabel("A, roll / pitch [deg]")
    ax[2].set_xlabel("time [s]")
    ax[2].legend(loc="best", fontsize=7, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, dpi=90), suffix=".png")
    plt.close(fig)


def plot_egomotion(
    ego: dict[str, np.ndarray], can_speed_mps: np.ndarray, path: Path, title: str = ""
) -> None:
    """A recording's estimate against time (PNG): forward speed beside the CAN speed and
    yaw rate, frames whose images could not be used marked.

    ego: `read_egomotion_csv` columns; can_speed_mps: (N,) the CAN speed at each frame's
    time (NaN where none)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.fileio import atomic_write

    t = ego["t_s"]
    bad = ego["degraded"] > 0
    fig, ax = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    ax[0].plot(t, can_speed_mps, "-", color="tab:orange", lw=1, label="CAN")
    ax[0].plot(t, ego["speed_mps"], "-", color="tab:blue", lw=1.2, label="estimate")
    ax[0].set_ylabel("forward speed [m/s]")
    ax[1].plot(t, ego["yaw_rate_dps"], "-", color="tab:blue", lw=1.2, label="estimate")
    ax[1].set_ylabel("yaw rate [deg/s]")
    ax[1].set_xlabel("time [s]")
    for a, col in ((ax[0], "speed_mps"), (ax[1], "yaw_rate_dps")):
        if bad.any():
            a.plot(t[bad], ego[col][bad], "x", color="tab:red", ms=5, label="images not used")
        a.legend(loc="best", fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, dpi=90), suffix=".png")
    plt.close(fig)
