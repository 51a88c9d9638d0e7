"""The bench's tracking evaluation as MOTChallenge files, which TrackEval reads.

One sequence per drive. Frame f of a MOT file is the drive's frame f (1 .. N-1: frame
0 is not scored, there is no motion yet), so ``seqLength`` is N - 1. A box is the
plan-view axis-aligned extent of a vehicle's footprint (ground truth) or of a track's
box (estimates) in the ego road frame (x forward, y left, origin on the road under the
camera's viewpoint) [m], written as MOT's ``bb_left, bb_top, bb_width, bb_height`` =
``x min, y min, x extent, y extent`` (`scenarios.detection_metrics.plan_box_xywh`).
TrackEval's ``MotChallenge2DBox`` reads floats, and its IoU of these boxes is the IoU of
the plan-view extents, the similarity of the bench's ``tracking.hota_box``.

- ground truth ``gt/gt.txt``: ``frame, vehicle id, bb_left, bb_top, bb_width,
  bb_height, 1, 1, 1`` (conf 1: evaluated; class 1; visibility 1), one row per vehicle
  of the evaluation set (`scenarios.evaluate.track_frames`) per frame;
- estimates: ``frame, track id, bb_left, bb_top, bb_width, bb_height, 1, -1, -1, -1``,
  one row per track with a box per frame (rows of tracks without a box are left out, as
  they are of ``hota_box``; a track file without any box has no MOT file).

Numbers are written with Python's ``repr``: they read back as the same floats, so
TrackEval's HOTA on the files equals the bench's ``hota_box`` to the last bit.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from scenarios.detection_metrics import EvalFrame, plan_box_xywh

BENCHMARK = "omnibench"  # TrackEval's BENCHMARK of the exported sequences
SPLIT = "all"  # its SPLIT_TO_EVAL: the seqmap is seqmaps/omnibench-all.txt
TRACKER = "tracker"  # the tracker folder name of exported estimates


def sequence_name(name: str) -> str:
    """A scenario's name as a MOT sequence (folder) name: letters, digits, ``._-``."""
    return re.sub(r"[^A-Za-z0-9._-]", "-", name) or "drive"


def _line(values: Sequence) -> str:
    return ",".join(repr(float(v)) if isinstance(v, float) else str(v) for v in values)


def gt_rows(frames: Sequence[EvalFrame]) -> list[tuple]:
    """MOT ground-truth rows of the frames of `track_frames` (frames[i]: drive frame i + 1)."""
    rows = []
    for i, f in enumerate(frames):
        for g in f.gt:
            x, y, w, h = (float(v) for v in plan_box_xywh(g.footprint_xy))
            rows.append((i + 1, int(g.id), x, y, w, h, 1, 1, 1))
    return rows


def track_rows(frames: Sequence[EvalFrame]) -> list[tuple]:
    """MOT rows of the frames' hypotheses that have a box (frames[i]: drive frame i + 1)."""
    rows = []
    for i, f in enumerate(frames):
        for tid, box in zip(f.hyp_ids, f.hyp_box_xywh, strict=True):
            if np.all(np.isfinite(box)):
                x, y, w, h = (float(v) for v in box)
                rows.append((i + 1, int(tid), x, y, w, h, 1, -1, -1, -1))
    return rows


def mot_text(rows: Sequence[tuple]) -> str:
    return "".join(_line(r) + "\n" for r in rows)


def write_gt(frames: Sequence[EvalFrame], out_dir: Path, seq: str, fps: float) -> list[Path]:
    """``out_dir/<seq>/gt/gt.txt``, ``out_dir/<seq>/seqinfo.ini`` and the seqmap
    ``out_dir/seqmaps/omnibench-all.txt``: TrackEval's ``GT_FOLDER`` layout."""
    from estimator.fileio import write_text

    out_dir = Path(out_dir)
    gt_txt = out_dir / seq / "gt" / "gt.txt"
    ini = out_dir / seq / "seqinfo.ini"
    seqmap = out_dir / "seqmaps" / f"{BENCHMARK}-{SPLIT}.txt"
    for p in (gt_txt, ini, seqmap):
        p.parent.mkdir(parents=True, exist_ok=True)
    write_text(gt_txt, mot_text(gt_rows(frames)))
    write_text(
        ini,
        "; omnibench: frame f is the drive's frame f; boxes: plan-view extents [m] in the\n"
        "; ego road frame, bb_left = x min, bb_top = y min, bb_width, bb_height along x, y\n"
        f"[Sequence]\nname={seq}\nframeRate={fps:g}\nseqLength={len(frames)}\n",
    )
    write_text(seqmap, f"name\n{seq}\n")
    return [gt_txt, ini, seqmap]


def write_tracks(frames: Sequence[EvalFrame], path: Path) -> Path | None:
    """The frames' hypotheses with a box as a MOT file at path; None (and no file, an
    older one removed) when none has a box."""
    from estimator.fileio import write_text

    rows = track_rows(frames)
    path = Path(path)
    if not rows:
        path.unlink(missing_ok=True)
        return None
    write_text(path, mot_text(rows))
    return path
