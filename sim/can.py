"""CAN-bus speed as a car reports it: scaled, noisy, quantised, at its own rate.

The estimator gets the latest message at each camera frame (zero-order hold).
"""

from __future__ import annotations

import numpy as np


def can_messages(
    t_s: np.ndarray,
    speed_mps: np.ndarray,
    rate_hz: float,
    speed_bias: float,
    speed_noise_mps: float,
    quantization_mps: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """CAN speed messages from the true speed.

    t_s, speed_mps: (N,) true speed samples (sorted times) [s], [m/s].
    Returns (t_msg_s (M,), speed_msg_mps (M,)): messages every 1/rate_hz from t_s[0],
    speed = quantise((1 + bias) * v_true(t) + noise), never negative.
    """
    t_msg = np.arange(t_s[0], t_s[-1] + 1e-9, 1.0 / rate_hz)
    v = np.interp(t_msg, t_s, speed_mps) * (1.0 + speed_bias)
    v = v + rng.normal(0.0, speed_noise_mps, size=v.shape) if speed_noise_mps > 0 else v
    if quantization_mps > 0:
        v = np.round(v / quantization_mps) * quantization_mps
    return t_msg, np.maximum(v, 0.0)


def can_at(t_query_s: np.ndarray, t_msg_s: np.ndarray, speed_msg_mps: np.ndarray) -> np.ndarray:
    """Latest CAN speed at or before each query time (zero-order hold)."""
    i = np.searchsorted(t_msg_s, np.asarray(t_query_s) + 1e-9, side="right") - 1
    return speed_msg_mps[np.clip(i, 0, len(t_msg_s) - 1)]
