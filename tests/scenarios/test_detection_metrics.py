"""Detection / tracking / localisation metrics against hand counts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.surround.tracking import Tracker
from scenarios.detection_metrics import (
    MOTION_CLASSES,
    SIZE_CLASSES,
    EvalFrame,
    GtVehicle,
    MetricsConfig,
    box_footprint,
    box_iou_xywh,
    breakdown,
    evaluate,
    hypotheses_from_tracks,
    motion_class,
    nearest_footprint_point,
    plan_box_xywh,
    point_footprint_distance,
    recall_by_bearing,
    recall_by_range,
    recall_polar,
    sector,
)

SECTIONS = {
    "detection": {"recall", "precision", "gt_count", "matched"},
    "tracking": {"mota", "idf1", "hota", "id_switches", "hota_box", "deta_box", "assa_box"},
    "localization": {
        "median_error_m", "p90_error_m", "centre_median_error_m", "centre_p90_error_m",
        "offset_median_error_m",
    },
}  # fmt: skip


def car(vid: int, x: float, y: float, yaw: float = 0.0) -> GtVehicle:
    return GtVehicle.from_box(vid, x, y, 4.0, 2.0, yaw)


def seen(g: GtVehicle, hid: int, offset=(0.0, 0.0)) -> tuple[int, float, float]:
    """Hypothesis at the vehicle's point nearest to the camera (+ offset)."""
    p = nearest_footprint_point(g.footprint_xy) + offset
    return (hid, float(p[0]), float(p[1]))


def two_cars(k: int) -> list[GtVehicle]:
    """Vehicle 1 ahead-left moving forward, vehicle 2 behind-right; 0.5 m per frame."""
    return [car(1, 8.0 + 0.5 * k, 4.0), car(2, -10.0 + 0.5 * k, -4.0)]


# ------------------------------------------------------------------ geometry
def test_point_inside_footprint_has_distance_zero():
    g = car(1, 10.0, 0.0, yaw=0.4)
    inside = np.array([[10.0, 0.0], [10.5, 0.3], *g.footprint_xy])  # centre, interior, corners
    np.testing.assert_array_equal(point_footprint_distance(inside, g.footprint_xy), 0.0)
    # a clockwise footprint is also a footprint
    np.testing.assert_array_equal(point_footprint_distance(inside, g.footprint_xy[::-1]), 0.0)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-30, 30),
    st.floats(-30, 30),
    st.floats(-math.pi, math.pi),
    st.floats(-10, 10),
    st.floats(-10, 10),
)
def test_point_footprint_distance_matches_box_formula(cx, cy, yaw, px, py):
    """In the box's own axes the distance is hypot(max(|u| - L/2, 0), max(|v| - W/2, 0))."""
    g = GtVehicle.from_box(0, cx, cy, 4.0, 2.0, yaw)
    p = np.array([cx + px, cy + py])
    c, s = math.cos(yaw), math.sin(yaw)
    u, v = c * px + s * py, -s * px + c * py
    ref = math.hypot(max(abs(u) - 2.0, 0.0), max(abs(v) - 1.0, 0.0))
    assert point_footprint_distance(p, g.footprint_xy)[0] == pytest.approx(ref, abs=1e-9)


def test_nearest_footprint_point():
    # box 8..12 x -1..1 ahead: the nearest point to the camera is (8, 0)
    np.testing.assert_allclose(nearest_footprint_point(car(1, 10.0, 0.0).footprint_xy), [8, 0])
    # box ahead-left: its rear-right corner
    np.testing.assert_allclose(nearest_footprint_point(car(1, 10.0, 5.0).footprint_xy), [8, 4])


