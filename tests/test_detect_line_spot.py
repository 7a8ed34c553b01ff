"""The short-track test (tracker.detect.line_spot): a particle's track one to three pixels
long under a sharp PSF is no star, while stars of the frame's PSF, elongated alike by the
PSF's ellipticity or a slew's trail, pass it (issue 12: tracks were most of the glare and
lunar sets' false detections)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from spot_grid import SHAPE, SKY_E, found, grid_centres, sensor_frame, spot

from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.line_spot import (
    CLIP_MIN_PIXELS,
    _solve,
    clipped_lines,
    floor_fit,
    line_fit,
    track_spots,
)

_DIFFUSION_PX = 0.45    # a particle's charge cloud (tracker.sim.scene.particle_tracks)
_NOISE_ADU = 3.0


def _segment(flux: float, sigma_px: float, length_px: float, angle: float, radius: int,
             phase: tuple[float, float]) -> np.ndarray:
    """A line of ``length_px`` at ``angle`` (radians from +x) of Gaussian cross-section
    ``sigma_px``, pixel-integrated, ``flux`` in all, centred ``phase`` px off the box's
    centre: a particle's track (sigma the charge's diffusion) or a trailed star (the PSF's)."""
    steps = max(2, int(math.ceil(length_px / 0.1)) + 1)
    out = np.zeros((2 * radius + 1, 2 * radius + 1))
    for t in np.linspace(-0.5, 0.5, steps):
        at = (phase[0] + t * length_px * math.cos(angle),
              phase[1] + t * length_px * math.sin(angle))
        out += spot(flux / steps, sigma_px, radius, at)
    return out


def _fit(units: list[np.ndarray], phases: np.ndarray, snr: float, sigma_px: float,
         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """line_fit of unit-flux 5 x 5 ``units`` scaled to peak SNR ``snr`` on 3 ADU of noise,
    their own shot noise 1 ADU^2 per ADU, at centres off by a centroid's error."""
    light, px, py = [], [], []
    for unit, phase in zip(units, phases, strict=True):
        flux = snr * _NOISE_ADU / unit.max()
        image = rng.poisson(flux * unit) + rng.normal(0.0, _NOISE_ADU, unit.shape)
        light.append(image.ravel())
        error = rng.normal(0.0, math.sqrt(2.0) * sigma_px / snr, 2)
        px.append(phase[0] + error[0])
        py.append(phase[1] + error[1])
    noise = np.full(len(units), _NOISE_ADU)
    return line_fit(np.array(light), np.array(px), np.array(py), noise, sigma_px)


def _stars_and_tracks(sigma_px: float, snr: float, length_px: tuple[float, float],
                      rng: np.random.Generator, stars: int = 300,
                      tracks: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """(stars found tracks, tracks found tracks), the stars setting the reference."""
    phases = rng.uniform(-0.5, 0.5, (stars + tracks, 2))
    units = [spot(1.0, sigma_px, 2, tuple(p)) for p in phases[:stars]]
    units += [_segment(1.0, _DIFFUSION_PX, float(rng.uniform(*length_px)),
                       float(rng.uniform(0.0, math.pi)), 2, tuple(p)) for p in phases[stars:]]
    coef, cov = _fit(units, phases, snr, sigma_px, rng)
    reference = np.arange(stars + tracks) < stars
    out = track_spots(coef, cov, reference, sigma_px)
    return out[:stars], out[stars:]


def test_solve_matches_numpy():
    """The solutions and the inverses' second-order block of positive definite systems
    as conditioned as the fit's (a sharp to a wide PSF's basis) agree with LAPACK's."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(20, 6, 9)) * np.logspace(0.0, -3.0, 6)[None, :, None]
    gram = np.einsum("mik,mjk->mij", a, a)
    rhs = rng.normal(size=(20, 6))
    coef, block = _solve(gram.transpose(1, 2, 0), rhs.T)
    assert np.allclose(coef, np.linalg.solve(gram, rhs[:, :, None])[:, :, 0], rtol=1e-9)
    assert np.allclose(block, np.linalg.inv(gram)[:, 3:, 3:], rtol=1e-9)


def _pixel_gaussian(cx: float, cy: float, sigma_px: float) -> np.ndarray:
    """A unit Gaussian centred (cx, cy) px off the middle pixel's centre, integrated
    over the 5 x 5 pixels (math.erf), row-major."""
    def axis(c):
        edges = np.arange(-2.5, 3.0) - c
        cdf = np.array([0.5 * math.erf(e / (sigma_px * math.sqrt(2.0))) for e in edges])
        return np.diff(cdf)
    return np.outer(axis(cy), axis(cx)).ravel()


def test_line_fit_is_the_weighted_least_squares_fit():
    """Against the fit made independently: the derivatives by finite differences of the
    pixel-integrated Gaussian, the weighted least squares by LAPACK."""
    rng = np.random.default_rng(2)
    sigma, h, noise, shot = 0.8, 1e-3, 3.0, 1.0
    for _ in range(5):
        cx, cy = rng.uniform(-0.5, 0.5, 2)
        def g(dx, dy, cx=cx, cy=cy):
            return _pixel_gaussian(cx + dx, cy + dy, sigma)
        design = np.stack([g(0, 0), (g(h, 0) - g(-h, 0)) / (2 * h),
                           (g(0, h) - g(0, -h)) / (2 * h),
                           (g(h, 0) - 2 * g(0, 0) + g(-h, 0)) / h ** 2,
                           (g(h, h) - g(h, -h) - g(-h, h) + g(-h, -h)) / (4 * h * h),
                           (g(0, h) - 2 * g(0, 0) + g(0, -h)) / h ** 2], axis=1)
        light = 2000.0 * _segment(1.0, 0.6, 1.5, 0.3, 2, (cx, cy)).ravel()
        light += rng.normal(0.0, noise, 25)
        p = design[:, 0]
        weight = 1.0 / (noise ** 2 + shot * max(p @ light / (p @ p), 0.0) * p)
        normal = design.T @ (weight[:, None] * design)
        expected = np.linalg.solve(normal, design.T @ (weight * light))
        coef, cov = line_fit(light[None, :], np.array([cx]), np.array([cy]),
                             np.array([noise]), sigma, shot)
        se = np.sqrt(np.diag(np.linalg.inv(normal)))
        assert np.all(np.abs(coef[0] - expected) < 1e-4 * se)
        assert np.allclose(cov[0], np.linalg.inv(normal)[3:, 3:], rtol=1e-4)


def test_stars_pass_and_short_tracks_fail_under_a_sharp_psf():
    """PSF sigma 0.65 px, peak SNR 15-150: no star of 900 is taken for a track (its
    chance is 1 in 10^4 by the test's design); of tracks 1.5-3 px long, more the brighter
    (seed 5 read 15, 76 and 100 %: the limits are those less a few binomial spreads)."""
    rng = np.random.default_rng(5)
    for snr, least in ((15.0, 0.05), (40.0, 0.6), (150.0, 0.95)):
        stars, tracks = _stars_and_tracks(0.65, snr, (1.5, 3.0), rng)
        assert np.count_nonzero(stars) == 0
        assert np.mean(tracks) >= least, (snr, np.mean(tracks))


def test_elongated_psf_and_trailed_stars_pass():
    """Stars all elongated alike, by a PSF's ellipticity or a slew's 1.5 px trail, set the
    reference and pass; a frame trailed far beyond the PSF's width is not tested."""
    rng = np.random.default_rng(6)
    for length in (0.8, 1.5, 6.0):
        phases = rng.uniform(-0.5, 0.5, (200, 2))
        units = [_segment(1.0, 0.65, length, 0.4, 2, tuple(p)) for p in phases]
        coef, cov = _fit(units, phases, 60.0, 0.65, rng)
        assert not track_spots(coef, cov, np.ones(200, bool), 0.65).any(), length


Light = Callable[[np.random.Generator, tuple[float, float]], np.ndarray]


def _grid_frame(seed: int, star_light: Light, impostor: Light) -> tuple[np.ndarray, ...]:
    """A tests/spot_grid.py frame: two thirds of its spots stars ``star_light(rng,
    phase)``, a third ``impostor(rng, phase)`` (13 x 13 e-), at random pixel phases;
    (image, xs, ys, star mask)."""
    rng = np.random.default_rng(seed)
    xs, ys = grid_centres()
    star = rng.random(len(xs)) < 2.0 / 3.0
    light = np.full(SHAPE, SKY_E)
    for x, y, is_star in zip(xs, ys, star, strict=True):
        phase = tuple(rng.uniform(-0.5, 0.5, 2))
        unit = star_light(rng, phase) if is_star else impostor(rng, phase)
        light[y - 6:y + 7, x - 6:x + 7] += unit
    return sensor_frame(light, rng), xs, ys, star


def _faint_star(sigma_px: float) -> Light:
    """Stars of PSF sigma ``sigma_px``, 400-4000 e-."""
    return lambda rng, phase: spot(float(rng.uniform(400.0, 4000.0)), sigma_px, 6, phase)


def _short_track(rng: np.random.Generator, phase: tuple[float, float]) -> np.ndarray:
    """A particle's track 1.5-3 px long at any angle, 1500-4000 e-."""
    return _segment(float(rng.uniform(1500.0, 4000.0)), _DIFFUSION_PX,
                    float(rng.uniform(1.5, 3.0)), float(rng.uniform(0.0, math.pi)), 6, phase)


def _one_pixel_hit(rng: np.random.Generator, phase: tuple[float, float]) -> np.ndarray:
    """A particle's hit of 800-3000 e- centred within 0.15 px of a pixel's centre."""
    return spot(float(rng.uniform(800.0, 3000.0)), _DIFFUSION_PX, 6,
                (0.3 * phase[0], 0.3 * phase[1]))


def _round_hit(rng: np.random.Generator, phase: tuple[float, float]) -> np.ndarray:
    """A particle's hit of 800-3000 e- at any pixel phase: its charge cloud alone."""
    return spot(float(rng.uniform(800.0, 3000.0)), _DIFFUSION_PX, 6, phase)


def _found_on_grid(impostor: Light, sigma_px: float, seeds: tuple[int, int],
                   star_light: Light | None = None) -> tuple[int, ...]:
    """(stars found, stars, impostors found, impostors) over two :func:`_grid_frame`s,
    their stars ``star_light`` (default :func:`_faint_star` of ``sigma_px``)."""
    det = make_detector(DetectConfig(max_stars=1024), SHAPE, 10)
    out = np.zeros(4, int)
    for seed in seeds:
        image, xs, ys, star = _grid_frame(seed, star_light or _faint_star(sigma_px), impostor)
        kept = found(det.detect(image).stars, xs, ys, star)
        out += (kept[0], np.count_nonzero(star), kept[1], np.count_nonzero(~star))
    return tuple(int(v) for v in out)


def test_detector_drops_short_tracks_and_keeps_stars():
    """Two frames of the grid under a 0.65 px PSF: every star is found, and of the ~150
    short tracks at most a tenth are reported (before the test: 112 of 154; after: 0)."""
    stars_found, stars, tracks_found, tracks = _found_on_grid(_short_track, 0.65, (11, 12))
    assert stars_found == stars
    assert tracks_found <= 0.1 * tracks, (tracks_found, tracks)


def test_a_hits_remnant_is_dropped_and_stars_kept():
    """A one-pixel hit whose core the impulse stage replaced leaves its wings, which the
    search finds (before: 66 of 146 hits under a 0.70 px PSF reported); the spot on them
    is dropped (4 left; none since round hits narrower than the stars are) and every star
    kept."""
    stars_found, stars, hits_found, hits = _found_on_grid(_one_pixel_hit, 0.7, (21, 22))
    assert stars_found == stars
    assert hits_found <= 0.1 * hits, (hits_found, hits)



def _faint_or_saturated_star(rng: np.random.Generator, phase: tuple[float, float]) -> np.ndarray:
    """Half the stars (PSF sigma 0.65 px) 400-4000 e-, half 8000-30000 e- (their cores
    clipped at full scale, 1381 e- over the sky)."""
    flux = rng.uniform(400.0, 4000.0) if rng.random() < 0.5 else rng.uniform(8000.0, 30000.0)
    return spot(float(flux), 0.65, 6, phase)


def _saturated_track(rng: np.random.Generator, phase: tuple[float, float]) -> np.ndarray:
    """A particle's track 1.5-3 px long at any angle, 4000-12000 e- (clipped along its
    middle)."""
    return _segment(float(rng.uniform(4000.0, 12000.0)), _DIFFUSION_PX,
                    float(rng.uniform(1.5, 3.0)), float(rng.uniform(0.0, math.pi)), 6, phase)


def test_saturated_short_tracks_are_dropped_and_saturated_stars_kept():
    """A grid under a 0.65 px PSF whose stars are half faint and half saturated, its
    impostors saturated short tracks: the track test fits the clipped spots on their
    unclipped pixels. Every star is found; of the ~150 tracks at most a tenth are
    reported (before: 51 of 152; after: 0; seeds 33, 34 read 46 of 149 and 0)."""
    stars_found, stars, tracks_found, tracks = _found_on_grid(
        _saturated_track, 0.65, (31, 32), _faint_or_saturated_star)
    assert stars_found == stars
    assert tracks_found <= 0.1 * tracks, (tracks_found, tracks)


def test_round_hits_narrower_than_the_stars_are_dropped():
    """Round hits at any pixel phase under a 0.62 px PSF (measured 0.59): a charge cloud
    of 0.45 px is narrower overall than the stars the PSF was measured on, at the hit's
    own phase. Every star is found; of the ~155 hits at most a tenth are reported
    (before the narrow test: 72; after: 2; under a 0.70 px PSF, seeds 41-43: 24 of 228
    and 1)."""
    stars_found, stars, hits_found, hits = _found_on_grid(_round_hit, 0.62, (41, 42))
    assert stars_found == stars
    assert hits_found <= 0.1 * hits, (hits_found, hits)


def test_narrow_test_passes_stars_of_any_brightness():
    """The narrow test's reference is the stars the PSF was measured on (the brightest):
    fainter stars of the same PSF pass it at peak SNR 15-150 (none of 900 taken for a
    hit), while round hits of 0.45 px are found the more the brighter (seed 7 read 5, 86
    and 100 %: the limits are those less a few binomial spreads)."""
    rng = np.random.default_rng(7)
    sigma = 0.65
    bright_phases = rng.uniform(-0.5, 0.5, (40, 2))
    bright = [spot(1.0, sigma, 2, tuple(p)) for p in bright_phases]
    for snr, least in ((15.0, 0.0), (40.0, 0.75), (150.0, 0.95)):
        phases = rng.uniform(-0.5, 0.5, (400, 2))
        units = [spot(1.0, sigma, 2, tuple(p)) for p in phases[:300]]
        units += [spot(1.0, _DIFFUSION_PX, 2, tuple(p)) for p in phases[300:]]
        coef_b, cov_b = _fit(bright, bright_phases, 200.0, sigma, rng)
        coef, cov = _fit(units, phases, snr, sigma, rng)
        coef, cov = np.concatenate([coef_b, coef]), np.concatenate([cov_b, cov])
        measured = np.arange(len(coef)) < 40
        out = track_spots(coef, cov, measured, sigma, measured)[40:]
        assert np.count_nonzero(out[:300]) == 0, snr
        assert np.mean(out[300:]) >= least, (snr, np.mean(out[300:]))


def _elliptical_star(sigma_px: float, ellipticity: float, angle: float,
                     phase: tuple[float, float]) -> np.ndarray:
    """A unit-peak elliptical Gaussian (axes' variances sigma^2 (1 +- e)) on the 5 x 5,
    each pixel the mean of 10 x 10 samples over its area, centred ``phase`` px off the
    middle pixel's centre."""
    sub = (np.arange(10) + 0.5) / 10.0 - 0.5
    y, x = np.mgrid[-2:3, -2:3].astype(float)
    dx = x[..., None, None] + sub[None, None, None, :] - phase[0]
    dy = y[..., None, None] + sub[None, None, :, None] - phase[1]
    along = dx * math.cos(angle) + dy * math.sin(angle)
    across = -dx * math.sin(angle) + dy * math.cos(angle)
    light = np.exp(-0.5 * (along ** 2 / (sigma_px ** 2 * (1.0 + ellipticity))
                           + across ** 2 / (sigma_px ** 2 * (1.0 - ellipticity))))
    return light.mean(axis=(2, 3))


def _clipped(light: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``light``'s pixels at or above a full scale drawn at 5-70 % of its peak, (25,)."""
    return (light >= rng.uniform(0.05, 0.7) * light.max()).ravel()


def test_a_stars_clipped_core_is_its_psf_and_a_tracks_a_line():
    """Clipped cores of 6 pixels and more: of stars of sigma 0.6-3 px, round or of
    ellipticity 0.15 (told to the test), at any phase and full scale, none is taken for
    a line; of particles' tracks 3-8 px long at any angle, most are."""
    rng = np.random.default_rng(5)
    stars, tracks = [], []
    while len(stars) < 1500:
        e = float(rng.choice([0.0, 0.15]))
        core = _clipped(_elliptical_star(float(rng.uniform(0.6, 3.0)), e,
                                         float(rng.uniform(0.0, math.pi)),
                                         tuple(rng.uniform(-0.5, 0.5, 2))), rng)
        if np.count_nonzero(core) >= CLIP_MIN_PIXELS:
            stars.append((core, e))
    while len(tracks) < 500:
        light = _segment(1.0, _DIFFUSION_PX, float(rng.uniform(3.0, 8.0)),
                         float(rng.uniform(0.0, math.pi)), 2, tuple(rng.uniform(-0.5, 0.5, 2)))
        core = _clipped(light, rng)
        if np.count_nonzero(core) >= CLIP_MIN_PIXELS:
            tracks.append(core)
    for e in (0.0, 0.15):
        cores = np.array([c for c, ce in stars if ce == e])
        assert not clipped_lines(cores, e).any()
    assert np.count_nonzero(clipped_lines(np.array(tracks), 0.0)) >= 0.8 * len(tracks)


def test_the_psfs_own_shape_is_the_reference_when_few_bright_spots_set_it():
    """Fewer than five bright spots (the lunar frame of a particle event with three bright
    stars): the PSF measured on the frame, of ellipticity 0 or 0.15 at any angle, sets the
    stars' shape. Of its stars at peak SNR 15-150 none is taken for a track (1 in 10^5
    by design); of tracks 2-4 px long, more the brighter (seed 8 read 15-19, 52-53 and
    65-97 %: the limits are those less a few binomial spreads). Without the PSF's shape
    none is tested."""
    rng = np.random.default_rng(8)
    sigma = 0.65
    for snr, least in ((15.0, 0.05), (40.0, 0.35), (150.0, 0.5)):
        for e in (0.0, 0.15):
            angle = float(rng.uniform(0.0, math.pi))
            phases = rng.uniform(-0.5, 0.5, (400, 2))
            units = [_elliptical_star(sigma, e, angle, tuple(p)) for p in phases[:300]]
            units += [_segment(1.0, _DIFFUSION_PX, float(rng.uniform(2.0, 4.0)),
                               float(rng.uniform(0.0, math.pi)), 2, tuple(p))
                      for p in phases[300:]]
            coef, cov = _fit(units, phases, snr, sigma, rng)
            few = np.arange(400) < 3
            shear = e * sigma ** 2 * np.array([math.cos(2 * angle), math.sin(2 * angle)])
            out = track_spots(coef, cov, few, sigma, psf_shear=shear)
            assert np.count_nonzero(out[:300]) == 0, (snr, e)
            assert np.mean(out[300:]) >= least, (snr, e, np.mean(out[300:]))
            assert not track_spots(coef, cov, few, sigma).any()


def _one_clipped(sigma_px: float, noise: float, rng: np.random.Generator,
                 count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` spots of ``sigma_px`` at any phase whose light reaches full scale in one
    pixel (the middle one): full scale 10-40 noises above the background, the peak 1.1-4
    times it. (light (count, 25) clipped at full scale, clipped (count, 25), phases
    (count, 2) with a centroid's error)."""
    light, clipped, phases = [], [], []
    while len(light) < count:
        phase = tuple(rng.uniform(-0.5, 0.5, 2))
        unit = spot(1.0, sigma_px, 2, phase)
        full = float(rng.uniform(10.0, 40.0)) * noise
        flux = float(rng.uniform(1.1, 4.0)) * full / unit.max()
        image = (rng.poisson(flux * unit) + rng.normal(0.0, noise, unit.shape)).ravel()
        over = image >= full
        if np.count_nonzero(over) != 1 or not over[12]:
            continue
        light.append(np.minimum(image, full))
        clipped.append(over)
        phases.append(np.array(phase) + rng.normal(0.0, 0.05, 2))
    return np.array(light), np.array(clipped), np.array(phases)


def test_a_spot_of_one_clipped_pixel_is_judged_narrow_with_that_pixel_at_its_floor():
    """A saturated spot of one clipped pixel: taken at full scale that pixel bounds the
    spot's trace from above (the more light in it, the narrower), so the narrow test may
    judge that fit. Of stars of sigma 0.6-1 px none is taken for a hit (3000 a sigma of
    0.55-1.3 px read at most 2 standard errors narrow); of round hits (0.45 px) more are
    found than by the fit that leaves the pixel out (seed 9 read 23, 73 and 100 % against
    17, 57 and 87 %: the limits are those less a few binomial spreads)."""
    rng = np.random.default_rng(9)
    noise = 20.0
    for sigma, least in ((0.6, 0.1), (0.7, 0.6), (1.0, 0.9)):
        bright_phases = rng.uniform(-0.5, 0.5, (40, 2))
        bright = [spot(1.0, sigma, 2, tuple(p)) for p in bright_phases]
        coef_b, cov_b = _fit(bright, bright_phases, 200.0, sigma, rng)
        stars = _one_clipped(sigma, noise, rng, 300)
        hits = _one_clipped(_DIFFUSION_PX, noise, rng, 100)
        light, clipped, phases = (np.concatenate(p) for p in zip(stars, hits, strict=True))
        spots = len(light)
        noises = np.full(spots, noise)
        coef, cov = line_fit(light, phases[:, 0], phases[:, 1], noises, sigma, usable=~clipped)
        f_coef, f_cov, bounded = floor_fit(light, clipped, phases[:, 0], phases[:, 1], noises,
                                           sigma)
        coef, cov = np.concatenate([coef_b, coef]), np.concatenate([cov_b, cov])
        measured = np.arange(40 + spots) < 40
        which = 40 + np.flatnonzero(bounded)
        out = track_spots(coef, cov, measured, sigma, measured,
                          floor=(f_coef[bounded], f_cov[bounded], which))[40:]
        censored = track_spots(coef, cov, measured, sigma, measured)[40:]
        assert np.count_nonzero(out[:300]) == 0, sigma
        assert np.mean(out[300:]) >= least, (sigma, np.mean(out[300:]))
        assert np.count_nonzero(out[300:]) > np.count_nonzero(censored[300:]), sigma


def test_floor_fits_are_each_spots_own_fits_to_the_bit():
    """floor_fit fits its spots at the floor and raised in one stack (issue 12's time):
    each spot's coefficients and covariance are its own fit's alone, to the bit, and its
    bound that of the spot judged alone."""
    rng = np.random.default_rng(4)
    light, clipped, phases = _one_clipped(0.7, 20.0, rng, 60)
    noises = rng.uniform(10.0, 30.0, len(light))
    coef, cov, bounded = floor_fit(light, clipped, phases[:, 0], phases[:, 1], noises, 0.7)
    for i in range(len(light)):
        one = slice(i, i + 1)
        at_floor = line_fit(light[one], phases[one, 0], phases[one, 1], noises[one], 0.7)
        alone = floor_fit(light[one], clipped[one], phases[one, 0], phases[one, 1],
                          noises[one], 0.7)
        assert np.array_equal(coef[i], at_floor[0][0]) and np.array_equal(cov[i], at_floor[1][0])
        assert bounded[i] == alone[2][0]
    assert np.count_nonzero(bounded) > 0


def _edge_frame(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A tests/spot_grid.py frame of faint stars (sigma 0.65 px) on its grid, and along its
    four edges, 1-1.5 px inside them (their 5 x 5 reaching beyond the frame), stars and
    short tracks in turn; (image, xs, ys, star mask) of the edge spots."""
    rng = np.random.default_rng(seed)
    light = np.full(SHAPE, SKY_E)
    gx, gy = grid_centres()
    for x, y in zip(gx, gy, strict=True):
        light[y - 6:y + 7, x - 6:x + 7] += _faint_star(0.65)(rng, tuple(rng.uniform(-0.5, 0.5, 2)))
    along = np.arange(40, SHAPE[0] - 40, 24)
    near = np.full(len(along), 1)
    xs = np.concatenate([along, along, near, SHAPE[1] - 1 - near])
    ys = np.concatenate([near, SHAPE[0] - 1 - near, along, along])
    star = np.arange(len(xs)) % 2 == 0
    padded = np.zeros((SHAPE[0] + 12, SHAPE[1] + 12))
    cx, cy = xs + rng.uniform(0.0, 0.5, len(xs)), ys + rng.uniform(0.0, 0.5, len(xs))
    cx = np.where(xs < SHAPE[1] // 2, cx, 2 * xs - cx)   # 1-1.5 px from the nearest edge
    cy = np.where(ys < SHAPE[0] // 2, cy, 2 * ys - cy)
    for x, y, px, py, is_star in zip(xs, ys, cx - xs, cy - ys, star, strict=True):
        unit = (spot(float(rng.uniform(1500.0, 4000.0)), 0.65, 6, (px, py)) if is_star
                else _short_track(rng, (px, py)))
        padded[y:y + 13, x:x + 13] += unit
    light += padded[6:-6, 6:-6]
    return sensor_frame(light, rng), cx, cy, star


def test_short_tracks_at_the_frame_edge_are_dropped_and_stars_kept():
    """Spots 1-1.5 px inside the frame's edge, their 5 x 5 reaching beyond it, are fitted
    on the pixels inside: every star there is found, of the short tracks at most a
    quarter (seeds 51, 52: before, the edge's tracks were not tested: 65 of 72 reported;
    after, 0; seeds 53-55 at 2-2.5 px: 0 of 108, and at 0-0.5 px, 15 pixels inside, too
    few to test: 86 of 108, no star lost either way)."""
    det = make_detector(DetectConfig(max_stars=1024), SHAPE, 10)
    totals = np.zeros(4, int)
    for seed in (51, 52):
        image, xs, ys, star = _edge_frame(seed)
        kept = found(det.detect(image).stars, xs, ys, star)
        totals += (kept[0], np.count_nonzero(star), kept[1], np.count_nonzero(~star))
    assert totals[0] == totals[1], totals
    assert totals[2] <= 0.25 * totals[3], totals
