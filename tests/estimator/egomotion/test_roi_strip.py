"""The strip's blur against a plain blur of the whole image (cv2.sepFilter2D, reflected
borders): the same values at every read ROI pixel, for a ring, a ROI on the image's
edges (reflected copies) and a scattered one (the bounding box chosen)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.egomotion.pyramid import gaussian_kernel
from estimator.egomotion.roi_strip import _box, _packed, roi_strip, strip_blur, strip_blur_image


def _rois() -> dict[str, tuple[tuple[int, int], np.ndarray]]:
    yy, xx = np.mgrid[:160, :200]
    ry, rx = np.mgrid[:320, :320]
    r = np.hypot(ry - 160, rx - 160)
    return {
        "ring": ((320, 320), (r > 111) & (r < 133)),  # the omni camera's at half size
        "edges": ((160, 200), (yy > 90 + 0.3 * np.abs(xx - 100)) | (xx < 4)),
        "scattered": ((40, 50), (yy[:40, :50] + xx[:40, :50]) % 7 < 3),
    }


def _check(shape, roi_mask, sigma, seed, layout=None):
    roi = np.flatnonzero(roi_mask)
    half = int(np.ceil(3 * sigma))
    kernel = gaussian_kernel(sigma, 2 * half + 1)
    if layout is None:
        strip = roi_strip(roi, shape, half)
    else:
        rows, cols = np.divmod(roi, shape[1])
        strip = (
            _box(rows, cols, shape, half)
            if layout == "box"
            else _packed(rows, cols, shape, half, layout)
        )
    rng = np.random.default_rng(seed)
    at = rng.choice(len(roi), len(roi) // 3, replace=False)
    read = rng.choice(len(roi), len(roi) // 2, replace=False)
    values = rng.normal(size=len(at)).astype(np.float32)
    full = np.zeros(shape[0] * shape[1], np.float32)
    full[roi[at]] = values
    want = cv2.sepFilter2D(full.reshape(shape), -1, kernel, kernel).ravel()[roi[read]]
    got = strip_blur(strip, strip.copies[:, at], values, kernel, strip.core[read])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    return strip


@pytest.mark.parametrize("name", ["ring", "edges", "scattered"])
def test_strip_blur_is_the_whole_image_blur(name):
    shape, mask = _rois()[name]
    strip = _check(shape, mask, 1.5, 0)
    if name == "ring":  # packed runs: fewer pixels than the ring's bounding box
        assert strip.size < 0.6 * (2 * 133 + 12) ** 2


@pytest.mark.parametrize("layout", ["box", 4, 16, 64])
@pytest.mark.parametrize("name", ["ring", "edges", "scattered"])
def test_every_layout_is_the_whole_image_blur(name, layout):
    """Each layout the choice is made from, whichever is chosen: runs of several band
    heights (reflected copies at the edges, runs cut in a band) and the bounding box."""
    shape, mask = _rois()[name]
    _check(shape, mask, 1.5, 1, layout)


@settings(max_examples=25, deadline=None)
@given(
    st.integers(8, 60),
    st.integers(8, 60),
    st.floats(0.02, 0.9),
    st.sampled_from([0.5, 1.0, 1.5, 2.5]),
    st.sampled_from([None, "box", 3, 8, 20]),
    st.integers(0, 2**16),
)
def test_strip_blur_random_rois(h, w, density, sigma, layout, seed):
    mask = np.random.default_rng(seed).random((h, w)) < density
    if mask.sum() < 2:
        mask[0, 0] = mask[-1, -1] = True
    if layout not in (None, "box") and int(np.ceil(3 * sigma)) >= min(h, w):
        layout = None  # runs need an image larger than the kernel's reach (`roi_strip`)
    _check((h, w), mask, sigma, seed, layout)


def test_empty_roi():
    strip = roi_strip(np.zeros(0, np.intp), (10, 10), 3)
    kernel = gaussian_kernel(1.0, 7)
    out = strip_blur(strip, strip.copies[:, :0], np.zeros(0, np.float32), kernel, strip.core[:0])
    assert out.shape == (0,)


def test_a_reused_canvas_gives_each_blur_as_a_fresh_one():
    """`strip_blur_image` with one canvas for several blurs of the same pixels (each
    overwrites them): every blur as on a new zero canvas, also the pixels with two copies."""
    shape, mask = _rois()["edges"]  # reflected copies at the image's edges
    roi = np.flatnonzero(mask)
    kernel = gaussian_kernel(1.5, 11)
    strip = _packed(*np.divmod(roi, shape[1]), shape, 5, 16)
    assert strip.copies.shape[0] > 1
    rng = np.random.default_rng(3)
    put = strip.copies[:, rng.choice(len(roi), len(roi) // 3, replace=False)]
    canvas = np.zeros(strip.size + 1, np.float32)
    for _ in range(3):
        values = rng.normal(size=put.shape[1]).astype(np.float32)
        fresh = strip_blur_image(strip, put, values, kernel)
        np.testing.assert_array_equal(strip_blur_image(strip, put, values, kernel, canvas), fresh)
        assert fresh.shape == (strip.size,) and np.abs(fresh).max() > 0
