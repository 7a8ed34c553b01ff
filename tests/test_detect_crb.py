"""The Cramer-Rao bound against its closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker.detect.crb import centroid_crb


def test_background_limited_bound_matches_the_closed_form():
    """Wide Gaussian (pixels negligible), flat noise sigma_b: sigma_x = sqrt(8 pi) s^2
    sigma_b / F per axis. The box and the free flux cost < 2 %."""
    s, flux, sigma_b = 3.0, 1e4, 10.0
    bound = centroid_crb([10.3], [20.7], [flux], s, lambda sig: np.full(sig.shape, sigma_b ** 2))
    expected = math.sqrt(2.0) * math.sqrt(8.0 * math.pi) * s * s * sigma_b / flux
    assert bound[0] == pytest.approx(expected, rel=0.02)


def test_photon_limited_bound_is_sigma_over_root_n():
    """Shot noise only: sigma_x = s_eff / sqrt(N), s_eff^2 = s^2 + 1/12 (pixel width)."""
    s, flux = 1.5, 1e5
    bound = centroid_crb([5.0, 5.4], [7.0, 7.25], [flux, flux], s, lambda sig: sig + 1e-12)
    expected = math.sqrt(2.0) * math.sqrt(s * s + 1.0 / 12.0) / math.sqrt(flux)
    assert bound == pytest.approx([expected, expected], rel=0.01)


def test_no_light_gives_an_infinite_bound():
    bound = centroid_crb([3.0], [3.0], [0.0], 1.2, lambda sig: np.ones(sig.shape))
    assert bound[0] == np.inf


def test_clipped_pixels_carry_no_information():
    """Censoring the pixels a bright star saturates raises its bound; below, nothing changes."""
    var = lambda sig: sig + 5.0  # noqa: E731 - shot noise plus a read/background floor
    free = centroid_crb([10.2], [11.7], [2e5], 1.2, var)[0]
    assert centroid_crb([10.2], [11.7], [2e5], 1.2, var, saturation=1e9)[0] == free
    clipped = centroid_crb([10.2], [11.7], [2e5], 1.2, var, saturation=5000.0)[0]
    # the core (~22,000 e- a pixel) is lost; under shot noise it held little of the
    # position information (the steep wings hold most), so the bound grows by a third
    assert 1.2 * free < clipped < 2 * free
