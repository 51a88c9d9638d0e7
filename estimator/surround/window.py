"""Windowed image statistics shared by the motion score and the pixel classifier."""

from __future__ import annotations

import cv2
import numpy as np


def gauss_window(img: np.ndarray, K: float) -> np.ndarray:
    """(h, w) the Gaussian-weighted mean <img> over a window of K px (odd, >= 3; sigma
    K / 4)."""
    k = max(3, int(K) | 1)
    return cv2.GaussianBlur(img, (k, k), k / 4.0)


def gradient_sq(a: np.ndarray) -> np.ndarray:
    """(h, w) float32 |g|^2 [grey level^2 / px^2] of a grey image (Sobel / 8)."""
    gu = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gv = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return gu * gu + gv * gv