# ------------------------------------------------------------------ evaluate
def test_perfect_hypotheses_score_one():
    frames = [
        EvalFrame(
            two_cars(k),
            [seen(g, 10 + g.id) for g in two_cars(k)],
            centres=[tuple(g.footprint_xy.mean(axis=0)) for g in two_cars(k)],
            boxes=[(*g.footprint_xy.mean(axis=0), 0.0, 4.0, 2.0) for g in two_cars(k)],
        )
        for k in range(10)
    ]
    m = evaluate(frames)
    for sec, keys in SECTIONS.items():
        assert set(m[sec]) == keys
    assert m["detection"] == {"recall": 1.0, "precision": 1.0, "gt_count": 20, "matched": 20}
    assert m["tracking"]["mota"] == 1.0 and m["tracking"]["idf1"] == 1.0
    assert m["tracking"]["hota"] == pytest.approx(1.0) and m["tracking"]["id_switches"] == 0
    assert m["tracking"]["hota_box"] == pytest.approx(1.0) and m["counts"]["box_hyp_count"] == 20
    assert m["localization"] == {
        "median_error_m": 0.0,
        "p90_error_m": 0.0,
        "centre_median_error_m": 0.0,
        "centre_p90_error_m": 0.0,
        "offset_median_error_m": 0.0,
    }
    assert m["gate_m"] == 1.5 and m["nan_reasons"] == {}


def test_box_centre_error_of_matched_hypotheses_with_a_box():
    """Centre error: a matched hypothesis's box centre to the footprint's centre; a
    hypothesis without a box (NaN) and an unmatched one do not count."""
    a, b = car(1, 10.0, 0.0), car(2, -10.0, 4.0)
    f = EvalFrame(
        [a, b],
        [(5, 7.5, 0.0), (6, -7.5, 3.5), (7, 30.0, 0.0)],
        centres=[(11.0, 0.5), (math.nan, math.nan), (31.0, 0.0)],
    )
    m = evaluate([f])
    assert m["detection"]["matched"] == 2 and m["counts"]["centre_pairs"] == 1
    assert m["localization"]["centre_median_error_m"] == pytest.approx(math.hypot(1.0, 0.5))
    # the point 0.5 m short of the rear face's middle (8, 0), the box 3.5 m beyond the
    # point where the centre is 2 m beyond that face point: the box adds (1.5, 0.5)
    assert m["localization"]["offset_median_error_m"] == pytest.approx(math.hypot(1.5, 0.5))
    none = evaluate([EvalFrame([a], [(5, 7.5, 0.0)])])
    assert math.isnan(none["localization"]["centre_median_error_m"])
    assert "localization.centre_median_error_m" in none["nan_reasons"]
    assert "localization.offset_median_error_m" in none["nan_reasons"]
    with pytest.raises(ValueError, match="1 box centres for 3 hypotheses"):
        EvalFrame([a], [(5, 7.5, 0.0), (6, 1.0, 1.0), (7, 2.0, 2.0)], centres=[(1.0, 1.0)])


def test_box_iou_is_trackevals_to_the_bit():
    """`box_iou_xywh` against TrackEval's own IoU (MotChallenge2DBox's, ``xywh``), boxes of
    random rotated footprints, touching and empty boxes included."""
    from trackeval.datasets._base_dataset import _BaseDataset

    rng = np.random.default_rng(3)
    boxes = [
        plan_box_xywh(box_footprint(*rng.uniform(-20, 20, 2), *rng.uniform(1, 5, 2), a))
        for a in rng.uniform(-math.pi, math.pi, 40)
    ]
    a = np.array(boxes[:25] + [[0.0, 0.0, 0.0, 1.0]])  # the last: no area
    b = np.array(boxes[25:] + [[a[0, 0] + a[0, 2], a[0, 1], 2.0, 2.0]])  # the last: touches
    ours = box_iou_xywh(a, b)
    assert np.array_equal(ours, _BaseDataset._calculate_box_ious(a, b, box_format="xywh"))
    assert (ours > 0).sum() >= 3 and ours[-1].max() == 0.0 and ours[0, -1] == 0.0
    # plan view of a 4 x 2 car turned 90 deg: 2 x 4
    assert plan_box_xywh(box_footprint(10.0, 0.0, 4.0, 2.0, math.pi / 2)) == pytest.approx(
        [9.0, -2.0, 2.0, 4.0]
    )


