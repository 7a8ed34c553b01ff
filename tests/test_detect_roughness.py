"""A star's pixel-scale roughness and its spread (tracker.detect.roughness), and the test
the default detector makes with them: track remnants rejected, faint round stars kept."""

from __future__ import annotations

import numpy as np
from test_detect_significance import _star

import tracker.detect.spot_shapes as spot_shapes
from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.default import effective_sigma
from tracker.detect.roughness import StarRoughness
from tracker.sim.scene import Scene, particle_tracks


def _roughness(s: np.ndarray, noise: float) -> np.ndarray:
    """tracker.detect.windowed's roughness of windows s (n, side, side), written out."""
    side = s.shape[1]
    lap = (4.0 * s[:, 1:-1, 1:-1] - s[:, :-2, 1:-1] - s[:, 2:, 1:-1] - s[:, 1:-1, :-2]
           - s[:, 1:-1, 2:])
    var = noise * noise
    return (((lap * lap).sum(axis=(1, 2)) - 20.0 * (side - 2) ** 2 * var)
            / ((s * s).sum(axis=(1, 2)) - side * side * var))


def test_a_stars_roughness_and_its_spread_match_noisy_stars():
    """Photon-counting stars (1 ADU a count) on Gaussian background noise, 20000 draws each,
    from background-limited to shot-limited and PSF sigma 0.8-2 px: the mean roughness
    is the model's within 3 % (under a 1.3 px PSF the shot noise alone makes a faint
    star read 3-5 times a noise-free point source's) and its standard deviation within
    15 %."""
    rng = np.random.default_rng(7)
    for sigma_px, flux, noise in ((0.8, 150.0, 2.2), (1.3, 370.0, 2.2), (1.3, 3000.0, 1.0),
                                  (2.0, 1000.0, 2.2), (1.3, 200.0, 0.5)):
        radius = int(np.ceil(3.0 * effective_sigma(sigma_px)))
        model = StarRoughness.of(radius, sigma_px)
        phase = rng.uniform(-0.5, 0.5, 2)
        mean = _star(flux, sigma_px, radius, phase)
        draws = rng.poisson(mean, (20000, *mean.shape)) + rng.normal(0.0, noise,
                                                                     (20000, *mean.shape))
        rough = _roughness(draws, noise)
        expected = float(model.expected(flux))
        assert abs(rough.mean() / expected - 1.0) < 0.03, (sigma_px, flux, rough.mean())
        assert abs(rough.std() / float(model.spread(flux, noise)) - 1.0) < 0.15, (
            sigma_px, flux, rough.std())
        if sigma_px >= 1.3 and flux < 500.0:
            assert expected > 3.0 * model.r0


def _frame(rng, shape, sigma_px, flux, spacing, tracks):
    """A 10-bit frame of round stars of ``flux`` (a range, ADU) on a grid of ``spacing`` px
    (shot noise at 1 ADU a count, the background's 2 ADU) and ``tracks`` particle tracks
    (tracker.sim.scene, 1.35 e-/ADU); the stars' positions and the tracks' charge (ADU)."""
    light = np.zeros(shape)
    gy, gx = np.meshgrid(np.arange(20, shape[0] - 10, spacing),
                         np.arange(20, shape[1] - 10, spacing), indexing="ij")
    xs = gx.ravel() + rng.uniform(-0.5, 0.5, gx.size)
    ys = gy.ravel() + rng.uniform(-0.5, 0.5, gy.size)
    for x, y in zip(xs, ys, strict=True):
        r0, c0 = int(round(y)), int(round(x))
        light[r0 - 8:r0 + 9, c0 - 8:c0 + 9] += _star(rng.uniform(*flux), sigma_px, 8,
                                                     (x - c0, y - r0))
    scene = Scene.empty(shape)
    particle_tracks(scene, rng, tracks)
    charge = scene.deposits / 1.35
    adu = rng.poisson(light) + charge + rng.normal(20.0, 2.0, shape)
    return np.clip(np.rint(adu), 0, 1023).astype(np.uint16), xs, ys, charge


def _run(seed: int, sigma_px: float, flux, spacing: int, tracks: int):
    """(stars found, stars no track crossed, false detections) over three frames."""
    rng = np.random.default_rng(seed)
    shape = (512, 512)
    det = make_detector(DetectConfig(max_stars=1024), shape, 10)
    found = clear = false = 0
    for _ in range(3):
        image, xs, ys, charge = _frame(rng, shape, sigma_px, flux, spacing, tracks)
        stars = det.detect(image).stars
        d = np.hypot(xs[:, None] - stars["x"][None], ys[:, None] - stars["y"][None])
        # a star a track crossed is not the test's: the track's charge is in its window
        r, c = np.rint(ys).astype(int), np.rint(xs).astype(int)
        crossed = np.array([charge[a - 6:a + 7, b - 6:b + 7].max() > 10.0
                            for a, b in zip(r, c, strict=True)])
        found += int(np.count_nonzero((d.min(axis=1) < 2.0) & ~crossed))
        clear += int(np.count_nonzero(~crossed))
        false += int(np.count_nonzero(d.min(axis=0) >= 3.0))
    return found, clear, false


def test_faint_round_stars_are_not_taken_for_track_remnants():
    """1323 round stars of 150-600 ADU (windowed SNR 25-100 over a 2 ADU background; a
    third of that with their own shot noise), PSF sigma 1.3 px: none is taken for a track
    remnant. Their roughness is judged against a star's of their own flux on their own
    noise (judged against a noise-free point source's, scaled to the frame's bright stars,
    5 were taken for track remnants, the shot noise alone making a faint star read three
    times a point source's). The point test (tracker.detect.point_spot) judges the 126
    of them fainter than ``sharp_min_snr`` with their shot noise, and loses a star 1 time
    in 1000 by design: here one (z 3.31; theirs spread as a standard normal, mean -0.03,
    standard deviation 1.04)."""
    found, clear, false = _run(1, 1.3, (150.0, 600.0), 24, 0)
    assert clear == 1323
    assert found >= clear - 1
    assert false == 0


def test_track_remnants_are_rejected(monkeypatch):
    """Pieces of diffused particle tracks (200 a frame, a few pixels long, charge spread
    0.45 px; tracker.sim.scene) among stars of PSF sigma 0.8 px: the remnant rule (narrow
    and rougher than a star of the spot's flux, by 3 times and beyond 4 of its noise's
    spreads) rejects pieces the rest of the detector lets through, and no star no track
    crossed is lost. Since frames whose bright peaks give no PSF measure it on the frame
    binned before their one search, the rest of the detector lets through few: 8 false
    detections in three frames, 9 without the rule (18 and 27 when such frames kept the
    prior 1.2 px for their first search); the bound of 10 keeps that gain. (At 120
    tracks and 1 px the impulse stage's cleared tracks leave 2 pieces, with the rule
    or without.)"""
    found, clear, false = _run(11, 0.8, (150.0, 1500.0), 40, 200)
    assert found == clear
    assert false <= 10, false
    monkeypatch.setattr(spot_shapes, "_REMNANT_ROUGH", np.inf)
    _, _, false_without = _run(11, 0.8, (150.0, 1500.0), 40, 200)
    assert false < false_without, (false, false_without)
