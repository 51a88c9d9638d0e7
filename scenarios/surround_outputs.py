"""The surround analysis' files, for a simulated drive (`scenarios.runner`) and for a
recording (`omnibench estimate`): ``tracks.csv`` (docs/FORMATS.md), ``tracks.png``,
``surround.png`` (a still of the side-by-side panels) and ``analysis.mp4`` (the panels,
frame by frame). Nothing here reads ground truth or imports the simulator.
"""

from __future__ import annotations

import csv
import io as _io
import math
import time
from pathlib import Path

import numpy as np

from estimator.fileio import atomic_write, write_png, write_text
from scenarios import visualize as viz

# tracks.csv: position [m] and ground velocity [m/s] in the ego road frame, their
# covariances (position [m^2]: `SurroundAnalyzer.track_position_cov`; velocity [(m/s)^2]:
# the Kalman filter's) and the box (centre [m], yaw [rad], length, width [m])
TRACK_STATE_COLUMNS = (
    "vx_mps", "vy_mps",
    "var_x_m2", "cov_xy_m2", "var_y_m2", "var_vx_m2ps2", "cov_vxvy_m2ps2", "var_vy_m2ps2",
)  # fmt: skip
TRACK_BOX_COLUMNS = ("box_x_m", "box_y_m", "box_yaw_rad", "box_length_m", "box_width_m")
TRACKS_CSV_COLUMNS = (
    "frame", "t_s", "track_id", "x_m", "y_m", *TRACK_STATE_COLUMNS, *TRACK_BOX_COLUMNS
)  # fmt: skip


def box_fields(box) -> tuple[float, float, float, float, float]:
    """(x, y, yaw, length, width) of a `Box`; NaN for None."""
    if box is None:
        return (math.nan,) * 5
    return (box.x_m, box.y_m, box.yaw_rad, box.length_m, box.width_m)


def box_centres(boxes: list) -> list[tuple[float, float]]:
    """Box centres (x, y) [m], NaN where a hypothesis has no box."""
    return [box_fields(b)[:2] for b in boxes]


def frame_track_rows(k: int, t_s: float, tracks: list, surround) -> list[tuple]:
    """One `TRACKS_CSV_COLUMNS` row per track of frame k at time t_s [s]; surround: the
    analyzer whose `track_box` and `track_position_cov` give a track's box and the
    covariance of its point."""
    rows = []
    for tr in tracks:
        P, C = tr.P, surround.track_position_cov(tr)
        rows.append(
            (k, t_s, tr.id, *(float(v) for v in tr.x[:4]))
            + (float(C[0, 0]), float(C[0, 1]), float(C[1, 1]))
            + (float(P[2, 2]), float(P[2, 3]), float(P[3, 3]))
            + box_fields(surround.track_box(tr))
        )
    return rows


def write_tracks_csv(path: Path, rows: list[tuple]) -> None:
    buf = _io.StringIO()
    w = csv.writer(buf)
    w.writerow(TRACKS_CSV_COLUMNS)
    for r in rows:
        w.writerow(
            [r[0], f"{r[1]:.4f}", r[2]]
            + [f"{v:.3f}" for v in r[3:7]]
            + [f"{v:.4g}" for v in r[7:13]]
            + [f"{v:.3f}" for v in r[13:18]]
        )
    write_text(path, buf.getvalue())


def panels(image, rec, sf, camera, mount, surround, gt_xy: np.ndarray | None = None) -> np.ndarray:
    """The side-by-side picture of one frame: the estimated motion, the road-compensated
    difference, the detections and the plan view with the tracks (and the true vehicles'
    centres gt_xy (N, 2) [m], when known)."""
    a = viz.motion_panel(image, rec, camera, mount.K0)
    c = viz.difference_panel(sf.detection.normalized_difference, surround.detector.valid)
    d = viz.detection_panel(image, sf)
    e = viz.surround_panel(image, surround.detector.plan, sf.tracks, gt_xy)
    return np.concatenate([a, c, d, e], axis=1)


