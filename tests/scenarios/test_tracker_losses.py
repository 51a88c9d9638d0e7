"""Which rule of the tracker loses what the candidates found (`scenarios.tracker_losses`)."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios.detection_metrics import EvalFrame, GtVehicle
from scenarios.tracker_losses import LOSS_STATES, tracker_losses

CAR = GtVehicle(7, np.array([[10.0, 1.0], [14.5, 1.0], [14.5, 3.0], [10.0, 3.0]]))
ON = (10.0, 2.0)  # [m] on the car's near face
OFF = (20.0, 2.0)  # [m] 5.5 m beyond it: outside the 1.5-m gate


def _frames(rows):
    """(candidates, states, tracks) of rows (candidate points, their states, track points,
    ego moving)."""
    cands, states, tracks = [], [], []
    for k, (c_xy, st, t_xy, moving) in enumerate(rows):
        cands.append(EvalFrame([CAR], [(i, *p) for i, p in enumerate(c_xy)], k, moving))
        states.append(st)
        tracks.append(EvalFrame([CAR], [(1, *p) for p in t_xy], k, moving))
    return cands, states, tracks


def test_each_lost_vehicle_frame_is_counted_by_its_candidates_track_state():
    rows = [
        ([ON], ["young"], [], True),  # found, no track: lost while young
        ([ON], ["vehicle"], [ON], True),  # found by both
        ([ON], ["tentative"], [OFF], True),  # the track's point beyond the gate: lost
        ([], [], [ON], True),  # the track alone (coasting)
        ([ON], ["intermittent"], [], False),  # ego stopped: not counted
        ([ON], [""], [], True),  # no track took the candidate
        ([OFF, ON], ["vehicle", "intermittent"], [OFF], True),  # the matched one's state
    ]
    out = tracker_losses(*_frames(rows))
    assert out["frames"] == 6 and out["gt_count"] == 6
    assert out["candidates_matched"] == 5 and out["tracks_matched"] == 2
    assert out["lost_by_track_state"] == {
        "vehicle": 0, "tentative": 1, "young": 1, "intermittent": 1, "none": 1
    }  # fmt: skip
    assert out["lost"] == 4 and out["lost_share"] == pytest.approx(4 / 5)
    assert out["tracks_only"] == 1
    assert tuple(out["lost_by_track_state"]) == LOSS_STATES


def test_nothing_found_is_nothing_lost():
    out = tracker_losses(*_frames([([OFF], ["tentative"], [], True)]))
    assert out["candidates_matched"] == 0 and out["lost"] == 0
    assert np.isnan(out["lost_share"])


def test_bad_input_is_refused_with_the_frame():
    cands, states, tracks = _frames([([ON], ["young"], [], True)])
    with pytest.raises(ValueError, match="one candidates frame"):
        tracker_losses(cands, states, tracks + tracks)
    with pytest.raises(ValueError, match="frame 0 has 1 candidates but 2"):
        tracker_losses(cands, [["young", "young"]], tracks)
    with pytest.raises(ValueError, match="unknown track states"):
        tracker_losses(cands, [["lost"]], tracks)
    other = [EvalFrame([GtVehicle(8, CAR.footprint_xy)], [], 0, True)]
    with pytest.raises(ValueError, match="evaluation sets differ"):
        tracker_losses(cands, states, other)
