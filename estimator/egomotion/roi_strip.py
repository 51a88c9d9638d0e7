"""Gaussian windows over values that live on a thin region of interest.

The plane-parallax test (`OffroadMapper._parallax_marks`) blurs images that are zero
outside the road's region of interest and reads them only inside it. The omni camera's
ROI is a ring (~45 px wide at 640 px): its bounding box is four times its area. Here the
ROI is cut into bands of rows, each band into runs of columns, and every run, grown by
the kernel's reach on all four sides, is laid side by side in one strip image. A blur of
the strip then gives, at each ROI pixel of a run's core, the same sum as a blur of the
whole image (the window never leaves its run's grown rectangle), on a fraction of the
pixels. Pixels of a grown rectangle outside the image hold the image's reflection
(BORDER_REFLECT_101, OpenCV's default): a sample near the image's edge is copied there.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class RoiStrip:
    """Where each ROI pixel of a level sits in the strip.

    shape: (rows, cols) of the strip; core: (M,) flat strip index of each ROI pixel in its
    own run; copies: (C, M) flat strip indices of each ROI pixel in every run's grown
    rectangle (its core among them), ``size`` (a spare last element) where it has fewer
    than C. The strip's flat arrays have ``size + 1`` elements.
    """

    shape: tuple[int, int]
    core: np.ndarray
    copies: np.ndarray

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]


def _reflect101(i: np.ndarray, n: int) -> np.ndarray:
    """Indices outside [0, n) reflected as BORDER_REFLECT_101 does; -1 where one reflection
    does not reach the image (farther out than a kernel's reach < n: never read)."""
    i = np.where(i < 0, -i, i)
    i = np.where(i >= n, 2 * (n - 1) - i, i)
    return np.where((i >= 0) & (i < n), i, -1)


def _runs(rows: np.ndarray, cols: np.ndarray, reach: int, band: int) -> list[tuple[int, int, int]]:
    """(row0, col0, col1) of the core of every run: rows row0 .. row0 + band - 1, columns
    col0 .. col1 - 1; a band's columns split where two grown runs would not overlap."""
    r_min = int(rows.min())
    runs = []
    for b in np.unique((rows - r_min) // band):
        row0 = r_min + int(b) * band
        c = np.unique(cols[(rows >= row0) & (rows < row0 + band)])
        cut = np.flatnonzero(np.diff(c) > 2 * reach + 1) + 1
        for part in np.split(c, cut):
            runs.append((row0, int(part[0]), int(part[-1]) + 1))
    return runs


def _box(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], reach: int) -> RoiStrip:
    """The ROI's bounding box grown by reach + 1 (clipped to the image) as the strip: one
    copy per pixel, the image's own reflection at a clipped edge."""
    h, w = shape
    r0, r1 = max(int(rows.min()) - reach - 1, 0), min(int(rows.max()) + reach + 2, h)
    c0, c1 = max(int(cols.min()) - reach - 1, 0), min(int(cols.max()) + reach + 2, w)
    at = (rows - r0) * (c1 - c0) + (cols - c0)
    return RoiStrip((r1 - r0, c1 - c0), at, at[None, :])


def _packed(
    rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], reach: int, band: int
) -> RoiStrip:
    """The runs of `_runs` side by side, each grown by reach."""
    h, w = shape
    runs = _runs(rows, cols, reach, band)
    height = band + 2 * reach
    width = sum(c1 - c0 + 2 * reach for _, c0, c1 in runs)
    cand = np.full(h * w, -1, np.intp)  # each image pixel's ROI index
    cand[rows * w + cols] = np.arange(len(rows))
    owner, pos, core = [], [], np.full(len(rows), -1, np.intp)
    x0 = 0
    for row0, c0, c1 in runs:
        ys = np.arange(row0 - reach, row0 + band + reach)
        xs = np.arange(c0 - reach, c1 + reach)
        # each strip pixel's source pixel in the image (reflected at its edges)
        ry, rx = _reflect101(ys, h)[:, None], _reflect101(xs, w)[None, :]
        m = np.where((ry >= 0) & (rx >= 0), cand[np.maximum(ry, 0) * w + np.maximum(rx, 0)], -1)
        at = np.arange(height)[:, None] * width + (x0 + np.arange(len(xs)))[None, :]
        hit = m >= 0
        owner.append(m[hit])
        pos.append(at[hit])
        inner = np.zeros_like(hit)  # the core: the band's rows, the run's columns
        inner[reach : reach + band, reach : reach + c1 - c0] = True
        inner &= ((ys >= 0) & (ys < h))[:, None] & ((xs >= 0) & (xs < w))[None, :]
        core[m[hit & inner]] = at[hit & inner]
        x0 += len(xs)
    owner_a, pos_a = np.concatenate(owner), np.concatenate(pos)
    order = np.argsort(owner_a, kind="stable")
    owner_a, pos_a = owner_a[order], pos_a[order]
    rank = np.arange(len(owner_a)) - np.searchsorted(owner_a, owner_a)  # among a pixel's copies
    copies = np.full((int(rank.max()) + 1, len(rows)), height * width, np.intp)
    copies[rank, owner_a] = pos_a
    assert (core >= 0).all(), "every ROI pixel lies in the core of a run"
    return RoiStrip((height, width), core, copies)


