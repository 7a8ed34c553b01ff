"""A spot's SNR with its own shot noise (tracker.detect.significance), and what it decides."""

from __future__ import annotations

import numpy as np

import tracker.detect.default as default
import tracker.detect.spot_shapes as spot_shapes
from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.default import effective_sigma
from tracker.detect.significance import shot_noise_snr
from tracker.normal import pixel_fractions


def _star(flux: float, sigma_px: float, radius: int, phase: tuple[float, float]) -> np.ndarray:
    """Expected light (ADU) of a pixel-integrated Gaussian star in a (2r+1)^2 window."""
    edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
    fx, _ = pixel_fractions(edges - phase[0], sigma_px)
    fy, _ = pixel_fractions(edges - phase[1], sigma_px)
    return flux * np.outer(fy, fx)


def test_shot_noise_snr_matches_the_scatter_of_the_weighted_sum():
    """Photon-counting stars (1 ADU per count) on a background of Gaussian noise: the
    weighted sum's measured SNR over 20000 draws is the formula's within 4 %, from
    background-limited (noise 3 ADU, flux 60) to shot-limited (noise 0.3, flux 3000);
    the background-only SNR overstates the latter several times."""
    rng = np.random.default_rng(3)
    sigma_px = 1.2
    s = effective_sigma(sigma_px)
    radius = int(np.ceil(3 * s))
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    for flux, noise, phase in ((60.0, 3.0, (0.0, 0.0)), (400.0, 1.0, (0.3, -0.2)),
                               (3000.0, 0.3, (0.5, 0.5))):
        mean = _star(flux, sigma_px, radius, phase)
        w = np.outer(np.exp(-0.5 * ((offsets - phase[1]) / s) ** 2),
                     np.exp(-0.5 * ((offsets - phase[0]) / s) ** 2))
        draws = rng.poisson(mean, (20000, *mean.shape)) + rng.normal(0.0, noise,
                                                                     (20000, *mean.shape))
        sums = np.einsum("nij,ij->n", draws, w)
        measured = sums.mean() / sums.std()
        weighted = float(np.sum(w * mean))
        background_only = weighted / (noise * np.sqrt(np.sum(w * w)))
        snr = float(shot_noise_snr(np.array([weighted]), np.array([background_only]))[0])
        assert abs(snr / measured - 1.0) < 0.04, (flux, noise, snr, measured)
    assert background_only > 3 * measured


def test_shot_noise_snr_of_nothing_is_zero():
    out = shot_noise_snr(np.array([0.0, -5.0, 10.0]), np.array([0.0, -1.0, 0.0]))
    assert out[0] == 0.0 and out[1] < 0 and np.isfinite(out).all()


def test_faint_photon_counted_stars_on_a_black_sky_are_kept():
    """Stars of 60-200 photon counts (1 ADU each) on an 8-bit sky that reads 0: their
    background-only SNR reads 15-70 while their shape is known to SNR 5-9, so the shape
    tests must not judge them on the background's noise (judged so, one in ten was
    rejected as a particle's charge or a track's remnant). A one-pixel hit of 40 counts
    is still rejected (by the impulse stage), and nothing else is reported."""
    rng = np.random.default_rng(21)
    shape = (256, 256)
    det = make_detector(DetectConfig(), shape, 8)
    found = total = false = 0
    for _ in range(6):
        gy, gx = np.meshgrid(np.linspace(24, 232, 6), np.linspace(24, 232, 6), indexing="ij")
        xs = gx.ravel() + rng.uniform(-0.5, 0.5, gx.size)
        ys = gy.ravel() + rng.uniform(-0.5, 0.5, gy.size)
        flux = rng.uniform(60.0, 200.0, xs.size)
        light = np.zeros(shape)
        for x, y, f in zip(xs, ys, flux, strict=True):
            r0, c0 = int(round(y)), int(round(x))
            light[r0 - 5:r0 + 6, c0 - 5:c0 + 6] += _star(f, 1.2, 5, (x - c0, y - r0))
        image = rng.poisson(light + 0.002)
        image[128, 128] += 40
        result = det.detect(np.clip(image, 0, 255).astype(np.uint8))
        d = np.hypot(xs[:, None] - result.stars["x"][None], ys[:, None] - result.stars["y"][None])
        found += int(np.count_nonzero(d.min(axis=1) < 2.0)) if result.count else 0
        false += int(np.count_nonzero(d.min(axis=0) >= 3.0)) if result.count else 0
        total += xs.size
    assert found / total >= 0.98, (found, total)   # 0.90 with the background-only SNR
    assert false == 0