def test_box_hota_scores_box_overlap_and_is_nan_without_boxes():
    """A box shifted by half its length overlaps 1/3 (IoU): matched at alpha <= 1/3 only;
    hypotheses without a box are left out; none with a box: NaN with the reason."""
    g = car(1, 10.0, 0.0)  # 4 x 2 along x
    frames = [
        EvalFrame([g], [seen(g, 5), (6, 0.0, 9.0)], boxes=[(12.0, 0.0, 0.0, 4.0, 2.0)] + [
            (math.nan,) * 5
        ])
        for _ in range(4)
    ]  # fmt: skip
    m = evaluate(frames)
    assert m["counts"]["box_hyp_count"] == 4
    alphas = np.arange(0.05, 0.99, 0.05)
    assert m["tracking"]["deta_box"] == pytest.approx(np.mean(alphas <= 1 / 3))
    assert m["tracking"]["assa_box"] == pytest.approx(np.mean(alphas <= 1 / 3))
    assert m["tracking"]["hota_box"] == pytest.approx(np.mean(alphas <= 1 / 3))
    none = evaluate([EvalFrame([g], [seen(g, 5)])])
    assert math.isnan(none["tracking"]["hota_box"]) and math.isfinite(none["tracking"]["hota"])
    assert none["nan_reasons"]["tracking.hota_box"] == "no hypothesis with a box"
    with pytest.raises(ValueError, match="1 boxes for 2 hypotheses"):
        EvalFrame([g], [(5, 7.5, 0.0), (6, 1.0, 1.0)], boxes=[(1.0, 1.0, 0.0, 4.0, 2.0)])


def test_swapped_id_counts_one_switch():
    # one vehicle, 10 frames, hypothesis id 7 then 8 from frame 5
    frames = [
        EvalFrame([car(1, 10.0, 3.0)], [seen(car(1, 10.0, 3.0), 7 if k < 5 else 8)])
        for k in range(10)
    ]
    m = evaluate(frames)
    assert m["tracking"]["id_switches"] == 1
    # hand count: best id pairing 1<->7: IDTP = 5, IDFN = 5, IDFP = 5 -> 10 / 20
    assert m["tracking"]["idf1"] == pytest.approx(0.5)
    assert m["tracking"]["mota"] == pytest.approx(1 - 1 / 10)  # one switch over 10 gt
    assert m["tracking"]["hota"] < 1.0
    assert m["detection"]["recall"] == 1.0


def test_missed_vehicle_lowers_recall_by_hand_count():
    frames = []
    for k in range(10):
        gts = two_cars(k)
        hyps = [seen(g, g.id) for g in gts if not (g.id == 2 and k < 3)]  # 2 missed 3 times
        frames.append(EvalFrame(gts, hyps))
    m = evaluate(frames)
    assert m["detection"]["gt_count"] == 20 and m["detection"]["matched"] == 17
    assert m["detection"]["recall"] == 17 / 20
    assert m["detection"]["precision"] == 1.0
    assert m["counts"]["misses"] == 3 and m["counts"]["false_positives"] == 0


def test_beyond_gate_is_false_positive():
    g = car(1, 10.0, 0.0)  # rear edge at x = 8
    far = EvalFrame([g], [(5, 8.0 - 1.6, 0.0)])  # 1.6 m from the footprint
    m = evaluate([far], MetricsConfig(gate_m=1.5))
    assert m["detection"]["matched"] == 0 and m["detection"]["precision"] == 0.0
    assert m["counts"]["false_positives"] == 1 and m["counts"]["mot_false_positives"] == 1
    assert m["counts"]["mot_misses"] == 1
    assert math.isnan(m["localization"]["median_error_m"])
    assert "localization.median_error_m" in m["nan_reasons"]
    near = EvalFrame([g], [(5, 8.0 - 1.4, 0.0)])
    m = evaluate([near], MetricsConfig(gate_m=1.5))
    assert m["detection"]["matched"] == 1
    assert m["localization"]["median_error_m"] == pytest.approx(1.4)


