"""Which rule of the tracker loses the vehicles that the detector's candidates found.

The candidates and the reported tracks are each matched to the evaluation set frame by
frame, with the same gate and assignment (`scenarios.detection_metrics.match_frames`). A
vehicle-frame that a candidate matched and no track did was lost after detection; the
matched candidate's `Detection.track_state` tells by which rule (`LOSS_STATES`):

- "tentative": its track was not yet confirmed (M of N hits);
- "young": confirmed, with fewer hits than a vehicle needs;
- "intermittent": enough hits, but a hit rate below the vehicle threshold;
- "vehicle": its track is a vehicle, but the track's reported point (the filtered one)
  lies beyond the gate or went to another vehicle;
- "none": no track took the candidate (a birth refused).

The other way round, "tracks_only" counts the vehicle-frames a track matched and no
candidate did (a track coasting over a missed detection, or its filtered point nearer the
vehicle than the candidate's).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from estimator.surround.analyzer import TRACK_STATES
from scenarios.detection_metrics import EvalFrame, MetricsConfig, match_frames, ratio

LOSS_STATES = (*TRACK_STATES, "none")


def tracker_losses(
    candidates: Sequence[EvalFrame],
    states: Sequence[Sequence[str]],
    tracks: Sequence[EvalFrame],
    config: MetricsConfig | None = None,
) -> dict:
    """Over the frames where the ego car moves: the vehicle-frames the candidates matched
    and the tracks did not, by the state of the matched candidate's track.

    candidates: one `EvalFrame` per analysed frame, its hypotheses the candidates;
    states: per frame, one `Detection.track_state` per candidate ("" for none); tracks:
    the same frames' `EvalFrame` of the reported tracks (the same evaluation set).
    Returns {"frames", "gt_count", "candidates_matched", "tracks_matched", "lost",
    "lost_share" (of the candidates' matches), "lost_by_track_state" ({state: count},
    `LOSS_STATES`), "tracks_only"}.
    """
    cfg = config if config is not None else MetricsConfig()
    if not (len(candidates) == len(states) == len(tracks)):
        raise ValueError(
            f"tracker_losses: need one candidates frame, states list and tracks frame per "
            f"frame, got {len(candidates)}, {len(states)} and {len(tracks)}"
        )
    for k, (c, s, t) in enumerate(zip(candidates, states, tracks, strict=True)):
        if len(s) != len(c.hyp_xy):
            raise ValueError(
                f"tracker_losses: frame {k} has {len(c.hyp_xy)} candidates but "
                f"{len(s)} track states"
            )
        bad = set(s) - set(LOSS_STATES) - {""}
        if bad:
            raise ValueError(f"tracker_losses: frame {k}: unknown track states {sorted(bad)}")
        if not np.array_equal(c.gt_ids, t.gt_ids):
            raise ValueError(
                f"tracker_losses: frame {k}: the candidates' and the tracks' evaluation sets "
                f"differ ({c.gt_ids.tolist()} against {t.gt_ids.tolist()})"
            )
    moving = [k for k, c in enumerate(candidates) if c.ego_moving]
    _, cand_matches = match_frames([candidates[k] for k in moving], cfg)
    _, track_matches = match_frames([tracks[k] for k in moving], cfg)
    by_cand = {(i, r): c for i, r, c in cand_matches}  # (frame, vehicle) -> candidate
    by_track = {(i, r) for i, r, _ in track_matches}
    lost = dict.fromkeys(LOSS_STATES, 0)
    for (i, r), c in by_cand.items():
        if (i, r) not in by_track:
            lost[states[moving[i]][c] or "none"] += 1
    n_lost = sum(lost.values())
    return {
        "frames": len(moving),
        "gt_count": sum(len(candidates[k].gt) for k in moving),
        "candidates_matched": len(by_cand),
        "tracks_matched": len(by_track),
        "lost": n_lost,
        "lost_share": ratio(n_lost, len(by_cand)),
        "lost_by_track_state": lost,
        "tracks_only": len(by_track - set(by_cand)),
    }
