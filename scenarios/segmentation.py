"""Pixel audit of the detector's motion mask against the vehicles' true pixels.

The built-in detectors decide, pixel by pixel, what moves unlike the road and static
structure (`estimator.surround.detection`); the plan view, blobs, obstacle map and
tracker then work from that mask alone. Two shares say whether a vehicle was lost in the
mask or after it:

- **pixel recall**: of the pixels that see a vehicle of the evaluation set (visible,
  within range: `scenarios.runner.gt_evaluation_set`), the share the mask marks, overall
  and by the vehicle's range band (`RANGE_BANDS_M`, the range of its footprint);
- **pixel precision**: of the marked pixels, the share that see a vehicle (any vehicle:
  one beyond the range is not a false mark).

Both count full-resolution pixels of the detector's analysed area (the field of view
below the horizon, less its margins), over the frames the detector ran on, from the
simulator's id images. A low pixel recall with a high track recall is possible (a few
marked pixels per vehicle are enough); a vehicle whose pixels are all unmarked cannot be
found by anything after the mask.
"""

from __future__ import annotations

import math

import numpy as np

from scenarios.detection_metrics import RANGE_BANDS_M


def _band_names(edges: tuple[float, ...]) -> list[str]:
    return [f"{lo:g}-{hi:g} m" for lo, hi in zip(edges[:-1], edges[1:], strict=True)]


class SegmentationAudit:
    """Counts of marked and vehicle pixels, frame by frame (`add`), and their shares
    (`result`)."""

    def __init__(self, area: np.ndarray, bands_m: tuple[float, ...] = RANGE_BANDS_M) -> None:
        """area: (H, W) bool, the pixels the mask decides; bands_m: range band edges [m]."""
        self.area = np.asarray(area, bool)
        self.bands_m = tuple(float(b) for b in bands_m)
        nb = len(self.bands_m) - 1
        self.vehicle_px = np.zeros(nb, np.int64)  # pixels of evaluated vehicles, per band
        self.marked_vehicle_px = np.zeros(nb, np.int64)  # ... of them marked
        self.marked_px = 0  # marked pixels
        self.marked_on_vehicles_px = 0  # marked pixels that see any vehicle
        self.frames = 0

    def add(self, mask: np.ndarray, ids: np.ndarray, ranges_m: dict[int, float]) -> None:
        """One frame. mask: (H, W) bool, the detector's motion mask at full resolution;
        ids: (H, W) int, the vehicle id each pixel sees (< 1: none or the ego car);
        ranges_m: id -> range [m] of the evaluated vehicles (the evaluation set)."""
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
        if not ranges_m:
            return
        seen = ids[self.area]
        hit = marked[self.area]
        top = int(max(int(seen.max(initial=0)), max(ranges_m))) + 1
        band_of_id = np.full(top, -1, np.int64)  # id -> range band (-1: not evaluated)
        for vid, r in ranges_m.items():
            b = int(np.searchsorted(self.bands_m, r, side="right")) - 1
            if 0 <= b < len(self.vehicle_px):
                band_of_id[vid] = b
        band = band_of_id[np.clip(seen, 0, top - 1)]
        band[seen < 1] = -1
        nb = len(self.vehicle_px)
        self.vehicle_px += np.bincount(band[band >= 0], minlength=nb)[:nb]
        self.marked_vehicle_px += np.bincount(band[(band >= 0) & hit], minlength=nb)[:nb]

    def result(self) -> dict:
        """{"pixel_recall", "pixel_precision", "vehicle_px", "marked_px", "frames",
        "range_bands": {band: {"pixel_recall", "vehicle_px"}}}; a share is NaN without
        pixels to count."""

        def share(num: int, den: int) -> float:
            return float(num / den) if den else math.nan

        bands = {
            name: {
                "pixel_recall": share(int(m), int(v)),
                "vehicle_px": int(v),
            }
            for name, m, v in zip(
                _band_names(self.bands_m), self.marked_vehicle_px, self.vehicle_px, strict=True
            )
        }
        return {
            "pixel_recall": share(int(self.marked_vehicle_px.sum()), int(self.vehicle_px.sum())),
            "pixel_precision": share(self.marked_on_vehicles_px, self.marked_px),
            "vehicle_px": int(self.vehicle_px.sum()),
            "marked_px": int(self.marked_px),
            "frames": self.frames,
            "range_bands": bands,
        }
