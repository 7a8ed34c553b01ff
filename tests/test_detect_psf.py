"""The PSF measured from the frame (tracker.detect.psf) and centroids with no pixel-phase bias
(tracker.detect.fit), with ``detect.psf_sigma_px`` left at its default of 1.2 px."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tracker.catalogue import load_catalogue
from tracker.config import DetectConfig, SimConfig, load_config
from tracker.detect import make_detector
from tracker.detect.crb import centroid_crb
from tracker.detect.psf import PsfEstimate, PsfTracker, combine_stars
from tracker.sim import render_points, render_sky
from tracker.sim.psf_shapes import PsfShape, shape_model
from tracker.sim.scene import glare_scene
from tracker.sim.sequence import random_attitude

CFG = DetectConfig()                         # psf_sigma_px 1.2: the start, not the answer
CLEAN = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
ADC_FULL_E = (1023 - 64) * 1.35             # light that fills the 10-bit ADC above bias, e-


def _phase_grid(shape, spacing, phases):
    """Stars at every combination of ``phases`` sub-pixel offsets, ``spacing`` px apart."""
    px, py = np.meshgrid(phases, phases)
    n = px.size
    side = int(math.ceil(math.sqrt(n)))
    xs = 40 + (np.arange(n) % side) * spacing + px.ravel()
    ys = 40 + (np.arange(n) // side) * spacing + py.ravel()
    assert xs.max() < shape[1] - 40 and ys.max() < shape[0] - 40
    return xs, ys


def _peak_fraction(sigma):
    return math.erf(0.5 / (sigma * math.sqrt(2.0))) ** 2


@pytest.mark.parametrize("sigma", [0.6, 0.8, 1.2, 2.0, 3.0])
def test_noise_free_stars_are_centred_at_every_sub_pixel_phase(sigma):
    """64 stars at phases 0, 1/8 .. 7/8 in x and y, peaks at 55 % of the ADC, rounding to
    whole ADU the only noise (its centroid error is about 0.002 px): the PSF is measured
    within 1 % and every centre is within 0.01 px. A windowed centroid with the configured
    1.2 px misses sigma 0.6 by up to 0.1 px at some phases."""
    shape = (720, 720)
    xs, ys = _phase_grid(shape, 80, np.arange(8) / 8.0)
    flux = 0.55 * ADC_FULL_E / _peak_fraction(sigma)
    frame = render_points(shape, xs, ys, np.full(len(xs), flux), CLEAN, np.random.default_rng(1),
                          noise_model="none", psf_sigma_px=sigma)
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(sigma, rel=0.01)
    assert result.psf_stars >= 40             # of the 48 brightest it looks at
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert result.count == len(xs)
    assert d.min(axis=1).max() < 0.01


@pytest.mark.parametrize("kind,beta", [("gaussian", 0.0), ("moffat", 2.5), ("airy", 0.0)])
@pytest.mark.parametrize("sigma", [0.9, 2.0])
def test_shapes_and_widths_not_configured_are_centred_near_the_bound(kind, beta, sigma):
    """Stars of a PSF the detector was not told (Moffat wings, Airy rings, elliptical),
    realistic noise: the RMSE of the stars at peak SNR >= 20 (80 or more of 144; the RMSE
    itself scatters by about 8 %) stays within 1.3x the Cramer-Rao bound of the true PSF.

    The bound for a non-Gaussian PSF is taken numerically from its supersampled stamps.
    """
    rng = np.random.default_rng(int(sigma * 10) + len(kind))
    shape = (600, 600)
    psf = PsfShape(kind, sigma, beta=beta or 3.0, ellipticity=0.08, angle_rad=0.4)
    xs = np.repeat(np.linspace(40, 560, 12), 12) + rng.uniform(-0.5, 0.5, 144)
    ys = np.tile(np.linspace(40, 560, 12), 12) + rng.uniform(-0.5, 0.5, 144)
    flux = 0.8 * ADC_FULL_E / _peak_fraction(sigma) * rng.uniform(0.5, 1.0, 144)
    frame = render_points(shape, xs, ys, flux, CLEAN, rng, noise_model="realistic", psf=psf)
    bright = frame.stars["peak_snr"] >= 20
    assert bright.sum() >= 80 and not frame.stars["saturated"].any()
    result = make_detector(CFG, shape, 10).detect(frame.image)
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert np.all(d.min(axis=1) < 1.0)
    xs, ys, flux, d = xs[bright], ys[bright], flux[bright], d[bright]
    rmse = float(np.sqrt(np.mean(d.min(axis=1) ** 2)))
    sky = frame.truth["noise"]["sky_e"] + CLEAN.dark_current_e_s * CLEAN.exposure_ms / 1000.0
    floor = sky + CLEAN.read_noise_e ** 2 + frame.truth["noise"]["gain_e_per_adu"] ** 2 / 12.0
    bound = centroid_crb(xs, ys, flux, 2.0 * sigma, lambda s: s + floor, model=shape_model(psf))
    assert rmse <= 1.3 * float(np.sqrt(np.mean(bound ** 2))), (rmse, bound.mean())


def test_psf_ellipticity_and_angle_are_measured():
    rng = np.random.default_rng(3)
    shape = (600, 600)
    psf = PsfShape("gaussian", 1.6, ellipticity=0.15, angle_rad=math.radians(35.0))
    xs, ys = rng.uniform(30, 570, 80), rng.uniform(30, 570, 80)
    frame = render_points(shape, xs, ys, np.full(80, 0.5 * ADC_FULL_E / _peak_fraction(1.6)),
                          CLEAN, rng, noise_model="realistic", psf=psf)
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(1.6, rel=0.03)
    assert result.psf_ellipticity == pytest.approx(0.15, abs=0.02)
    assert result.psf_angle_deg == pytest.approx(35.0, abs=4.0)


def test_the_tracker_averages_agreeing_frames_and_follows_a_change_at_once():
    """Measurements that agree within their errors are averaged (up to psf_memory_frames);
    one that disagrees (focus moved) replaces the estimate for its own frame; a frame
    without a measurement keeps an estimate two frames agreed on."""
    rng = np.random.default_rng(5)
    tracker = PsfTracker(1.2, memory=20)
    used = []
    for _ in range(40):
        m = 1.5 * (1 + 0.02 * rng.standard_normal())
        used.append(tracker.update(PsfEstimate(m, 0.0, 0.0, 30, 0.03)).sigma_px)
    assert used[0] != 1.2                                  # the first frame's own value
    assert np.std(used[20:]) < 0.4 * 0.02 * 1.5            # averaged: steadier than one frame
    assert abs(np.mean(used[20:]) - 1.5) < 0.01
    kept = tracker.update(None)                            # no stars this frame
    assert kept.sigma_px == used[-1] and kept.stars == 0
    moved = tracker.update(PsfEstimate(2.1, 0.0, 0.0, 30, 0.03))
    assert moved.sigma_px == 2.1
    # one frame's word is not kept for a frame without stars (the next file of a folder
    # may come from other optics): the configured start is; a second frame confirms it
    assert tracker.update(None).sigma_px == 1.2
    tracker.update(PsfEstimate(2.12, 0.0, 0.0, 30, 0.03))
    kept = tracker.update(None)
    assert abs(kept.sigma_px - 2.11) < 0.01 and kept.stars == 0


def _round_hits(shape, rng, xs, ys, count, sigma_px, gap_px):
    """Deposits (e-, ``shape``) of ``count`` round particle hits, 2000-6000 e- each diffused
    to ``sigma_px``, at random places more than ``gap_px`` from every star at (xs, ys)
    (none on a star: it would pull it); 60 places are drawn from ``rng``."""
    deposits = np.zeros(shape)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    hits = rng.uniform([10, 10, 2000], [shape[1] - 10, shape[0] - 10, 6000], (60, 3))
    apart = np.hypot(hits[:, :1] - xs[None, :], hits[:, 1:2] - ys[None, :]).min(axis=1) > gap_px
    for x, y, q in hits[apart][:count]:
        box = (slice(int(y) - 3, int(y) + 4), slice(int(x) - 3, int(x) + 4))
        g = np.exp(-0.5 * ((xx[box] - x) ** 2 + (yy[box] - y) ** 2) / sigma_px ** 2)
        deposits[box] += q * g / g.sum()
    return deposits


def test_particle_hits_outnumbering_the_stars_do_not_set_the_psf():
    """A particle event's round hits (charge diffused to sigma 0.45-0.55 px, never blurred
    by the optics) outnumber a lunar frame's few bright stars: the mode of the sigmas is
    the hits', and the stars, three times wider, measure the PSF (3 agreeing suffice
    beside such a sharp population). Wider spots that do not agree leave the frame
    unmeasured rather than measured on the hits; a frame of one PSF is unchanged."""
    rng = np.random.default_rng(12)
    hits = rng.uniform(0.45, 0.55, 12)
    est = _combined(np.concatenate([hits, 1.8 * (1 + 0.03 * rng.standard_normal(4))]))
    assert est is not None and est.sigma_px == pytest.approx(1.8, rel=0.05)
    assert est.stars == 4
    assert _combined(np.concatenate([hits, [1.3, 2.6]])) is None
    assert _combined(np.concatenate([hits, [1.8, 1.85]])) is None    # two stars: too few
    one = 0.7 * (1 + 0.04 * rng.standard_normal(30))
    assert _combined(np.concatenate([one, [0.47, 0.5]])).sigma_px == pytest.approx(
        _combined(one).sigma_px, rel=0.02)


def test_stars_among_brighter_particle_hits_measure_the_psf_and_are_found():
    """8 stars of sigma 1.8 px among 40 round particle hits (charge diffused to 0.55 px,
    peaks as high as the stars'): the brightest peaks, which size the PSF meter's
    windows, are hits, and the stars outgrow those windows; they are measured again in
    windows wide enough for them, and the PSF is theirs (it was 0.45-0.55 px, and not
    one star was found)."""
    rng = np.random.default_rng(50)
    shape = (500, 500)
    xs = np.repeat([100.0, 200.0, 300.0, 400.0], 2) + rng.uniform(-20, 20, 8)
    ys = np.tile([150.0, 350.0], 4) + rng.uniform(-20, 20, 8)
    deposits = _round_hits(shape, rng, xs, ys, 40, 0.55, 10.0)
    frame = render_points(shape, xs, ys, np.full(8, 15000.0), CLEAN, rng,
                          noise_model="realistic", psf_sigma_px=1.8, deposits=(deposits, []))
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(1.8, rel=0.05)
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert np.all(d.min(axis=1) < 1.0)


def test_a_sharp_mode_beside_a_few_far_wider_binned_stars_does_not_set_the_psf():
    """Three stars of sigma 2.2 px too faint at their peaks (SNR 7.6) for the bright-star
    pass, among 30 round particle hits (charge diffused to 0.6 px): the bright peaks are
    hits, and 14 of them agree on a PSF of 0.56 px. The 4 x 4 bins hold the three stars,
    too few to measure the PSF but agreeing on one four times wider, beyond their
    standard errors: the sample is bimodal, and a sharp PSF's stars never read that
    much wider. Searched with the hits' PSF the frame gave 30 detections and none of
    the stars; with the three stars' PSF, the three stars and nothing else. (Seed 7 of
    20 such frames of 3 and 4 stars, seeds 3-12, the one whose PSF the hits set; the
    other 19 are unchanged.)"""
    rng = np.random.default_rng(7)
    shape = (500, 500)
    xs, ys = rng.uniform(40, 460, 3), rng.uniform(40, 460, 3)
    deposits = _round_hits(shape, rng, xs, ys, 30, 0.6, 15.0)
    frame = render_points(shape, xs, ys, np.full(3, 2000.0), CLEAN, rng,
                          noise_model="realistic", psf_sigma_px=2.2, deposits=(deposits, []))
    assert frame.stars["peak_snr"].max() < 10
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(2.2, rel=0.1)
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert np.all(d.min(axis=1) < 1.5)
    assert result.count <= 4


def test_round_particle_hits_on_a_glare_frame_do_not_set_a_wide_psf():
    """A glare frame (800 x 650, 16 mm) of PSF sigma 2.65 px with a particle event: its
    brightest isolated round spots are near-normal hits (a path in the silicon about as
    long as the layer is thick: round, and as sharp as the charge's diffusion), and
    five of them agreed on a PSF of 0.48 px; searched with it, 27 detections, most of
    them hits. The frame's 4 x 4 bins, where the stars' light is summed, agree on one
    over 1.5 times wider: the sharp spots were charge, and the PSF is the stars'.
    (Seed 28 of 40 small glare frames of sigma 1.8-2.8 px, the one whose PSF was
    measured on hits; the other 39 are unchanged, and so were 100 more.)"""
    cfg = load_config(None)
    catalogue = load_catalogue(path=cfg.catalogue.path, mag_limit=None)
    camera = dataclasses.replace(cfg.camera, width=800, height=650)
    sim = dataclasses.replace(cfg.sim, noise_model="realistic")
    rng = np.random.default_rng(28)
    sigma = float(rng.uniform(1.8, 2.8))
    frame = render_sky(camera, catalogue, random_attitude(rng), sim, rng,
                       psf=PsfShape("gaussian", sigma),
                       scene=glare_scene((650, 800), rng, sim.full_well_e, tracks=(40, 60)))
    result = make_detector(cfg.detect, frame.image.shape, frame.bit_depth).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(sigma, rel=0.1)
    d = np.hypot(frame.stars["x"][:, None] - result.stars["x"][None, :],
                 frame.stars["y"][:, None] - result.stars["y"][None, :])
    assert np.count_nonzero(d.min(axis=0) > 2.0) <= 2


def test_a_sharp_psf_is_not_overruled_by_too_few_binned_stars():
    """A 400 ms realistic frame (800 x 650, 16 mm) of PSF sigma 0.68 px: its bright stars
    agree on 0.65 px, as sharp as a particle's charge, so the 4 x 4 bins are consulted.
    Fewer stars there than a measurement needs, faint and undersampled, read over 1.5
    times wider; they had overruled the bright stars, and the frame went unmeasured and
    was searched at the configured 1.2 px. Only a measurement overrules them now.
    (Seed 17 of 40 such frames of sigma 0.6-0.7 px, the one the bins overruled; the
    bench's realistic 16 mm 100 ms frame 12 lost 20 of its 26 stars the same way.)"""
    cfg = load_config(None)
    catalogue = load_catalogue(path=cfg.catalogue.path, mag_limit=None)
    camera = dataclasses.replace(cfg.camera, width=800, height=650)
    sim = dataclasses.replace(cfg.sim, noise_model="realistic", glare_e=400.0,
                              cosmic_ray_rate_cm2_s=300.0, exposure_ms=400.0)
    rng = np.random.default_rng(17)
    sigma = float(rng.uniform(0.6, 0.7))
    frame = render_sky(camera, catalogue, random_attitude(rng), sim, rng,
                       psf=PsfShape("gaussian", sigma))
    result = make_detector(cfg.detect, frame.image.shape, frame.bit_depth).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(sigma, rel=0.1)


def test_a_frame_of_faint_stars_of_a_wide_psf_is_searched_with_it():
    """Too few stars above 10 sigma for the bright-star pass: the frame's brightest 4 x 4
    bins measure sigma 2.8, and the frame is searched (once) with it, not the default
    1.2 px."""
    rng = np.random.default_rng(9)
    shape = (500, 500)
    xs, ys = rng.uniform(30, 470, 40), rng.uniform(30, 470, 40)
    frame = render_points(shape, xs, ys, np.full(40, 2500.0), CLEAN, rng,
                          noise_model="realistic", psf_sigma_px=2.8)
    assert frame.stars["peak_snr"].max() < 10
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(2.8, rel=0.1)
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert np.mean(d.min(axis=1) < 1.5) >= 0.95


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_faint_stars_of_a_wide_psf_measure_it_and_their_hot_pixels_are_not_stars(seed):
    """40 stars of sigma 2.2 px at matched-filter SNR 15 (peak SNR 3: none for the
    bright-star pass) among 700 hot pixels of a few hundred e-: the frame's brightest
    4 x 4 bins measure the PSF before the search (within 5 %, from 5 or more stars), and
    the hot pixels judged against it are no stars. Judged against the sharpest PSF
    handled, a hot pixel whose 3x3 median noise lifted stands above it by less than a
    star's sharpest contrast; with the bright pixels as the PSF's candidates the frame
    measured no PSF (or 1.9-2.05 px from five or six spots) and kept 1-3 hot pixels as
    stars. A star with such a pixel on its core (above its median by half the star's
    peak, within a pixel of its centre) goes with it: 1-4 of the 40 (the detector that
    searched such a frame a second time kept them on a first frame, and lost the same
    ones from its third on, with the PSF known)."""
    sim = dataclasses.replace(SimConfig(), cosmic_ray_rate_cm2_s=0.0, hot_pixel_fraction=2e-3,
                              hot_pixel_dark_e_s=1500.0)
    rng = np.random.default_rng(seed)
    shape = (600, 600)
    xs, ys = rng.uniform(30, 570, 40), rng.uniform(30, 570, 40)
    frame = render_points(shape, xs, ys, np.full(40, 450.0), sim, rng,
                          noise_model="realistic", psf_sigma_px=2.2)
    assert frame.stars["peak_snr"].max() < 5
    hot = np.array([(s["x"], s["y"]) for s in frame.false_sources if s["kind"] == "hot_pixel"])
    assert len(hot) > 500
    result = make_detector(CFG, shape, 10).detect(frame.image)
    assert result.psf_sigma_px == pytest.approx(2.2, rel=0.05)
    assert result.psf_stars >= 5
    on_hot = np.hypot(hot[:, :1] - result.stars["x"][None, :],
                      hot[:, 1:] - result.stars["y"][None, :]).min(axis=0) < 1.0
    assert not on_hot.any()
    d = np.hypot(xs[:, None] - result.stars["x"][None, :], ys[:, None] - result.stars["y"][None, :])
    assert np.mean(d.min(axis=1) < 1.5) >= 0.9


def test_too_few_stars_to_measure_the_psf_still_bound_it_for_their_hot_pixels():
    """Ten frames of 4 stars of sigma 2.2 px at matched-filter SNR 20 among 330 hot pixels:
    too few to measure the PSF, but enough to say the frame's stars are no sharper than
    the sharpest of them, and the lone hot pixels judged against that are no stars: 7
    are kept over the ten frames (21 judged against the sharpest PSF handled), and
    every star found. When 3-4 of them agree, far wider than the configured 1.2 px,
    the frame is searched with theirs (psf_stars says how many); else 1.2 px is kept."""
    sim = dataclasses.replace(SimConfig(), cosmic_ray_rate_cm2_s=0.0, hot_pixel_fraction=1e-3,
                              hot_pixel_dark_e_s=1500.0)
    on_hot = found = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        xs, ys = rng.uniform(30, 570, 4), rng.uniform(30, 570, 4)
        frame = render_points((600, 600), xs, ys, np.full(4, 700.0), sim, rng,
                              noise_model="realistic", psf_sigma_px=2.2)
        hot = np.array([(s["x"], s["y"]) for s in frame.false_sources])
        result = make_detector(CFG, (600, 600), 10).detect(frame.image)
        if result.psf_stars:
            assert 3 <= result.psf_stars < CFG.psf_min_stars
            assert result.psf_sigma_px == pytest.approx(2.2, rel=0.15)
        else:
            assert result.psf_sigma_px == CFG.psf_sigma_px
        on_hot += int(np.count_nonzero(np.hypot(hot[:, :1] - result.stars["x"][None, :],
                                                hot[:, 1:] - result.stars["y"][None, :])
                                       .min(axis=0) < 1.0))
        d = np.hypot(xs[:, None] - result.stars["x"][None, :],
                     ys[:, None] - result.stars["y"][None, :])
        found += int(np.count_nonzero(d.min(axis=1) < 1.5))
    assert on_hot <= 10
    assert found == 40


def test_the_replay_record_carries_the_psf_and_what_was_left_out():
    """tracker replay's per-frame record: the PSF used and its basis, and the stars beyond
    detect.max_stars (the flight computer and the overlay see only the kept ones)."""
    from tracker.commands.replay import frame_record
    from tracker.config import Config
    from tracker.pipeline import Pipeline

    rng = np.random.default_rng(12)
    shape = (400, 400)
    xs, ys = rng.uniform(20, 380, 60), rng.uniform(20, 380, 60)
    frame = render_points(shape, xs, ys, np.full(60, 4000.0), CLEAN, rng,
                          noise_model="realistic", psf_sigma_px=1.7)
    cfg = Config()
    cfg = dataclasses.replace(cfg, detect=dataclasses.replace(cfg.detect, max_stars=40),
                              identify=dataclasses.replace(cfg.identify, enabled=False))
    record = frame_record("f.png", Pipeline(cfg).process(frame.image, 10, 0))
    assert record["psf"]["sigma_px"] == pytest.approx(1.7, rel=0.05)
    assert record["psf"]["fwhm_px"] == pytest.approx(2.3548 * record["psf"]["sigma_px"],
                                                     rel=1e-3)
    assert record["psf"]["stars"] >= 5
    uncapped = make_detector(dataclasses.replace(cfg.detect, max_stars=1000), shape,
                             10).detect(frame.image)
    assert uncapped.count > 40
    assert len(record["stars"]) == 40
    assert record["rejected"]["left_out"] == uncapped.count - 40
    assert record["detect_reason"] == "too_many"


def _combined(sigmas, min_stars=5):
    """combine_stars on round spots (SNR 100) of these optical sigmas (px)."""
    s = np.asarray(sigmas, np.float64)
    c = s * s + 1.0 / 12.0        # round stars' pixel covariances
    return combine_stars(s, np.zeros_like(s), c, c, np.zeros_like(s), np.full_like(s, 100.0),
                         min_stars)


def test_psf_mode_takes_a_cluster_whose_scatter_fills_the_agreement_window():
    """Six faint stars of a wide PSF (sigma 3 px) measured with 8 % scatter: five lie
    within 15 % of their cluster's median, so they agree (a mode placed at the densest
    bin's own centre, half a bin up, left the lowest of them out and the frame with
    no PSF); a minority of narrow blobs moves nothing."""
    est = _combined([2.42, 2.54, 2.84, 2.87, 2.9, 3.06])
    assert est is not None and est.stars == 5 and abs(est.sigma_px - 2.86) < 0.05
    est = _combined([1.45, 1.5, 1.52, 1.55, 1.6, 0.6, 0.62, 0.65])
    assert est is not None and est.stars == 5 and abs(est.sigma_px - 1.52) < 0.02
    assert _combined([2.0, 2.3, 2.7, 3.1, 3.6]) is None     # no five agree


def _elongated(sigma, ellipticity, angle):
    """Pixel covariances (cxx, cyy, cxy) of spots of optical sigma, ellipticity and long-axis
    angle (arrays), the pixel's own width added."""
    s, e, a = (np.asarray(v, np.float64) for v in (sigma, ellipticity, angle))
    half, spread = s * s, e * s * s
    return (half + spread * np.cos(2 * a) + 1.0 / 12.0, half - spread * np.cos(2 * a)
            + 1.0 / 12.0, spread * np.sin(2 * a))


def _noisy_shapes(rng, sigma, ellipticity, angle_rad, snr):
    """Pixel covariances of spots of one PSF whose ellipticity vectors are scattered by
    their noise: 2 / SNR per component (times the pixel width's share, as measured)."""
    cxx, cyy, cxy = _elongated(sigma, ellipticity, np.full_like(sigma, angle_rad))
    trace = cxx + cyy - 2.0 / 12.0
    error = 2.0 * (cxx + cyy) / trace / snr
    e1 = (cxx - cyy) / trace + error * rng.standard_normal(len(sigma))
    e2 = 2.0 * cxy / trace + error * rng.standard_normal(len(sigma))
    return 0.5 * trace * (1 + e1) + 1.0 / 12.0, 0.5 * trace * (1 - e1) + 1.0 / 12.0, \
        0.5 * trace * e2


def test_a_sharp_mode_of_bright_spots_pointing_every_way_is_no_psf():
    """Short particle tracks are as sharp as the sharpest PSF (sigma 0.5-0.6 px measured),
    bright (SNR 50-200) and elongated (0.3-0.45) every way: six of them agreed on sigma
    0.55 and searched a frame of sigma 2.2 px stars with it. Each lies far beyond its
    own noise from their median shape: too few share one, no PSF. Sharp stars of one
    shape still measure it, with two tracks among them."""
    rng = np.random.default_rng(3)
    sigma = np.array([0.50, 0.53, 0.55, 0.55, 0.57, 0.60])
    angle = np.arange(6) * np.pi / 6 + rng.uniform(0, 0.2, 6)
    tracks = _elongated(sigma, rng.uniform(0.3, 0.45, 6), angle)
    snr = np.array([50.0, 90.0, 120.0, 60.0, 200.0, 150.0])
    assert combine_stars(sigma, np.full(6, 0.4), *tracks, snr, 5) is None
    # eight stars of a sigma 0.6 px PSF of ellipticity 0.1 at 30 deg (SNR 40-400) and
    # two tracks at 90 and 120 deg
    s = rng.uniform(0.58, 0.62, 8)
    star_snr = np.exp(rng.uniform(np.log(40.0), np.log(400.0), 8))
    stars = _noisy_shapes(rng, s, 0.1, np.radians(30), star_snr)
    both = [np.concatenate([a, b[3:5]]) for a, b in zip(stars, tracks, strict=True)]
    est = combine_stars(np.concatenate([s, sigma[3:5]]), np.zeros(10), *both,
                        np.concatenate([star_snr, snr[3:5]]), 5)
    assert est is not None and est.stars == 10
    assert abs(est.ellipticity - 0.1) < 0.05 and abs(np.degrees(est.angle_rad) - 30) < 15


def test_a_sharp_mode_of_which_only_a_few_share_a_shape_is_no_psf():
    """The sixth lunar 16 mm frame of `tracker bench detect --scene-frames 10` (PSF
    sigma 2.26 px, a particle event): its bright peaks were seven short tracks of sigma
    0.46-0.56 px, SNR 27-69, elongated 0.25-0.5 every way. Three lay near their median
    shape by chance, as many as three stars need beside wider ones, and the seven set
    a PSF of 0.53 px: the frame was searched with it and 38 of its detections were
    tracks. A PSF's stars all share its shape within their noise; here most do not,
    and there is no PSF. Seven stars of one sharp PSF with the same sigmas and SNRs,
    their shapes scattered by their noise, still measure it."""
    sigma = np.array([0.54, 0.55, 0.50, 0.50, 0.54, 0.46, 0.56])
    e1 = np.array([0.04, 0.09, -0.25, 0.10, 0.11, -0.41, -0.11])
    e2 = np.array([-0.47, -0.43, 0.10, 0.38, 0.48, 0.06, 0.29])
    snr = np.array([69.4, 39.1, 40.4, 58.2, 35.2, 42.1, 27.4])
    half = sigma ** 2
    tracks = (half * (1 + e1) + 1.0 / 12.0, half * (1 - e1) + 1.0 / 12.0, half * e2)
    assert combine_stars(sigma, np.hypot(e1, e2), *tracks, snr, 3) is None
    rng = np.random.default_rng(15)
    for _ in range(50):
        stars = _noisy_shapes(rng, sigma, 0.1, np.radians(40), snr)
        est = combine_stars(sigma, np.zeros(7), *stars, snr, 3)
        assert est is not None and est.stars >= 6


def test_faint_sharp_stars_scattered_in_shape_by_their_noise_measure_the_psf():
    """A real 8-bit frame's faint stars (openstartracker img0: PSF sigma 0.65 px,
    ellipticity 0.3, SNR 8-36) lie 0.2-0.55 from their median shape, as far as
    particle tracks do, but within a few standard errors of their own: all count, in
    every draw."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        s = rng.uniform(0.60, 0.70, 7)
        snr = np.exp(rng.uniform(np.log(8.0), np.log(36.0), 7))
        shapes = _noisy_shapes(rng, s, 0.3, np.radians(27), snr)
        est = combine_stars(s, np.zeros(7), *shapes, snr, 5)
        assert est is not None and est.stars == 7


@pytest.mark.parametrize("sigma", [0.6, 0.9, 1.5, 2.0])
def test_stars_cut_by_the_frames_edge_are_centred_on_the_light_inside_it(sigma):
    """Stars 0.25-1.5 px inside each of the four edges (pixel centres 0 and size - 1),
    at sub-pixel phases along it, peaks at 50 % of the ADC, rounding the only noise: a
    window reaching beyond the frame reads zeros there, which pulled the fit of the
    pixel-integrated PSF inward by 0.15 px (sigma 0.6) to 0.55 px (sigma 1.5). Fitted on
    the pixels the frame holds, every centre found is within 0.08 px (the frame's
    measured PSF, a few per cent off an undersampled one, is the rest), and those 1.5 px
    in are all found."""
    shape = (400, 400)
    offs = np.arange(1, 7) * 0.25
    along = 30 + np.arange(len(offs)) * 50 + np.arange(len(offs)) / len(offs)
    ex = np.concatenate([offs, along, shape[1] - 1 - offs, along + 0.3])
    ey = np.concatenate([along + 0.5, offs, along + 0.7, shape[0] - 1 - offs])
    grid = np.arange(60, 341, 56) + 0.37      # inner stars that measure the PSF
    ix, iy = (a.ravel() for a in np.meshgrid(grid, grid + 0.21))
    xs, ys = np.concatenate([ex, ix]), np.concatenate([ey, iy])
    flux = 0.5 * ADC_FULL_E / _peak_fraction(sigma)
    frame = render_points(shape, xs, ys, np.full(len(xs), flux), CLEAN,
                          np.random.default_rng(2), noise_model="none", psf_sigma_px=sigma)
    stars = make_detector(CFG, shape, 10).detect(frame.image).stars
    d = np.hypot(ex[:, None] - stars["x"][None, :], ey[:, None] - stars["y"][None, :])
    near = d.min(axis=1)
    found = near < 2.0
    assert found[np.tile(offs, 4) == 1.5].all()
    assert near[found].max() < 0.08, near


@pytest.mark.parametrize("flux_e", [4000.0, 20000.0])
def test_a_focus_jump_to_a_wide_psf_is_seen_on_the_frames_few_stars(flux_e):
    """A detector that measured sigma 1.0 px on frames of many stars, then frames of 4 stars
    of sigma 2.8 px (a refocus): too few for a measurement, but the 3-4 that agree on
    their binned spots contradict the PSF carried over (over 25 % wider, far beyond
    their error), and the frame is searched with theirs. Against the carried one a wide
    star's wings fill its sky ring and it was masked as embedded in a body: of the 24
    stars of six such frames 7 were lost at peak SNR 8.6 (4000 e-; 4 x 4 bins tell),
    20 at peak SNR 20 (20000 e-; the bright peaks tell); now every one is found."""
    rng = np.random.default_rng(21)
    shape = (600, 600)
    det = make_detector(CFG, shape, 10)
    for _ in range(2):
        xs, ys = rng.uniform(30, 570, 60), rng.uniform(30, 570, 60)
        sharp = render_points(shape, xs, ys, np.full(60, 6000.0), CLEAN, rng,
                              noise_model="realistic", psf_sigma_px=1.0)
        assert det.detect(sharp.image).psf_sigma_px == pytest.approx(1.0, rel=0.1)
    found = 0
    for _ in range(6):
        xs, ys = rng.uniform(40, 560, 4), rng.uniform(40, 560, 4)
        frame = render_points(shape, xs, ys, np.full(4, flux_e), CLEAN, rng,
                              noise_model="realistic", psf_sigma_px=2.8)
        result = det.detect(frame.image)
        d = np.hypot(xs[:, None] - result.stars["x"][None, :],
                     ys[:, None] - result.stars["y"][None, :])
        found += int(np.count_nonzero(d.min(axis=1, initial=np.inf) < 1.0))
        if result.psf_stars:
            assert result.psf_sigma_px == pytest.approx(2.8, rel=0.15)
    assert found == 24
