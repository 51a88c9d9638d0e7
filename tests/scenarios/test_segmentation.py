"""The motion mask's pixel audit: counts against hand-made frames."""

import math

import numpy as np
import pytest

from scenarios.detection_metrics import GtVehicle
from scenarios.segmentation import SegmentationAudit
from scenarios.visualize import SEGMENTATION_COLOURS, segmentation_picture


def _ahead(vid: int, range_m: float) -> GtVehicle:
    """Vehicle vid, 2 x 2 m, whose footprint's nearest point is range_m ahead."""
    x = np.array([0.0, 2.0, 2.0, 0.0]) + range_m
    return GtVehicle(vid, np.column_stack([x, [-1.0, -1.0, 1.0, 1.0]]))


def _frame() -> tuple[np.ndarray, np.ndarray]:
    """ids (10, 10): vehicle 3 (4 px), vehicle 5 (6 px), the ego car (0, 5 px), none (-1)."""
    ids = np.full((10, 10), -1)
    ids[0, :4] = 3
    ids[1, :6] = 5
    ids[9, :5] = 0
    return ids, np.ones((10, 10), bool)


def test_shares_count_evaluated_vehicles_for_recall_and_any_vehicle_for_precision():
    ids, area = _frame()
    mask = np.zeros_like(area)
    mask[0, :2] = True  # 2 of vehicle 3's 4 pixels
    mask[1, :3] = True  # 3 of vehicle 5's (not evaluated: beyond the range)
    mask[5, :4] = True  # 4 pixels of road
    mask[9, :1] = True  # 1 pixel of the ego car: not a vehicle
    audit = SegmentationAudit(area)
    audit.add(mask, ids, [_ahead(3, 7.0)])
    r = audit.result()
    assert r["pixel_recall"] == pytest.approx(2 / 4)
    assert r["pixel_precision"] == pytest.approx((2 + 3) / (2 + 3 + 4 + 1))
    assert r["vehicle_px"] == 4 and r["marked_px"] == 10 and r["frames"] == 1
    assert r["range_bands"]["5-10 m"] == {"pixel_recall": 0.5, "vehicle_px": 4}
    assert math.isnan(r["range_bands"]["0-5 m"]["pixel_recall"])
    assert r["range_bands"]["15-25 m"]["vehicle_px"] == 0


def test_the_true_mask_scores_one_and_pixels_outside_the_area_do_not_count():
    ids, area = _frame()
    area[:, 8:] = False
    ids[0, 8:] = 3  # vehicle 3 also outside the area
    audit = SegmentationAudit(area)
    audit.add(ids > 0, ids, [_ahead(3, 2.0), _ahead(5, 12.0)])
    audit.add(ids > 0, ids, [_ahead(3, 2.0), _ahead(5, 12.0)])
    r = audit.result()
    assert r["pixel_recall"] == 1.0 and r["pixel_precision"] == 1.0
    assert r["range_bands"]["0-5 m"]["vehicle_px"] == 2 * 4
    assert r["range_bands"]["10-15 m"]["vehicle_px"] == 2 * 6
    assert r["frames"] == 2


def test_nothing_marked_has_no_precision_and_a_bad_shape_is_named():
    ids, area = _frame()
    audit = SegmentationAudit(area)
    audit.add(np.zeros_like(area), ids, [])
    r = audit.result()
    assert math.isnan(r["pixel_precision"]) and math.isnan(r["pixel_recall"])
    with pytest.raises(ValueError, match=r"mask \(5, 5\)"):
        audit.add(np.zeros((5, 5), bool), ids, [])


def test_the_audit_picture_colours_each_kind_of_pixel():
    ids, area = _frame()
    area[:, 9] = False
    mask = np.zeros_like(area)
    mask[0, :2] = True  # vehicle 3, marked
    mask[5, :4] = True  # road, marked
    mask[1, 9] = True  # outside the area
    grey = np.full((10, 10, 3), 100, np.uint8)
    out = segmentation_picture(grey, mask, ids > 0, area)
    assert out.shape == (10, 10, 3) and out.dtype == np.uint8

    def hue(px: np.ndarray) -> int:  # index of the colour the pixel is nearest to
        colours = np.array(list(SEGMENTATION_COLOURS.values()), float)
        return int(np.argmin(np.linalg.norm(colours - px.astype(float), axis=1)))

    assert hue(out[0, 1]) == 0  # marked vehicle: yellow
    assert hue(out[0, 3]) == 1  # vehicle not marked: green
    assert hue(out[5, 2]) == 2  # marked, no vehicle: red
    assert out[7, 7].tolist() == [60, 60, 60]  # the image, dimmed
    assert out[1, 9].tolist() == [24, 24, 24]  # outside the area: darker, not coloured