def roi_strip(
    roi_idx: np.ndarray,
    shape: tuple[int, int],
    reach: int,
    bands: tuple[int, ...] = (16, 24, 32, 48, 64),
) -> RoiStrip:
    """The strip of the ROI pixels roi_idx (M,) (flat indices of an (H, W) image) for a kernel
    of that reach [px]: the runs of the band height (of those tried) with the fewest
    pixels, or the ROI's bounding box, whichever has the least work (its pixels plus one
    per copy of a ROI pixel). Computed once per camera level."""
    h, w = shape
    rows, cols = np.divmod(np.asarray(roi_idx, np.intp), w)
    if len(rows) == 0:
        return RoiStrip((1, 1), np.zeros(0, np.intp), np.zeros((1, 0), np.intp))

    box = _box(rows, cols, shape, reach)
    if reach >= min(h, w):  # a reflection would reflect again: the image's own
        return box

    def area(band: int) -> int:
        runs = _runs(rows, cols, reach, band)
        return sum((band + 2 * reach) * (c1 - c0 + 2 * reach) for _, c0, c1 in runs)

    packed = _packed(rows, cols, shape, reach, min(bands, key=area))
    return min((box, packed), key=lambda s: s.size + s.copies.size)


def strip_blur(
    strip: RoiStrip, put: np.ndarray, values: np.ndarray, kernel: np.ndarray, get: np.ndarray
) -> np.ndarray:
    """(N,) float32: the image that holds values (K,) at some ROI pixels and 0 elsewhere,
    blurred with the separable kernel (k, 1) float32 (``cv2.sepFilter2D``, the kernel both
    ways), read at some ROI pixels. put: (C, K) ``strip.copies[:, at]`` of the valued ROI
    pixels at (K,); get: (N,) ``strip.core[read]`` of the read ones (both indices into the
    ROI; computed once for several blurs of the same pixels)."""
    return strip_blur_image(strip, put, values, kernel)[get]


def strip_blur_image(
    strip: RoiStrip,
    put: np.ndarray,
    values: np.ndarray,
    kernel: np.ndarray,
    canvas: np.ndarray | None = None,
) -> np.ndarray:
    """(strip.size,) float32: the blurred strip of `strip_blur`, not yet read (several blurs
    compared pixel by pixel are read once). canvas: (strip.size + 1,) float32, zero except
    at put's pixels, to reuse across blurs of the same put (each overwrites those pixels
    alone); None: a new one."""
    img = np.zeros(strip.size + 1, np.float32) if canvas is None else canvas
    for copy in put:
        img[copy] = values
    return cv2.sepFilter2D(img[:-1].reshape(strip.shape), -1, kernel, kernel).ravel()
