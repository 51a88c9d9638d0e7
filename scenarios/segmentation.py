"""Pixel audit of the detector's motion mask against the vehicles' true pixels.

The built-in detectors decide, pixel by pixel, what moves unlike the road and static
structure (`estimator.surround.detection`); the plan view, blobs, obstacle map and
tracker then work from that mask alone. Two shares say whether a vehicle was lost in the
mask or after it:

- **pixel recall**: of the pixels that see a vehicle of the evaluation set (visible,
  within range: `scenarios.runner.gt_evaluation_set`), the share the mask marks, overall
  and by the vehicle's range band (placed as `scenarios.detection_metrics.breakdown`
  places it: its footprint point nearest the camera);
- **pixel precision**: of the marked pixels, the share that see a vehicle (any vehicle:
  one beyond the range is not a false mark).

Both count full-resolution pixels of the detector's analysed area (the field of view
below the horizon, less its margins), over the frames the detector ran on, from the
simulator's id images. A low pixel recall with a high track recall is possible (a few
marked pixels per vehicle are enough); a vehicle whose pixels are all unmarked cannot be
found by anything after the mask.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenarios.detection_metrics import (
    BAND_NAMES,
    GtVehicle,
    band_labels,
    nearest_footprint_point,
    ratio,
)


class SegmentationAudit:
    """Counts of marked and vehicle pixels, frame by frame (`add`), and their shares
    (`result`)."""

    def __init__(self, area: np.ndarray) -> None:
        """area: (H, W) bool, the pixels the mask decides."""
        self.area = np.asarray(area, bool)
        nb = len(BAND_NAMES)
        self.vehicle_px = np.zeros(nb, np.int64)  # pixels of evaluated vehicles, per band
        self.marked_vehicle_px = np.zeros(nb, np.int64)  # ... of them marked
        self.marked_px = 0  # marked pixels
        self.marked_on_vehicles_px = 0  # marked pixels that see any vehicle
        self.frames = 0

    def add(self, mask: np.ndarray, ids: np.ndarray, vehicles: Sequence[GtVehicle]) -> None:
        """One frame. mask: (H, W) bool, the detector's motion mask at full resolution;
        ids: (H, W) int, the vehicle id each pixel sees (< 1: none or the ego car);
        vehicles: the frame's evaluation set."""
        mask = np.asarray(mask, bool)
        ids = np.asarray(ids)
        if mask.shape != self.area.shape or ids.shape != self.area.shape:
            raise ValueError(
                f"SegmentationAudit.add: mask {mask.shape} and ids {ids.shape} must be "
                f"{self.area.shape}"
            )
        marked = mask & self.area
        self.marked_px += int(marked.sum())
        self.marked_on_vehicles_px += int((marked & (ids > 0)).sum())
        self.frames += 1
        if not vehicles:
            return
        names = band_labels(np.array([nearest_footprint_point(v.footprint_xy) for v in vehicles]))
        seen = ids[self.area]
        hit = marked[self.area]
        top = max(int(seen.max(initial=0)), max(v.id for v in vehicles)) + 1
        band_of_id = np.full(top, -1, np.int64)  # id -> range band (-1: not evaluated)
        for v, name in zip(vehicles, names, strict=True):
            if name:
                band_of_id[v.id] = BAND_NAMES.index(name)
        band = np.where(seen > 0, band_of_id[np.clip(seen, 0, top - 1)], -1)
        nb = len(BAND_NAMES)
        self.vehicle_px += np.bincount(band[band >= 0], minlength=nb)
        self.marked_vehicle_px += np.bincount(band[(band >= 0) & hit], minlength=nb)

    def result(self) -> dict:
        """{"pixel_recall", "pixel_precision", "vehicle_px", "marked_px", "frames",
        "range_bands": {band: {"pixel_recall", "vehicle_px"}}}; a share is NaN without
        pixels to count."""
        bands = {
            name: {"pixel_recall": ratio(int(m), int(v)), "vehicle_px": int(v)}
            for name, m, v in zip(BAND_NAMES, self.marked_vehicle_px, self.vehicle_px, strict=True)
        }
        return {
            "pixel_recall": ratio(int(self.marked_vehicle_px.sum()), int(self.vehicle_px.sum())),
            "pixel_precision": ratio(self.marked_on_vehicles_px, self.marked_px),
            "vehicle_px": int(self.vehicle_px.sum()),
            "marked_px": int(self.marked_px),
            "frames": self.frames,
            "range_bands": bands,
        }
