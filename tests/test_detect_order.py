"""tracker.detect.order: numpy's medians and percentiles, to the last bit."""

from __future__ import annotations

import math

import numpy as np

from tracker.detect.order import median, percentile


def _samples(rng):
    for n in [*range(1, 40), 255, 2050]:
        for _ in range(10):
            values = rng.standard_normal(n) * 10 ** rng.uniform(-3, 3)
            if rng.random() < 0.3:
                values = np.round(values)                 # ties
            yield values


def test_percentiles_are_numpys_floats():
    for values in _samples(np.random.default_rng(31)):
        for q in (0.0, 10.0, 25.0, 50.0, 84.13, 99.9):
            assert percentile(values, q) == float(np.percentile(values, q)), (len(values), q)


def test_medians_are_numpys_floats():
    for values in _samples(np.random.default_rng(32)):
        assert median(values) == float(np.median(values)), len(values)
        single = values.astype(np.float32)
        assert median(single) == float(np.median(single)), len(values)


def test_nan_anywhere_gives_nan():
    values = np.array([1.0, np.nan, 3.0, 4.0])
    assert math.isnan(median(values)) and math.isnan(median(values[:3]))
    assert math.isnan(percentile(values, 10.0))
