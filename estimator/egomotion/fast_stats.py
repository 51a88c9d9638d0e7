"""Small-array reductions: numpy's values without its per-call overhead."""

from __future__ import annotations

import math

import numpy as np

# np.median, np.percentile and np.nan_to_num spend 20-100 µs a call on argument
# handling; the estimator calls them ~20 times a frame on a few hundred to a few
# thousand values. These give numpy 2's values (the same order statistics, the same
# arithmetic; tests/estimator/egomotion/test_direct.py compares them) without that overhead.


def fast_median(a: np.ndarray) -> float:
    """``float(np.median(a))`` of a 1-D float array (NaN if a holds one or is empty)."""
    n = a.shape[0]
    if n == 0:
        return math.nan
    k = n // 2
    if n % 2:
        part = np.partition(a, (k, n - 1))
        m = part[k]  # np.median: the mean of one value
    else:
        part = np.partition(a, (k - 1, k, n - 1))
        m = (part[k - 1] + part[k]) / 2  # np.median: the mean of the middle two
    return float(part[n - 1] if np.isnan(part[n - 1]) else m)


def fast_percentile(a: np.ndarray, q: float) -> float:
    """``float(np.percentile(a, q))`` of a non-empty 1-D float array (numpy's default
    "linear" method: the order statistics around ``(n - 1) q / 100``, interpolated
    as numpy's ``_lerp`` does)."""
    n = a.shape[0]
    v = (n - 1) * (q / 100)
    lo = math.floor(v)
    hi = lo + 1
    if v >= n - 1:  # numpy: the last order statistic (its index -1)
        lo = hi = -1
    gamma = v - lo
    part = np.partition(a, sorted({lo % n, hi % n, n - 1}))
    if np.isnan(part[n - 1]):
        return float(part[n - 1])
    x0, x1 = part[lo], part[hi]
    diff = x1 - x0
    return float(x1 - diff * (1 - gamma) if gamma >= 0.5 else x0 + diff * gamma)


def nan_to_num_fast(a: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(a)`` (NaN -> 0, +/-inf -> the largest finite values); a itself
    (not a copy) when it is all finite, the usual case."""
    return a if np.isfinite(a).all() else np.nan_to_num(a)