def test_mota_cross_check_by_hand():
    g1, g2 = car(1, 10.0, 5.0), car(2, -10.0, -5.0)
    frames = [
        EvalFrame([g1, g2], [seen(g1, 100), seen(g2, 200)]),  # 2 matches
        EvalFrame([g1, g2], [seen(g1, 100), (300, 0.0, 30.0)]),  # g2 missed, 300 false
        EvalFrame([g1, g2], [seen(g1, 200), seen(g2, 100)]),  # both change id: 2 switches
    ]
    m = evaluate(frames)
    fn, fp, idsw, gt = 1, 1, 2, 6
    assert m["tracking"]["id_switches"] == idsw
    assert m["counts"]["mot_misses"] == fn and m["counts"]["mot_false_positives"] == fp
    assert m["tracking"]["mota"] == pytest.approx(1 - (fn + fp + idsw) / gt)
    assert m["detection"]["recall"] == 5 / 6 and m["detection"]["precision"] == 5 / 6


def test_hota_uses_distance_similarity():
    # every hypothesis 0.7 m outside the footprint: similarity 1 - 0.7/1.5 = 0.533,
    # a match at the 10 alphas 0.05 ... 0.50 (HOTA = 1 there), none at the 9 above
    g = car(1, 10.0, 0.0)
    frames = [EvalFrame([g], [(1, 8.0 - 0.7, 0.0)]) for _ in range(5)]
    m = evaluate(frames)
    assert m["tracking"]["hota"] == pytest.approx(10 / 19)
    assert m["tracking"]["mota"] == 1.0  # motmetrics: inside the gate is a match


def test_empty_frames_and_zero_gt():
    g = car(1, 10.0, 0.0)
    frames = [EvalFrame([], []), EvalFrame([g], [seen(g, 1)]), EvalFrame([], [])]
    m = evaluate(frames)
    assert m["detection"]["recall"] == 1.0 and m["tracking"]["mota"] == 1.0
    assert m["counts"]["empty_frames"] == 2

    m = evaluate([EvalFrame([], []), EvalFrame([], [])])
    assert math.isnan(m["detection"]["recall"]) and math.isnan(m["tracking"]["hota"])
    assert math.isnan(m["detection"]["precision"]) and math.isnan(m["tracking"]["mota"])
    assert m["nan_reasons"]["tracking.mota"] == "no ground-truth vehicle"
    assert m["nan_reasons"]["detection.precision"] == "no hypothesis"

    m = evaluate([EvalFrame([], [(1, 5.0, 5.0)])])  # zero gt, one false alarm
    assert m["detection"]["precision"] == 0.0 and math.isnan(m["tracking"]["idf1"])

    m = evaluate([EvalFrame([g], [])])  # a vehicle, no hypothesis at all
    assert m["detection"]["recall"] == 0.0 and m["tracking"]["hota"] == 0.0
    assert m["tracking"]["mota"] == 0.0
    assert evaluate([])["counts"]["frames"] == 0


def test_recall_by_range_and_bearing():
    ahead, left, behind = car(1, 6.0, 0.0), car(2, 0.0, 11.0, math.pi / 2), car(3, -22.0, 0.0)
    # nearest points: (4, 0) range 4 bearing 0; (0, 9) range 9 bearing 90; (-20, 0) range 20, 180
    frames = [EvalFrame([ahead, left, behind], [seen(ahead, 1), seen(behind, 3)])]
    r = recall_by_range(frames, [0, 5, 10, 30, 50])
    assert r["gt_count"] == [1, 1, 1, 0] and r["matched"] == [1, 0, 1, 0]
    assert r["recall"][:3] == [1.0, 0.0, 1.0] and math.isnan(r["recall"][3])
    b = recall_by_bearing(frames, [-180, -45, 45, 135, 180])
    assert b["gt_count"] == [0, 1, 1, 1] and b["recall"][1:] == [1.0, 0.0, 1.0]
    with pytest.raises(ValueError, match="increasing"):
        recall_by_range(frames, [10, 5])


