"""The point test (tracker.detect.point_spot): a faint hot pixel under a PSF wider than a
particle's charge is no star, and a star of the frame's PSF fails it 1 time in 1000."""

from __future__ import annotations

import math

import numpy as np
from spot_grid import SHAPE, SKY_E, found, grid_centres, sensor_frame, spot

from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.point_spot import (
    Z_STAR_LOSS,
    _symmetric_inverse,
    pixel_noise_model,
    point_significance,
)

_NOISE_ADU = 3.0


def _z(spot_sigma_px: float, snr: float, sigma_px: float, count: int,
       rng: np.random.Generator) -> np.ndarray:
    """z of ``count`` spots of optical sigma ``spot_sigma_px`` (0: one pixel, centred) at
    windowed SNR ``snr`` (tracker.detect.windowed's, on 3 ADU of background noise; their
    own shot noise 1 ADU^2 per ADU added), tested against a PSF of ``sigma_px`` at a
    centre off by a faint star's centroid error (sqrt(2) sigma / SNR per axis)."""
    w = math.sqrt(sigma_px ** 2 + 1.0 / 12.0)
    axis = np.arange(-4, 5)
    weight = np.exp(-0.5 * (axis[None, :] ** 2 + axis[:, None] ** 2) / w ** 2)
    out = np.zeros(count)
    for i in range(count):
        if spot_sigma_px == 0:
            phase = (0.0, 0.0)
            unit = np.zeros((9, 9))
            unit[4, 4] = 1.0
        else:
            phase = tuple(rng.uniform(-0.5, 0.5, 2))
            unit = spot(1.0, spot_sigma_px, 4, phase)
        flux = snr * _NOISE_ADU * math.sqrt(np.sum(weight ** 2)) / np.sum(weight * unit)
        image = rng.poisson(flux * unit) + rng.normal(0.0, _NOISE_ADU, unit.shape)
        ex, ey = (p + rng.normal(0.0, math.sqrt(2.0) * w / snr) for p in phase)
        cx, cy = int(round(ex)), int(round(ey))
        light = image[3 + cy:6 + cy, 3 + cx:6 + cx].reshape(1, 9)
        out[i] = point_significance(light, np.array([ex - cx]), np.array([ey - cy]),
                                    np.array([_NOISE_ADU]), sigma_px)[0]
    return out


def test_a_star_fails_one_time_in_a_thousand():
    """Stars of the PSF at SNR 5-20: z is a standard normal (mean 0, spread 1 within their
    sampling error), and 4000 of them fail the test about 4 times (Poisson: at most 12)."""
    rng = np.random.default_rng(3)
    z = np.concatenate([_z(0.85, snr, 0.85, 1000, rng) for snr in (5.0, 7.0, 10.0, 20.0)])
    assert abs(np.mean(z)) < 0.15
    assert 0.93 < np.std(z) < 1.07
    assert np.count_nonzero(z > Z_STAR_LOSS) <= 12


def test_a_hot_pixel_is_a_point():
    """A one-pixel spot at windowed SNR 7 under a PSF of sigma 0.85 px reads z near 6 (module
    docstring): nearly all are rejected."""
    z = _z(0.0, 7.0, 0.85, 500, np.random.default_rng(4))
    assert np.mean(z > Z_STAR_LOSS) > 0.95


def _frames_with_hot_pixels(seed: int, sigma_px: float, impulse_sigma: float,
                            star_share: float = 2.0 / 3.0,
                            star_e: tuple[float, float] = (150.0, 3000.0),
                            hot_e: tuple[float, float] = (35.0, 70.0),
                            raw8: bool = False):
    """(stars kept, stars, hot pixels kept, hot pixels) over two frames of tests/spot_grid.py:
    a share ``star_share`` of the spots stars of PSF sigma ``sigma_px`` (``star_e`` e-),
    the rest hot pixels of ``hot_e`` e- (35-70 e-: windowed SNR about 2.5-5); the
    detector's ``impulse_sigma`` as given. ``raw8``: 8-bit frames of :func:`_raw8_frame`
    on its sky, else spot_grid's 10-bit ones."""
    rng = np.random.default_rng(seed)
    det = make_detector(DetectConfig(max_stars=1024, impulse_sigma=impulse_sigma), SHAPE,
                        8 if raw8 else 10)
    kept = np.zeros(2, int)
    total = np.zeros(2, int)
    for _ in range(2):
        light = np.full(SHAPE, _RAW8_SKY_E if raw8 else SKY_E)
        gx, gy = grid_centres()
        star = rng.random(gx.size) >= 1.0 - star_share
        xs = gx + np.where(star, rng.uniform(-0.5, 0.5, gx.size), 0.0)
        ys = gy + np.where(star, rng.uniform(-0.5, 0.5, gy.size), 0.0)
        for x, y, is_star in zip(xs, ys, star, strict=True):
            r0, c0 = int(round(y)), int(round(x))
            if is_star:
                light[r0 - 9:r0 + 10, c0 - 9:c0 + 10] += spot(
                    rng.uniform(*star_e), sigma_px, 9, (x - c0, y - r0))
            else:
                light[r0, c0] += rng.uniform(*hot_e)
        frame = _raw8_frame(light, rng) if raw8 else sensor_frame(light, rng)
        kept += found(det.detect(frame).stars, xs, ys, star)
        total += (int(np.count_nonzero(star)), int(np.count_nonzero(~star)))
    return kept[0], total[0], kept[1], total[1]


