"""tracker.normal: tail and interval log-probabilities, pixel-integrated Gaussian."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker.normal import log_interval, log_tail, pixel_fractions


def _reference_log_interval(lo: float, hi: float) -> float:
    """log P(lo < Z < hi) from math.erfc, taken on the side where it does not cancel."""
    r = math.sqrt(2.0)
    if lo >= 0:
        p = 0.5 * (math.erfc(lo / r) - math.erfc(hi / r))
    elif hi <= 0:
        p = 0.5 * (math.erfc(-hi / r) - math.erfc(-lo / r))
    else:
        p = 1.0 - 0.5 * math.erfc(hi / r) - 0.5 * math.erfc(-lo / r)
    return math.log(p)


def test_log_interval_matches_erfc_across_and_in_both_tails():
    rng = np.random.default_rng(3)
    lo = rng.normal(0.0, 8.0, 5000)
    hi = lo + rng.exponential(1.0, 5000) + 1e-3
    ref = np.array([_reference_log_interval(a, b) for a, b in zip(lo, hi, strict=True)])
    keep = ref > -700.0                      # where math.erfc itself is still > 0
    got = log_interval(lo, hi)
    # NR erfcc's 1.2e-7 fractional error; intervals of width 1e-3 across 0 lose 3 digits
    assert np.max(np.abs(got[keep] - ref[keep])) < 1e-3
    assert np.median(np.abs(got[keep] - ref[keep])) < 1e-6


def test_open_ends_and_far_tails_stay_finite():
    lo = np.array([-np.inf, -np.inf, 30.0, -np.inf])
    hi = np.array([np.inf, 0.0, np.inf, -30.0])
    got = log_interval(lo, hi)
    assert got[0] == pytest.approx(0.0, abs=1e-7)
    assert got[1] == pytest.approx(math.log(0.5), abs=1e-6)
    # Q(30) = exp(-450) ... far below float range, its log is not: -454.3
    assert got[2] == pytest.approx(got[3]) and got[2] == pytest.approx(-454.3212, abs=1e-3)
    assert log_tail(np.array([np.inf]))[0] == -np.inf and log_tail(np.array([-np.inf]))[0] == 0


def test_pixel_fractions_sum_to_one_and_derivative_matches_finite_difference():
    edges = np.arange(-8, 10) - 0.5 - 0.37
    frac, deriv = pixel_fractions(edges, 1.3)
    assert frac.sum() == pytest.approx(1.0, abs=1e-6)
    h = 1e-5
    plus, _ = pixel_fractions(edges - h, 1.3)        # centre moved by +h
    minus, _ = pixel_fractions(edges + h, 1.3)
    np.testing.assert_allclose(deriv, (plus - minus) / (2 * h), atol=1e-6)
