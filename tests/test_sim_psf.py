"""The simulator's PSF and photometry: exact centroids, normalised flux, edge spill."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker.config import SimConfig
from tracker.normal import erf
from tracker.sim import render_points
from tracker.sim.photometry import aperture_area_m2, star_electrons
from tracker.sim.psf import psf_stamps

NOISELESS = SimConfig(noise_model="none")


def test_erf_matches_math_erf_to_its_stated_accuracy():
    x = np.linspace(-6.0, 6.0, 2001)
    reference = np.array([math.erf(v) for v in x])
    # Numerical Recipes erfcc: fractional error of erfc < 1.2e-7, so |erf error| < 2.4e-7.
    assert np.max(np.abs(erf(x) - reference)) < 2.4e-7


@pytest.mark.parametrize("sigma", [0.6, 1.0, 1.5, 2.5])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.25, -0.4), (0.5, 0.5), (-0.37, 0.13)])
def test_noiseless_star_centroid_and_flux_equal_truth(sigma, offset):
    x, y = 20.0 + offset[0], 21.0 + offset[1]
    frame = render_points((41, 43), [x], [y], [5000.0], NOISELESS, np.random.default_rng(0),
                          psf_sigma_px=sigma)
    light = frame.signal_e.astype(np.float64)
    rows, cols = np.indices(light.shape)
    # Exact pixel integration: the intensity centroid is the true centre up to erf's
    # 2.4e-7 error and the 5-sigma tail cut (< 1e-5 px); 0.01 px is the brief's bar.
    assert abs((light * cols).sum() / light.sum() - x) < 0.01
    assert abs((light * rows).sum() / light.sum() - y) < 0.01
    # Flux: float32 storage (6e-8) plus tails beyond 5 sigma (< 1.2e-6 of the light).
    assert light.sum() == pytest.approx(5000.0, rel=2e-6)
    assert frame.stars["x"][0] == x and frame.stars["y"][0] == y
    assert frame.stars["in_frame"][0]


def test_star_outside_the_frame_spills_its_wing_in():
    sigma, x, y = 1.5, -2.0, 10.0
    frame = render_points((21, 21), [x], [y], [1e4], NOISELESS, np.random.default_rng(0),
                          psf_sigma_px=sigma)
    # Light inside = the Gaussian's mass right of the frame edge x = -0.5.
    inside_fraction = 0.5 * (1.0 - math.erf((-0.5 - x) / (sigma * math.sqrt(2.0))))
    assert frame.signal_e.sum() == pytest.approx(1e4 * inside_fraction, rel=1e-5)
    assert frame.signal_e[:, 0].sum() > 0
    assert not frame.stars["in_frame"][0]


def test_smeared_stamp_is_the_mean_of_its_path():
    path_x = np.array([[10.0, 11.0, 12.0]])
    path_y = np.array([[8.0, 8.0, 8.0]])
    smeared = psf_stamps(path_x, path_y, 1.0)
    assert smeared.values.sum() == pytest.approx(1.0, abs=2e-6)
    cols = smeared.x0[0] + np.arange(smeared.values.shape[2])
    assert (smeared.values[0].sum(axis=0) * cols).sum() == pytest.approx(11.0, abs=1e-6)


def test_bad_positions_are_refused():
    with pytest.raises(ValueError, match="star positions must be finite"):
        render_points((10, 10), [np.nan], [1.0], [1.0], NOISELESS, np.random.default_rng(0))
    with pytest.raises(ValueError, match="one finite electron count >= 0 per source"):
        render_points((10, 10), [1.0], [1.0], [-5.0], NOISELESS, np.random.default_rng(0))


def test_photometry_follows_the_documented_zero_point():
    cfg = SimConfig()
    area = math.pi * (0.016 / 2.0 / 2.0) ** 2  # 16 mm f/2.0 -> 8 mm pupil
    assert aperture_area_m2(16.0, 2.0) == pytest.approx(area)
    expected = 4.0e10 * area * 0.85 * 0.45 * 0.1
    assert star_electrons(0.0, 16.0, cfg) == pytest.approx(expected)
    # Five magnitudes are a factor of 100 exactly.
    assert star_electrons(6.0, 16.0, cfg) == pytest.approx(star_electrons(1.0, 16.0, cfg) / 100)
