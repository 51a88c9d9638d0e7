"""The frame pyramid's filters are OpenCV's."""

from __future__ import annotations

import cv2
import numpy as np

from estimator.egomotion.pyramid import gaussian_blur, gaussian_kernel


def test_gaussian_blur_is_opencvs() -> None:
    """`gaussian_blur` (cv2.sepFilter2D with `gaussian_kernel`) gives cv2.GaussianBlur's
    float32 values exactly: the pre-smoothing (sigma 0.7, OpenCV's kernel size) and the
    plane-parallax window (11 taps, sigma 1.5) on sparse and dense images of odd sizes."""
    rng = np.random.default_rng(5)
    for h, w in ((640, 640), (545, 533), (17, 9)):
        dense = rng.normal(size=(h, w)).astype(np.float32) * 50
        sparse = np.where(rng.random((h, w)) < 0.01, dense, 0).astype(np.float32)
        for img in (dense, sparse):
            for sigma, ksize in ((0.7, 0), (1.5, 11)):
                ref = cv2.GaussianBlur(img, (ksize, ksize), sigma)
                out = gaussian_blur(img, gaussian_kernel(sigma, ksize))
                assert out.dtype == np.float32 and out.tobytes() == ref.tobytes()