def _hot_pixel_frames(seed: int, measure: bool = True):
    """(stars found, false detections) over three 512 x 512 10-bit frames of 289 faint
    stars (200-1500 ADU, PSF sigma 2.4 px, on a sky of 100 counts) and 600 hot pixels
    8-20 noises high each; ``measure``: detect.psf_measure."""
    rng = np.random.default_rng(seed)
    shape = (512, 512)
    det = make_detector(DetectConfig(max_stars=1024, psf_measure=measure), shape, 10)
    found = false = 0
    for _ in range(3):
        light = np.full(shape, 100.0)
        gy, gx = np.meshgrid(np.arange(20, 502, 30), np.arange(20, 502, 30), indexing="ij")
        xs = gx.ravel() + rng.uniform(-0.5, 0.5, gx.size)
        ys = gy.ravel() + rng.uniform(-0.5, 0.5, gy.size)
        for x, y in zip(xs, ys, strict=True):
            r0, c0 = int(round(y)), int(round(x))
            light[r0 - 8:r0 + 9, c0 - 8:c0 + 9] += _star(rng.uniform(200.0, 1500.0), 2.4, 8,
                                                         (x - c0, y - r0))
        image = rng.poisson(light) + rng.normal(20.0, 2.0, shape)
        hot = rng.integers(5, 507, (2, 600))
        image[hot[0], hot[1]] += rng.uniform(8.0, 20.0, 600) * 10.2
        stars = det.detect(np.clip(np.rint(image), 0, 1023).astype(np.uint16)).stars
        d = np.hypot(xs[:, None] - stars["x"][None], ys[:, None] - stars["y"][None])
        found += int(np.count_nonzero(d.min(axis=1) < 2.0))
        false += int(np.count_nonzero(d.min(axis=0) >= 3.0))
    return found, false


def test_faint_spots_far_narrower_than_a_star_are_rejected(monkeypatch):
    """Below the shape tests' SNR a spot's width is still known to about sqrt(2)/SNR of
    a star's: hot pixels the impulse stage left among faint stars of a wide PSF (their
    noisy 3x3 median and neighbours made them look like light), searched with the
    configured 1.2 px (detect.psf_measure false), are rejected when far narrower than a
    star by more than 4 of that (14 false detections in three frames against 22, the
    point test off), and not one star more is lost. The point test, made on such a
    frame against the sharpest PSF it is made for (tracker.detect.point_spot), leaves 3
    of the 14; the 8 stars it drops of 505 each had one of the frames' 1800 hot pixels
    1.3-2.1 px from its centre (so had none found). With the PSF measured on the
    frames' binned spots (2.3 px, before the one search) the matched filter leaves none
    of them above the threshold, and finds 532 stars, not 497 (576 when the first two
    frames were searched again after their lone hot pixels were cleared: a star with one
    on its core, above its median by half the star's peak, is dropped with it)."""
    found_point, false_point = _hot_pixel_frames(2, measure=False)
    found_measured, false_measured = _hot_pixel_frames(2)
    monkeypatch.setattr(default, "Z_STAR_LOSS", np.inf)
    found, false = _hot_pixel_frames(2, measure=False)
    monkeypatch.setattr(spot_shapes, "_WIDTH_SPREADS", np.inf)
    found_without, false_without = _hot_pixel_frames(2, measure=False)
    assert found == found_without
    assert false <= false_without - 5, (false, false_without)
    assert false_point <= 4 and found_point >= found - 10, (false_point, found_point, found)
    assert false_measured == 0 and found_measured >= found_point + 25