_RAW8_SKY_E = 1.5   # e- a pixel: a near-noiseless integer sky at 8 bits


def _raw8_frame(light_e: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The 8-bit frame of ``light_e`` on a RAW8 OV2311 at analogue gain 1: 5.4 e-/ADU (its
    10-bit ADC's top 8 bits: 0.19 ADU^2 of shot noise per ADU), black level 16 ADU,
    read noise 0.4 ADU, rounding and clipping."""
    image = 16.0 + rng.poisson(light_e) / 5.4 + rng.normal(0.0, 0.4, light_e.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def test_faint_hot_pixels_the_impulse_stage_spares_are_rejected():
    """Sigma 0.85 px, measured on the frame's stars, the impulse stage off (hot pixels it
    spares: on glare, or beside noise that makes them look like a sharp star's core): the
    detector kept 10 of 149 hot pixels before the point test (fainter than the shape
    tests judge), 2 with it, and keeps the 300 stars of 301 it kept before."""
    stars_kept, stars, hot_kept, hot = _frames_with_hot_pixels(5, 0.85, 1000.0)
    assert (stars, hot) == (301, 149)
    assert stars_kept >= 300
    assert hot_kept <= 4, hot_kept


def test_faint_hot_pixels_on_a_raw8_frame_are_rejected_by_its_measured_noise():
    """Issue 12: on a RAW8 frame a star's shot noise is 0.19 ADU^2 per ADU, not the 1 the
    test took, and its integer sky reads noisier than its pixels are; the noise model
    measured on the frame's faint spots (tracker.detect.point_spot.pixel_noise_model)
    rejects the faint hot pixels (22-38 e-, 4-7 ADU) that passed as stars. The impulse
    stage off, as in the test above. Figures from a run (seed 6,
    sigma 0.85 px): hot pixels kept 51 -> 7 of 146, all 304 stars kept as before (seed
    7: 53 -> 6 of 151, 299 of 299)."""
    stars_kept, stars, hot_kept, hot = _frames_with_hot_pixels(
        6, 0.85, 1000.0, hot_e=(22.0, 38.0), raw8=True)
    assert (stars, hot) == (304, 146)
    assert stars_kept >= stars - 1
    assert hot_kept <= 12, hot_kept


def _shot_limited_spots(count: int, rng: np.random.Generator, shot_adu: float,
                        noise_adu: float) -> tuple[np.ndarray, ...]:
    """(light, phase_x, phase_y) of ``count`` stars of sigma 0.9 px and 20-150 ADU at
    random phases: shot noise of ``shot_adu`` ADU^2 per ADU, background noise
    ``noise_adu``."""
    light = np.zeros((count, 9))
    phases = rng.uniform(-0.5, 0.5, (count, 2))
    for i in range(count):
        mean = spot(rng.uniform(20.0, 150.0), 0.9, 1, tuple(phases[i])).ravel()
        light[i] = shot_adu * rng.poisson(mean / shot_adu) + rng.normal(0.0, noise_adu, 9)
    return light, phases[:, 0], phases[:, 1]


def test_the_noise_model_bounds_a_raw8_frames_shot_noise_from_above():
    """150 stars of 0.2 ADU^2 of shot noise per ADU (a RAW8 OV2311 frame's) on 0.5 ADU of
    noise the background read as 0.75: g is measured at its upper bound, above the truth
    and well under the 1 taken before (0.22-0.26 by a run over these five seeds), and s
    at most 1. Fewer than 20 spots leave (1, 1)."""
    for seed in range(5):
        light, px, py = _shot_limited_spots(150, np.random.default_rng(seed), 0.2, 0.5)
        scale, shot = pixel_noise_model(light, px, py, np.full(150, 0.75), 0.9)
        assert 0.2 < shot < 0.4, (seed, shot)
        assert 0.25 / 0.75 ** 2 <= scale <= 1.0
        few = pixel_noise_model(light[:19], px[:19], py[:19], np.full(19, 0.75), 0.9)
        assert few == (1.0, 1.0)


def test_faint_hot_pixels_are_rejected_on_a_frame_whose_stars_did_not_measure_its_psf():
    """Issue 12: a frame of few faint stars (3 % of the spots, sigma 1.6 px, 300-1000 e-)
    does not measure its PSF and carries the configured 1.2 px; a hot pixel's light is in
    one pixel whatever the PSF, so its spots are tested against the sharpest PSF the test
    is made for. Figures from a run (seed 7, the impulse stage off): hot pixels kept 7 ->
    3 of 437 (the same 7 with the measured noise model alone), stars 12 of 13 as before."""
    stars_kept, stars, hot_kept, hot = _frames_with_hot_pixels(
        7, 1.6, 1000.0, star_share=0.03, star_e=(300.0, 1000.0))
    assert (stars, hot) == (13, 437)
    assert stars_kept >= 12
    assert hot_kept <= 4, hot_kept


def test_the_noise_models_symmetric_inverse_is_the_matrix_inverse():
    """The closed-form inverse (no LAPACK call in the frame loop) of spots' 3 x 3 Gram
    matrices times the matrices is the identity."""
    basis = np.random.default_rng(5).normal(size=(300, 9, 3))
    gram = np.einsum("mik,mil->mkl", basis, basis)
    product = np.einsum("mkl,mln->mkn", _symmetric_inverse(gram), gram)
    assert np.abs(product - np.eye(3)).max() < 1e-12
