"""The small-array reductions give numpy's values."""

from __future__ import annotations

import math

import numpy as np

from estimator.egomotion.fast_stats import fast_median, fast_percentile, nan_to_num_fast


def test_fast_reductions_give_numpys_values() -> None:
    """`fast_median`, `fast_percentile` and `nan_to_num_fast` (the estimator's short cuts
    past numpy's argument handling) return exactly numpy's values: odd and even sizes,
    ties, a single value, NaN, inf, and percentiles whose interpolation weight is on
    either side of 1/2."""
    rng = np.random.default_rng(3)
    arrays = [rng.normal(size=n) for n in (1, 2, 3, 4, 7, 8, 299, 300, 1001)]
    arrays += [rng.integers(0, 4, size=50).astype(float), np.array([0.0, np.inf, 1.0])]
    arrays += [np.array([1.0, np.nan, 0.5]), np.array([np.nan]), rng.random(20) ** 8]
    for a in arrays:
        assert np.array_equal(fast_median(a.copy()), np.median(a), equal_nan=True)
        for q in (0, 10, 37.5, 50, 90, 99.9, 100):
            with np.errstate(invalid="ignore"):  # inf - inf in the interpolation (numpy too)
                got, ref = fast_percentile(a.copy(), q), np.percentile(a, q)
            assert np.array_equal(got, ref, equal_nan=True)
    assert math.isnan(fast_median(np.zeros(0)))
    w = rng.normal(size=(100, 2))
    assert nan_to_num_fast(w) is w
    w[3, 1], w[7, 0], w[9, 1] = np.nan, np.inf, -np.inf
    assert np.array_equal(nan_to_num_fast(w), np.nan_to_num(w))
