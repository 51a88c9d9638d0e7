"""The surround analysis' files (`scenarios.surround_outputs`)."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from scenarios.surround_outputs import TRACKS_CSV_COLUMNS, VideoWriter, write_tracks_csv


def test_a_video_is_kept_only_when_finished(tmp_path: Path):
    """close(keep=False), a run that failed: neither the video nor its partial file stays."""
    frame = np.full((64, 96, 3), 128, np.uint8)
    for keep in (False, True):
        out = tmp_path / str(keep)
        out.mkdir()
        w = VideoWriter(out / "analysis.mp4", 10.0)
        w.append(frame)
        w.append(frame)
        w.close(keep=keep)
        assert (out / "analysis.mp4").exists() is keep
        assert not list(out.glob(".*partial*"))


def test_tracks_csv_rows_and_a_missing_box(tmp_path: Path):
    """Columns as documented; a track without a box writes NaN box fields."""
    row = (3, 0.2, 7, 12.0, -3.5, 1.0, 0.0, 0.2, 0.0, 0.2, 4.0, 0.0, 4.0) + (math.nan,) * 5
    write_tracks_csv(tmp_path / "tracks.csv", [row])
    with open(tmp_path / "tracks.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == TRACKS_CSV_COLUMNS
    assert rows[0]["track_id"] == "7" and float(rows[0]["y_m"]) == -3.5
    assert math.isnan(float(rows[0]["box_x_m"]))