class VideoWriter:
    """mp4 written to a temp name and renamed on close (never half-written)."""

    def __init__(self, path: Path, fps: float) -> None:
        import imageio.v2 as imageio

        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.stem}.partial.mp4")
        self._w = imageio.get_writer(
            self.tmp, fps=fps, codec="libx264", quality=7, macro_block_size=16, format="FFMPEG"
        )
        self.n = 0

    def append(self, frame: np.ndarray) -> None:
        self._w.append_data(frame)
        self.n += 1

    def close(self, keep: bool = True) -> None:
        """Finish the file; keep=False (a failed run): remove what was written."""
        self._w.close()
        if self.n and keep:
            atomic_write(self.path, lambda p: self.tmp.replace(p), suffix=".mp4")
        self.tmp.unlink(missing_ok=True)


class SurroundRecorder:
    """The surround analysis of a drive, beside its ego-motion estimate: each frame
    (`step`) goes through the analyzer with the estimate of that frame; `close` writes
    ``tracks.csv`` and ``tracks.png`` (`finish`), and ``surround.png`` (frame still_k) and
    ``analysis.mp4`` are written on the way (video=False: no video; `close` ends it
    whatever happened).

    surround: an analyzer (`estimator.surround.plugin.make_surround`) and its name; fps:
    the video's frame rate [1/s].
    """

    def __init__(
        self,
        surround,
        name: str,
        camera,
        mount,
        out_dir: Path,
        fps: float,
        still_k: int = 0,
        video: bool = True,
    ) -> None:
        self.surround, self.name = surround, name
        self.camera, self.mount = camera, mount
        self.out_dir = Path(out_dir)
        self.fps, self.video = float(fps), bool(video)
        self.still_k = int(still_k)
        self.rows: list[tuple] = []
        self.seconds: list[float] = []  # the analyzer's time per frame
        self._writer: VideoWriter | None = None  # opened at the first frame

    def step(
        self,
        k: int,
        t_s: float,
        image: np.ndarray,
        rec,
        vehicle_mask: np.ndarray | None = None,
        gt_xy: np.ndarray | None = None,
    ):
        """Frame k at t_s [s] with the estimator's record of it (x, dt_s, speed_mps,
        yaw_rate_rps); returns the analyzer's frame (None on its first). vehicle_mask: the
        analyzer's diagnostic input (`SurroundAnalyzer.step`); gt_xy: (N, 2) the true
        vehicles' centres [m] drawn in the surround map, when known."""
        masks = {"vehicle_mask": vehicle_mask} if vehicle_mask is not None else {}
        t0 = time.perf_counter()
        sf = self.surround.step(
            k, t_s, image, rec.x, rec.dt_s, rec.speed_mps, rec.yaw_rate_rps, **masks
        )
        self.seconds.append(time.perf_counter() - t0)
        if sf is None:  # the analyzer's first frame: nothing to compare with yet
            return None
        if self.video and self._writer is None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self._writer = VideoWriter(self.out_dir / "analysis.mp4", self.fps)
        self.rows += frame_track_rows(k, t_s, sf.tracks, self.surround)
        if self._writer is not None or k == self.still_k:
            pic = panels(image, rec, sf, self.camera, self.mount, self.surround, gt_xy)
            if self._writer is not None:
                self._writer.append(pic)
            if k == self.still_k:
                self.out_dir.mkdir(parents=True, exist_ok=True)
                write_png(self.out_dir / "surround.png", pic)
        return sf

    def finish(self, title: str = "") -> None:
        """Close the video and write tracks.csv and tracks.png."""
        self.close(keep=True)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        write_tracks_csv(self.out_dir / "tracks.csv", self.rows)
        viz.plot_tracks(self.rows, self.out_dir / "tracks.png", title=title)

    def close(self, keep: bool = False) -> None:
        """Close the video: kept by `finish`, removed otherwise (a run that failed);
        again: nothing."""
        if self._writer is not None:
            self._writer.close(keep=keep)
            self._writer = None

    @property
    def n_tracks(self) -> int:
        """Distinct tracks written so far."""
        return len({r[2] for r in self.rows})

    @property
    def ms_per_frame(self) -> float:
        """Median time of the analyzer's step [ms] (NaN before two frames)."""
        return 1000.0 * float(np.median(self.seconds[1:])) if len(self.seconds) > 1 else math.nan
