"""Order statistics of small 1-D arrays, numpy's own floats without numpy's Python layers.

np.median and np.percentile spend tens of microseconds in Python around a
partial sort of a few hundred values; the detector takes a dozen of them a
frame. These take the same order statistics by one np.partition and combine
them with numpy's own arithmetic (the mean of the two middle values; the
linear method's interpolation), so they return the same float, bit for bit
(tests hold them to numpy's). NaN anywhere gives NaN, as numpy's do.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["median", "percentile"]


def median(values: np.ndarray) -> float:
    """np.median of a non-empty 1-D float array."""
    n = len(values)
    half = n // 2
    if n % 2:
        part = np.partition(values, (half, n - 1))
        return math.nan if math.isnan(part[-1]) else float(part[half])
    part = np.partition(values, (half - 1, half, n - 1))
    if math.isnan(part[-1]):
        return math.nan
    return float((part[half - 1] + part[half]) / 2.0)


def percentile(values: np.ndarray, q: float) -> float:
    """np.percentile(values, q) (its linear method) of a non-empty 1-D float64 array."""
    n = len(values)
    virtual = (n - 1) * (q / 100.0)
    if n == 1:
        return float(values[0])
    below = math.floor(virtual)
    part = np.partition(values, (below, below + 1, n - 1))
    if math.isnan(part[-1]):
        return math.nan
    a, b = float(part[below]), float(part[below + 1])
    t = virtual - below
    step = b - a
    return b - step * (1.0 - t) if t >= 0.5 else a + step * t