def test_tracker_output_scores_well():
    """End to end: the tracker's confirmed tracks on a noiseless two-car scene."""
    tr = Tracker()
    frames = []
    for k in range(30):
        gts = two_cars(k)
        z = np.array([nearest_footprint_point(g.footprint_xy) for g in gts])
        tracks = tr.step(k * 0.1, z, 0.0, 0.0)
        frames.append(EvalFrame(gts, hypotheses_from_tracks(tracks), t_s=k * 0.1))
    m = evaluate(frames)
    assert m["tracking"]["id_switches"] == 0 and m["detection"]["precision"] == 1.0
    assert m["detection"]["matched"] == 2 * (30 - 2)  # confirmed from the 3rd frame on
    assert m["localization"]["median_error_m"] < 0.01
    # vehicle 2 passes abeam (frames 16-24): its nearest point stays at x = 0 while
    # the car moves on, a manoeuvre of the reported point the constant-velocity
    # model follows with a lag (overshoot 0.4 m, measured here)
    assert 0.2 < m["localization"]["p90_error_m"] < 0.5


def test_bad_input():
    with pytest.raises(ValueError, match="duplicate hypothesis ids"):
        EvalFrame([car(1, 5, 0)], [(1, 0.0, 0.0), (1, 1.0, 1.0)])
    with pytest.raises(ValueError, match="duplicate ground-truth ids"):
        EvalFrame([car(1, 5, 0), car(1, 9, 0)], [])
    with pytest.raises(ValueError, match=r"\(4, 2\)"):
        GtVehicle(1, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="gate_m"):
        MetricsConfig(gate_m=0.0)


# ------------------------------------------------------------------ where detection fails
@pytest.mark.parametrize(
    ("speed", "yaw_deg", "ego_speed", "expected"),
    [
        (0.2, 0.0, 20.0, "stationary"),
        (0.2, 0.0, 0.0, "stationary"),
        (20.5, 0.0, 20.0, "co-moving"),
        (0.0 + 0.6, 90.0, 0.0, "co-moving"),  # both nearly still: within 1 m/s
        (25.0, 0.0, 20.0, "overtaking"),
        (15.0, 10.0, 20.0, "overtaken"),
        (20.0, 180.0, 20.0, "oncoming"),
        (10.0, -90.0, 20.0, "crossing"),
        (10.0, 120.0, 0.0, "crossing"),
    ],
)
def test_motion_class_of_hand_made_cases(speed, yaw_deg, ego_speed, expected):
    assert motion_class(speed, math.radians(yaw_deg), ego_speed, 0.0) == expected


@settings(max_examples=60, deadline=None)
@given(
    st.floats(0.0, 40.0),
    st.floats(-math.pi, math.pi),
    st.floats(0.0, 40.0),
    st.floats(-math.pi, math.pi),
)
def test_motion_class_does_not_depend_on_the_world_heading(speed, yaw, ego_speed, turn):
    a = motion_class(speed, yaw, ego_speed, 0.0)
    assert a in MOTION_CLASSES
    assert motion_class(speed, yaw + turn, ego_speed, turn) == a


def test_sectors_split_the_bearings_at_45_and_135_degrees():
    assert [sector(b) for b in (0.0, 44.9, 45.0, 134.9, 135.0, -135.0, -134.9, -45.0, -44.9)] == [
        "front", "front", "left", "left", "rear", "rear", "right", "right", "front",
    ]  # fmt: skip


