"""The simulator's noise: sensor statistics, hot pixels, cosmic rays, seed models, SNR."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.config import SimConfig
from tracker.sim import apply_seed_noise, noise_power, render_points, snr_db
from tracker.sim.frame import sim_psf, star_stamps
from tracker.sim.psf import stamp_pixels
from tracker.sim.seednoise import delivered_moments, param_for_snr

QUIET = SimConfig(dark_current_e_s=0.0, hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0,
                  glare_e=0.0, read_noise_e=0.0, gain_e_per_adu=1.0, bias_adu=100.0)
SHAPE = (400, 400)
N = SHAPE[0] * SHAPE[1]


def _blank(cfg, rng=0, sky_e=0.0, **kw):
    return render_points(SHAPE, [], [], [], cfg, np.random.default_rng(rng), sky_e=sky_e, **kw)


def test_read_noise_has_the_configured_std():
    frame = _blank(dataclasses.replace(QUIET, read_noise_e=5.0))
    # Read noise 5 e- at 1 e-/ADU plus rounding (1/12 ADU^2); the std of N = 160000
    # samples scatters by 5/sqrt(2N) = 0.009 ADU, so 0.05 is > 5 sigma.
    assert frame.image.astype(float).std() == pytest.approx(np.sqrt(25 + 1 / 12), abs=0.05)
    assert frame.image.astype(float).mean() == pytest.approx(100.0, abs=0.05)


def test_shot_noise_variance_equals_its_mean():
    frame = _blank(dataclasses.replace(QUIET, bias_adu=0.0), sky_e=50.0)
    counts = frame.image.astype(float)
    # Poisson(50) at 1 e-/ADU, no read noise: mean and variance 50. Standard errors
    # sqrt(50/N) = 0.018 (mean) and 50 sqrt(2/N) = 0.18 (variance).
    assert counts.mean() == pytest.approx(50.0, abs=0.1)
    assert counts.var() == pytest.approx(50.0, abs=1.0)


def test_bright_star_saturates_at_the_10_bit_full_scale():
    frame = render_points((30, 30), [15.0], [15.0], [1e7], SimConfig(),
                          np.random.default_rng(0))
    assert frame.image.dtype == np.uint16 and frame.bit_depth == 10
    assert frame.image.max() == 1023
    assert frame.stars["saturated"][0]
    frame8 = render_points((30, 30), [15.0], [15.0], [1e7], SimConfig(),
                           np.random.default_rng(0), bit_depth=8)
    assert frame8.image.dtype == np.uint8 and frame8.image.max() == 255


def test_hot_pixels_are_fixed_per_sensor_seed():
    cfg = SimConfig(cosmic_ray_rate_cm2_s=0.0)
    hot = _blank(cfg, rng=1).false_sources
    assert hot and all(s["kind"] == "hot_pixel" for s in hot)
    assert _blank(cfg, rng=2).false_sources == hot  # another frame, the same sensor
    assert _blank(dataclasses.replace(cfg, seed=2), rng=1).false_sources != hot
    frame = _blank(cfg, rng=3)
    # Each listed hot pixel carries >= 5 read-noise of charge: far above the 64 ADU bias.
    for s in hot:
        assert frame.image[int(s["y"]), int(s["x"])] > 64 + 0.5 * s["charge_e"] / 1.35 - 10


def test_cosmic_rays_land_where_the_truth_says():
    cfg = dataclasses.replace(QUIET, cosmic_ray_rate_cm2_s=2e4, read_noise_e=2.0)
    frame = _blank(cfg)
    rays = [s for s in frame.false_sources if s["kind"] == "cosmic_ray"]
    # Expected count: 2e4 /cm^2/s * (400 * 3 um)^2 * 0.1 s = 28.8; Poisson spread 5.4.
    assert 10 <= len(rays) <= 50
    for ray in rays:
        r, c = int(round(ray["y"])), int(round(ray["x"]))
        window = frame.image[max(r - 4, 0):r + 5, max(c - 4, 0):c + 5].astype(float) - 100
        assert window.max() > 100  # >= 400 e- deposited per pixel crossed


def test_salt_and_pepper_sets_its_density():
    grey = np.full((500, 400), 0.5)
    noisy, info = apply_seed_noise(grey, "salt_pepper", np.random.default_rng(0), param=0.05)
    # Exactly round(0.05 * N) distinct pixels, half to 0 and half to 1.
    assert np.mean(noisy == 0.0) == pytest.approx(0.025, abs=1e-5)
    assert np.mean(noisy == 1.0) == pytest.approx(0.025, abs=1e-5)
    assert info == {"model": "salt_pepper", "param": 0.05}


def test_gaussian_poisson_adds_gaussian_then_photon_variance():
    grey = np.full((500, 400), 0.5)
    noisy, _ = apply_seed_noise(grey, "gaussian_poisson", np.random.default_rng(0),
                                param=0.001)
    # Far from the clip points: variance 0.001 (Gaussian) + 0.5/255 (Poisson at 255 counts
    # per unit); its standard error is 0.0029 * sqrt(2/N) = 6e-6.
    assert noisy.var() == pytest.approx(0.001 + 0.5 / 255, rel=0.02)
    strong, _ = apply_seed_noise(grey, "gaussian_poisson", np.random.default_rng(1),
                                 param=0.15)
    # With the seed's variance 0.15 much of the spread is clipped: compare with the model,
    # which ignores the clip at 1 after the Poisson stage (10 % of these pixels sit at
    # c = 1, where that clip removes about a tenth of their noise power): within 5 %.
    expected = noise_power("gaussian_poisson", 0.15, np.array([0.5]))[0]
    assert np.mean((strong - 0.5) ** 2) == pytest.approx(expected, rel=0.05)


def test_speckle_multiplies_by_a_mask_of_the_given_variance():
    grey = np.full((500, 400), 0.3)
    noisy, _ = apply_seed_noise(grey, "speckle", np.random.default_rng(0), param=0.15)
    # 0.3 * (1 + 0.387 z) leaves 0..1 only below z = -2.58 (0.5 % of pixels, clipped to 0).
    assert (noisy / 0.3).mean() == pytest.approx(1.0, abs=0.01)
    assert (noisy / 0.3).var() == pytest.approx(0.15, rel=0.03)


def test_glare_follows_its_formula():
    noisy, info = apply_seed_noise(np.zeros((300, 400)), "glare", np.random.default_rng(0),
                                   param=0.8, glare_centre=(100.0, 50.0), glare_radius_px=200)
    assert noisy[50, 100] == pytest.approx(0.8)
    assert noisy[50, 300] == pytest.approx(0.8 * np.exp(-0.5))
    assert info["glare_centre"] == [100.0, 50.0] and info["glare_radius_px"] == 200.0


def test_unknown_model_and_bad_images_are_refused():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="unknown seed noise model 'fog'"):
        apply_seed_noise(np.zeros((4, 4)), "fog", rng, param=1.0)
    with pytest.raises(ValueError, match="image has non-finite pixels"):
        apply_seed_noise(np.full((4, 4), np.nan), "speckle", rng, param=1.0)
    with pytest.raises(ValueError, match="a target SNR applies to the seed noise models"):
        render_points((9, 9), [4.0], [4.0], [10.0], SimConfig(), rng, snr_db=0.0)


def _star_field(rng):
    """300 stars of 100 to 3000 e- on a full OV2311 frame (a default sky has about 300)."""
    xs, ys = rng.uniform(0, 1600, 300), rng.uniform(0, 1300, 300)
    return xs, ys, 10.0 ** rng.uniform(2.0, 3.5, 300)


@pytest.mark.parametrize("model, tolerance_db", [
    # Largest |measured - target| over seeds 0-9 and targets -5, 0, 3 dB (a previous run):
    # 0.04 dB gaussian_poisson, 0.02 glare; 0.35 salt_pepper (at +3 dB only ~10 salt
    # pixels are set, so one pixel more or less is 0.4 dB); 0.43 speckle (approximate
    # rounding term, and a huge mask variance lets a few pixels dominate).
    ("gaussian_poisson", 0.2), ("glare", 0.2), ("salt_pepper", 0.6), ("speckle", 0.8),
])
@pytest.mark.parametrize("target", [-5.0, 0.0, 3.0])
def test_target_snr_is_reached(model, tolerance_db, target):
    rng = np.random.default_rng(7)
    xs, ys, electrons = _star_field(rng)
    frame = render_points((1300, 1600), xs, ys, electrons, SimConfig(), rng,
                          noise_model=model, snr_db=target)
    assert frame.bit_depth == 8 and frame.image.dtype == np.uint8
    assert frame.truth["snr_db"] == pytest.approx(target, abs=tolerance_db)
    assert frame.truth["snr_db_target"] == target


def test_snr_measure_and_out_of_reach_target():
    clean = np.zeros((10, 10))
    clean[5, 5] = 1.0
    noisy = clean.copy()
    noisy[0, 0] = 1.0
    assert snr_db(clean, noisy) == pytest.approx(0.0)
    with pytest.raises(ValueError, match="out of reach for salt_pepper"):
        param_for_snr("salt_pepper", clean, -30.0)


def test_speckled_star_that_rounds_away_is_not_counted_detectable():
    """Multiplicative noise is tiny on tiny light, but 8-bit rounding is not: the per-star
    SNR has the LSB^2/12 floor, so a star below half an LSB is not 'detectable'."""
    frame = render_points((40, 40), [20.0], [20.0], [20.0], SimConfig(),
                          np.random.default_rng(3), noise_model="speckle", bit_depth=8)
    assert frame.image[15:26, 15:26].max() <= 1          # the star is (almost) gone
    assert frame.stars["mf_snr"][0] < 3.0


@pytest.mark.parametrize("model, param, clean", [
    ("gaussian_poisson", 0.15, 0.0), ("gaussian_poisson", 0.15, 0.35),
    ("salt_pepper", 0.05, 0.3), ("speckle", 0.15, 0.4)])
def test_delivered_moments_are_the_8bit_pixels(model, param, clean):
    """Mean and variance of 200 000 delivered 8-bit pixels of one clean value against
    delivered_moments: standard errors of the mean 0.001 and of the variance 2-3 %
    of it at most; the clip at 1 after the Poisson stage is left out of the model."""
    grey = np.full((500, 400), clean)
    noisy, _ = apply_seed_noise(grey, model, np.random.default_rng(5), param=param)
    delivered = np.rint(noisy * 255.0) / 255.0
    mean, variance = delivered_moments(model, param, np.array([clean]))
    assert delivered.mean() == pytest.approx(mean[0], abs=0.003)
    assert delivered.var() == pytest.approx(variance[0], rel=0.02)


def test_matched_filter_snr_under_clipped_noise_is_what_the_pixels_give():
    """A star on a black sky under Gaussian+Poisson variance 0.15 (half the noise clipped
    at 0): the truth's mf_snr is no more than what a matched filter at the star, weighted
    by the delivered signal over the sky's variance, reads on average over 300 noise
    draws (8.9). Counting the star's own light against (I - S)^2 gave 10.0, more than
    any filter reads."""
    rng = np.random.default_rng(8)
    cfg = SimConfig()
    x, y = 15.3, 15.6
    first = render_points((31, 31), [x], [y], [20000.0], cfg, rng,
                          noise_model="gaussian_poisson")
    snr = first.stars["mf_snr"][0]
    assert 6.0 < snr < 12.0
    full = first.truth["noise"]["full_scale_e"]
    own = star_stamps([x], [y], sim_psf(cfg))
    rows, cols, inside = stamp_pixels((31, 31), own)
    light = np.where(inside, own.values * 20000.0 / full, 0.0)[0]
    lit, _ = delivered_moments("gaussian_poisson", 0.15, np.minimum(light, 1.0))
    sky, sky_var = delivered_moments("gaussian_poisson", 0.15, np.zeros(1))
    weights = (lit - sky[0]) / sky_var[0]
    norm = np.sqrt(np.sum(weights ** 2) * sky_var[0])
    reads = []
    for _ in range(300):
        image = render_points((31, 31), [x], [y], [20000.0], cfg, rng,
                              noise_model="gaussian_poisson").image / 255.0
        reads.append(np.sum(weights * (image[rows[0], cols[0]] - sky[0])) / norm)
    # the truth counts each pixel's larger noise, with or without the star (its wings
    # lift the clipped noise): at most a fifth under the reading, never over it
    assert snr <= np.mean(reads) <= 1.2 * snr
