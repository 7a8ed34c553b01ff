"""The speckle likelihood: it is the simulator's noise, and its fit is unbiased."""

from __future__ import annotations

import numpy as np

from tracker.bench.detect_data import speckle_information
from tracker.detect.multiplicative import MultiplicativeFit, interval_scores
from tracker.detect.windowed import later_within
from tracker.normal import pixel_fractions
from tracker.sim.seednoise import apply_seed_noise


def test_score_has_mean_zero_and_variance_equal_to_the_information_under_the_simulator():
    """E[d log P / d mu] = 0 and E[score^2] = I hold only if the likelihood is the noise.

    Pixels drawn by the simulator's own speckle (clip, then 8-bit rounding);
    a likelihood that got the rounding or a clip wrong biases the mean score
    by many standard errors.
    """
    rng = np.random.default_rng(5)
    variance = 0.6
    for clean in (0.004, 0.03, 0.2, 0.7):
        noisy, _ = apply_seed_noise(np.full((400, 500), clean), "speckle", rng, param=variance)
        k = np.rint(noisy * 255.0).ravel()
        lo = np.where(k <= 0, -np.inf, k - 0.5)
        hi = np.where(k >= 255, np.inf, k + 0.5)
        _, by_mu, _ = interval_scores(lo, hi, 255.0 * clean, np.sqrt(variance))
        score = 255.0 * by_mu                           # per unit of the clean value
        info = float(speckle_information(variance, np.array([clean]))[0])
        standard_error = np.sqrt(info / score.size)
        assert abs(score.mean()) < 5.0 * standard_error, (clean, score.mean(), standard_error)
        assert 0.95 < np.mean(score ** 2) / info < 1.05, (clean, np.mean(score ** 2), info)


def test_fit_is_unbiased_from_windows_off_centre():
    """300 spots drawn by the fit's own model from windows off-centre by up to 1 px."""
    rng = np.random.default_rng(8)
    n, radius, sigma, s_true = 300, 4, 1.2, 0.8
    tx, ty = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    edges = np.arange(-radius, radius + 2) - 0.5
    fx, _ = pixel_fractions(edges[None, :] - tx[:, None], sigma)
    fy, _ = pixel_fractions(edges[None, :] - ty[:, None], sigma)
    mu = 400.0 * (fy[:, :, None] * fx[:, None, :]).reshape(n, -1)
    values = np.rint(np.clip(mu * (1.0 + s_true * rng.standard_normal(mu.shape)), 0, 255))
    fit = MultiplicativeFit(radius, sigma, 255.0)
    x, y, ok = fit.fit(values, np.zeros_like(values), values.sum(axis=1))
    assert ok.all()
    err_x, err_y = x - tx, y - ty
    rms = np.sqrt(np.mean(err_x ** 2 + err_y ** 2))
    assert rms < 0.2, rms
    # bias: mean error well inside its standard error of rms / sqrt(2 n) per axis x 4
    assert abs(err_x.mean()) < 4 * rms / np.sqrt(2 * n)
    assert abs(err_y.mean()) < 4 * rms / np.sqrt(2 * n)


def test_fit_keeps_its_star_when_a_neighbours_wing_lights_a_corner_of_the_window():
    """A faint speckled star (flux 100 ADU, s = 1) with one pixel of 1-3 ADU in a corner
    of its 9 x 9 window, as a neighbour 6-7 px away puts there.

    The star's model gives that pixel a probability near 1e-30, so without a
    term for light that is not the star's that one pixel outweighs the
    star's own and drags the centre to the edge of the start grid (1.5 px
    and more off); with it the centre stays where the star's pixels put it.
    """
    rng = np.random.default_rng(21)
    n, radius, sigma = 200, 4, 1.3
    tx, ty = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)
    edges = np.arange(-radius, radius + 2) - 0.5
    fx, _ = pixel_fractions(edges[None, :] - tx[:, None], sigma)
    fy, _ = pixel_fractions(edges[None, :] - ty[:, None], sigma)
    mu = 100.0 * (fy[:, :, None] * fx[:, None, :]).reshape(n, -1)
    values = np.rint(np.clip(mu * (1.0 + rng.standard_normal(mu.shape)), 0, 255))
    corner = rng.choice([0, 8, 72, 80], n)                 # one of the window's corners
    values[np.arange(n), corner] = rng.integers(1, 4, n)
    fit = MultiplicativeFit(radius, sigma, 255.0)
    x, y, ok = fit.fit(values, np.zeros_like(values), values.sum(axis=1))
    err = np.hypot(x - tx, y - ty)
    assert ok.all()
    assert np.mean(err > 1.0) < 0.02, np.sort(err)[-10:]
    assert np.sqrt(np.mean(err ** 2)) < 0.5, np.sqrt(np.mean(err ** 2))


def test_fit_never_raises_on_windows_it_cannot_fit():
    """Empty, saturated, random and sparse windows under odd backgrounds and fluxes.

    A star whose curvature is singular (all-zero or all-clipped window) keeps
    its start; nothing raises (np.linalg.solve on a stack would, for one
    singular matrix) and nothing warns.
    """
    rng = np.random.default_rng(0)
    fit = MultiplicativeFit(4, 1.2, 255.0)
    windows = [np.zeros((3, 81)), np.full((3, 81), 255.0),
               rng.integers(0, 256, (40, 81)).astype(float),
               (rng.random((20, 81)) < 0.05) * 255.0]
    for values in windows:
        for background in (np.zeros_like(values), rng.normal(0.0, 5.0, values.shape),
                           np.full(values.shape, 300.0), np.full(values.shape, -20.0)):
            for flux in (values.sum(axis=1), np.full(len(values), -50.0),
                         np.full(len(values), 1e9), np.full(len(values), np.nan)):
                with np.errstate(divide="raise", over="raise", invalid="raise"):
                    x, y, ok = fit.fit(values, background, flux)
                assert x.shape == y.shape == ok.shape == (len(values),)
                assert np.all(np.isfinite(x[ok])) and np.all(np.isfinite(y[ok]))


def test_later_within_matches_brute_force():
    """The duplicate mask (a centre within r of an earlier, brighter one) of the speckle mode."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        n = int(rng.integers(0, 300))    # both the dense and the sorted comparison
        x, y, r = rng.uniform(0, 20, n), rng.uniform(0, 20, n), rng.uniform(0.5, 3.0)
        d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
        expected = np.array([np.any(d[i, :i] <= r) for i in range(n)], bool)
        np.testing.assert_array_equal(later_within(x, y, r), expected)