def test_breakdown_counts_by_band_sector_motion_and_ego_state():
    ahead = GtVehicle.from_box(1, 8.0, 0.0, 4.0, 2.0, 0.0)  # nearest point 6 m ahead
    ahead = GtVehicle(1, ahead.footprint_xy, "overtaken")
    left = GtVehicle(2, GtVehicle.from_box(2, 0.0, 4.0, 4.0, 2.0, 0.0).footprint_xy, "co-moving")
    behind = GtVehicle(3, GtVehicle.from_box(3, -20.0, 0.0, 4.0, 2.0, 0.0).footprint_xy, "crossing")
    frames = [
        # moving: ahead and left found, behind missed, one false alarm on the right at 3 m
        EvalFrame([ahead, left, behind], [seen(ahead, 10), seen(left, 11), (12, 0.0, -3.0)]),
        # stopped: only the left one, found
        EvalFrame([left], [seen(left, 11)], ego_moving=False),
    ]
    b = breakdown(frames)
    bands = b["range_bands"]
    assert bands["5-10 m"] == {
        "gt_count": 1, "matched": 1, "hyp_count": 1, "hyp_matched": 1,
        "recall": 1.0, "precision": 1.0,
    }  # fmt: skip
    assert bands["0-5 m"]["gt_count"] == 2 and bands["0-5 m"]["matched"] == 2
    assert bands["0-5 m"]["hyp_count"] == 3 and bands["0-5 m"]["precision"] == pytest.approx(2 / 3)
    assert bands["15-25 m"]["gt_count"] == 1 and bands["15-25 m"]["recall"] == 0.0
    assert math.isnan(bands["15-25 m"]["precision"])  # no hypothesis there
    sec = b["sectors"]
    assert (sec["front"]["recall"], sec["left"]["gt_count"], sec["rear"]["recall"]) == (1.0, 2, 0.0)
    assert sec["right"]["hyp_count"] == 1 and sec["right"]["precision"] == 0.0
    assert math.isnan(sec["right"]["recall"])
    mo = b["motion"]
    assert (mo["co-moving"]["gt_count"], mo["co-moving"]["recall"]) == (2, 1.0)
    assert mo["crossing"]["recall"] == 0.0 and mo["overtaken"]["recall"] == 1.0
    assert "unknown" not in mo
    ego = b["ego_state"]
    assert ego["moving"]["frames"] == 1 and ego["stopped"]["frames"] == 1
    assert ego["moving"]["detection"]["recall"] == pytest.approx(2 / 3)
    assert ego["moving"]["detection"]["precision"] == pytest.approx(2 / 3)
    assert ego["stopped"]["detection"]["recall"] == 1.0
    # the breakdowns over each state's frames: the left vehicle once in each
    mo_moving, mo_stopped = ego["moving"]["motion"], ego["stopped"]["motion"]
    assert (mo_moving["co-moving"]["gt_count"], mo_moving["crossing"]["gt_count"]) == (1, 1)
    assert mo_moving["crossing"]["recall"] == 0.0 and mo_moving["overtaken"]["recall"] == 1.0
    assert (mo_stopped["co-moving"]["gt_count"], mo_stopped["co-moving"]["recall"]) == (1, 1.0)
    assert mo_stopped["crossing"]["gt_count"] == 0
    assert ego["moving"]["range_bands"]["15-25 m"]["gt_count"] == 1
    assert ego["moving"]["range_bands"]["0-5 m"]["hyp_count"] == 2
    assert ego["stopped"]["range_bands"]["0-5 m"]["gt_count"] == 1
    assert ego["stopped"]["sectors"]["left"]["recall"] == 1.0
    # sizes unknown (vehicles made without their pixels): all in the "unknown" class
    assert b["sizes"]["unknown"] == {"gt_count": 4, "matched": 3, "recall": 0.75}
    assert b["sizes"]["small"]["gt_count"] == 0 and math.isnan(b["sizes"]["small"]["recall"])


def test_breakdown_by_apparent_size_uses_cocos_area_ranges():
    """COCO's area ranges (pycocotools): small below 32^2 px, medium up to 96^2, large."""
    assert SIZE_CLASSES == {
        "small": (0.0, 1024.0), "medium": (1024.0, 9216.0), "large": (9216.0, 1e10),
    }  # fmt: skip

    def sized(i, x, px):
        return GtVehicle(i, car(i, x, 0.0).footprint_xy, visible_px=px)

    small, medium = sized(1, 22.0, 300), sized(2, 12.0, 5000)
    edge, large = sized(3, -12.0, 1024), sized(4, 6.0, 20000)
    frames = [
        EvalFrame([small, medium, edge, large], [seen(medium, 1), seen(large, 2)]),
        EvalFrame([small, large], [seen(small, 3)], ego_moving=False),
    ]
    b = breakdown(frames)
    sizes = b["sizes"]
    assert list(sizes) == ["small", "medium", "large"]  # none unknown: no such class
    assert sizes["small"] == {"gt_count": 2, "matched": 1, "recall": 0.5}
    assert sizes["medium"] == {"gt_count": 2, "matched": 1, "recall": 0.5}  # 1024 px: medium
    assert sizes["large"] == {"gt_count": 2, "matched": 1, "recall": 0.5}
    moving = b["ego_state"]["moving"]["sizes"]
    assert (moving["small"]["recall"], moving["large"]["recall"]) == (0.0, 1.0)
    with pytest.raises(ValueError, match="GtVehicle 5: visible_px must be >= 0 or NaN, got -1"):
        GtVehicle(5, small.footprint_xy, visible_px=-1)


