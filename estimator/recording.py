"""Inputs of the estimator from a recording: video frames, timestamps, CAN speed.

This is the entry point for real data, so everything is validated: a missing
file, an unreadable video, a CAN file without the expected columns, NaN or
negative speeds and non-increasing timestamps are reported with the file, the
row and the value. A NaN speed *inside* the recording is allowed (a dropped
CAN message): the estimator then runs on its own prediction and flags it.
"""

from __future__ import annotations

import csv
import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np


class RecordingError(ValueError):
    """A recording input that cannot be used; the message names file, row and value."""


@dataclass(frozen=True)
class CanTrack:
    """CAN speed messages: t_s (M,) increasing [s], speed_mps (M,) [m/s] (NaN = lost)."""

    t_s: np.ndarray
    speed_mps: np.ndarray

    def at(self, t_query_s: float, max_age_s: float = 0.5) -> float:
        """Latest speed at or before t_query_s; NaN when none is fresher than max_age_s."""
        i = int(np.searchsorted(self.t_s, t_query_s + 1e-9, side="right")) - 1
        if i < 0 or t_query_s - self.t_s[i] > max_age_s:
            return math.nan
        return float(self.speed_mps[i])


def read_can_csv(path: str | Path) -> CanTrack:
    """CSV with header ``t_s,speed_mps`` (extra columns ignored)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"CAN file not found: {path}")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        cols = reader.fieldnames or []
        missing = [c for c in ("t_s", "speed_mps") if c not in cols]
        if missing:
            raise RecordingError(f"{path}: missing column(s) {missing}; found {cols}")
        t, v = [], []
        for row_no, row in enumerate(reader, start=2):
            try:
                ti = float(row["t_s"])
                vi = float(row["speed_mps"]) if row["speed_mps"].strip() else math.nan
            except (TypeError, ValueError):
                raise RecordingError(
                    f"{path}: row {row_no}: not a number (t_s={row['t_s']!r}, "
                    f"speed_mps={row['speed_mps']!r})"
                ) from None
            if not math.isfinite(ti):
                raise RecordingError(f"{path}: row {row_no}: t_s is {ti}")
            if t and ti <= t[-1]:
                raise RecordingError(
                    f"{path}: row {row_no}: t_s={ti} does not increase (previous {t[-1]})"
                )
            if vi < 0 or vi > 150:
                raise RecordingError(f"{path}: row {row_no}: speed_mps={vi} out of 0..150")
            t.append(ti)
            v.append(vi)
    if not t:
        raise RecordingError(f"{path}: no CAN rows")
    return CanTrack(np.array(t), np.array(v))


def read_timestamps_csv(path: str | Path) -> np.ndarray:
    """CSV with header ``frame,t_s``: (N,) increasing frame times [s]."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"timestamps file not found: {path}")
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        if "t_s" not in (reader.fieldnames or []):
            raise RecordingError(f"{path}: missing column 't_s'; found {reader.fieldnames}")
        t = []
        for row_no, row in enumerate(reader, start=2):
            try:
                t.append(float(row["t_s"]))
            except ValueError:
                raise RecordingError(f"{path}: row {row_no}: t_s={row['t_s']!r}") from None
    t = np.array(t)
    if len(t) and (not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0)):
        raise RecordingError(f"{path}: timestamps must be finite and increasing")
    return t


def _iter_images(files: list[Path], flags: int, what: str) -> Iterator[np.ndarray]:
    """cv2.imread of each file (flags), in order; an unreadable one is named."""
    for p in files:
        img = cv2.imread(str(p), flags)
        if img is None:
            raise RecordingError(f"{p}: unreadable {what}")
        yield img


def _image_files(folder: Path, suffixes: tuple[str, ...], what: str) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)
    if not files:
        raise RecordingError(f"{folder}: no {what} in this folder")
    return files


def iter_road_masks(folder: str | Path) -> Iterator[np.ndarray]:
    """(H, W) bool road masks (non-zero = road), one PNG per frame in name order.

    For a road segmentation computed elsewhere (`estimator.egomotion.direct` lets its points off
    the road tell the rotation only); the estimator checks each mask's size.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(f"road mask folder not found: {folder}")
    files = _image_files(folder, (".png",), "PNG road masks")
    for m in _iter_images(files, cv2.IMREAD_GRAYSCALE, "road mask"):
        yield m > 0


def iter_frames(source: str | Path) -> Iterator[np.ndarray]:
    """RGB frames (H, W, 3) uint8 of a video file or of a folder of PNG/JPEG images."""
    source = Path(source)
    if source.is_dir():
        files = _image_files(source, (".png", ".jpg", ".jpeg"), "PNG/JPEG frames")
        for img in _iter_images(files, cv2.IMREAD_COLOR, "image"):
            yield img[..., ::-1]
        return
    if not source.is_file():
        raise RecordingError(f"video not found: {source}")
    cap = cv2.VideoCapture(str(source))
    if not cap.isOpened():
        raise RecordingError(f"{source}: cannot open as a video")
    try:
        n = 0
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            n += 1
            yield frame[..., ::-1]
        if n == 0:
            raise RecordingError(f"{source}: the video has no readable frames")
    finally:
        cap.release()


def count_frames(source: str | Path) -> int | None:
    """Number of frames of a folder of PNG/JPEG images (its image files) or of a video (the
    count its container states, which some formats only estimate); None when unknown."""
    source = Path(source)
    if source.is_dir():
        return len(_image_files(source, (".png", ".jpg", ".jpeg"), "PNG/JPEG frames"))
    if not source.is_file():
        raise RecordingError(f"video not found: {source}")
    cap = cv2.VideoCapture(str(source))
    n = cap.get(cv2.CAP_PROP_FRAME_COUNT) if cap.isOpened() else 0.0
    cap.release()
    return int(n) if n and math.isfinite(n) and n > 0 else None


def frame_times(fps: float) -> Iterator[float]:
    """Times [s] of frames 0, 1, 2, ... at ``fps`` [Hz] (> 0), without end: as many as the
    recording has frames, whatever its length. RecordingError at once for a bad rate."""
    if not (math.isfinite(fps) and fps > 0):
        raise RecordingError(f"frame rate must be finite and > 0, got {fps}")
    return (k / fps for k in itertools.count())


def video_fps(source: str | Path) -> float | None:
    """Frame rate stored in a video file (None for a folder or when unknown)."""
    source = Path(source)
    if source.is_dir():
        return None
    cap = cv2.VideoCapture(str(source))
    fps = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
    cap.release()
    return float(fps) if fps and math.isfinite(fps) and fps > 0 else None