def test_candidates_are_counted_without_ids_by_band_and_ego_state():
    """A detector's candidates: recall and precision per frame's matching, whatever the
    ids (a candidate has none across frames), by range band and ego state."""
    ahead = car(1, 8.0, 0.0)  # nearest point 6 m ahead
    far = car(2, 22.0, 3.0)  # nearest point ~20 m ahead
    frames = [
        # moving: ahead found twice over (one duplicate), far missed, clutter at 30 m
        EvalFrame([ahead, far], [(0, 6.0, 0.0), (1, 6.5, 0.3), (2, 30.0, -8.0)]),
        # moving: both found; ids restart in every frame
        EvalFrame([ahead, far], [(0, 6.1, 0.0), (1, 20.2, 3.0)]),
        # stopped: ahead missed, no candidate
        EvalFrame([ahead], [], ego_moving=False),
    ]
    c = breakdown(frames, tracked=False)
    assert c["detection"] == {
        "recall": 0.6, "precision": 0.6, "gt_count": 5, "matched": 3, "hyp_count": 5,
    }  # fmt: skip
    moving = c["ego_state"]["moving"]
    assert moving["frames"] == 2 and moving["detection"]["recall"] == 0.75
    assert moving["range_bands"]["5-10 m"]["recall"] == 1.0
    assert moving["range_bands"]["15-25 m"]["recall"] == 0.5
    stopped = c["ego_state"]["stopped"]
    assert stopped["detection"]["recall"] == 0.0 and math.isnan(stopped["detection"]["precision"])
    u = c["unmatched"]
    assert (u["duplicate"], u["clutter"]) == (1, 1)
    assert "tracking" not in c and "tracking" not in moving  # no tracks to score


def test_unmatched_hypotheses_split_into_duplicate_misplaced_and_clutter():
    ahead = GtVehicle.from_box(1, 10.0, 0.0, 4.0, 2.0, 0.0)  # footprint x 8..12, y -1..1
    frames = [
        EvalFrame(
            [ahead],
            [
                (1, 8.0, 0.0),  # matched (on the footprint)
                (2, 7.0, 0.5),  # 1.0 m off, the vehicle already matched: duplicate
                (3, 8.5, 4.0),  # 3.0 m beside it: misplaced
                (4, 10.0, 6.9),  # 5.9 m: clutter
            ],
        ),
        EvalFrame([], [(5, 3.0, 3.0)]),  # no vehicle in the frame: clutter
    ]
    u = breakdown(frames)["unmatched"]
    assert (u["hyp_count"], u["unmatched"]) == (5, 4)
    assert (u["duplicate"], u["misplaced"], u["clutter"]) == (1, 1, 2)
    assert u["clutter_share"] == pytest.approx(0.5)
    none_unmatched = breakdown([EvalFrame([ahead], [(1, 8.0, 0.0)])])["unmatched"]
    assert none_unmatched["unmatched"] == 0 and math.isnan(none_unmatched["clutter_share"])


def test_recall_polar_places_each_vehicle_once_by_range_and_bearing():
    ahead, left = car(1, 8.0, 0.0), car(2, 0.0, 4.0)
    frames = [EvalFrame([ahead, left], [seen(ahead, 10)]), EvalFrame([left], [])]
    p = recall_polar(frames, [0.0, 5.0, 10.0], [-180.0, -90.0, 0.0, 90.0, 180.0])
    gt, hit = np.array(p["gt_count"]), np.array(p["matched"])
    assert gt.sum() == 3 and hit.sum() == 1
    assert gt[0, 3] == 2 and hit[0, 3] == 0  # left: nearest point (0, 3), bearing 90
    assert gt[1, 2] == 1 and hit[1, 2] == 1  # ahead: nearest point (6, 0), bearing 0
