"""The default detector against simulated truth (tracker.sim)."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from tracker.bench.detect_data import bound_variance
from tracker.config import DetectConfig, SimConfig
from tracker.detect import StarFlag, make_detector
from tracker.detect import default as default_module
from tracker.detect.crb import centroid_crb
from tracker.detect.default import effective_sigma
from tracker.sim import render_points
from tracker.sim.sensor import cosmic_rays

CFG = DetectConfig(method="default")
# A clean sensor: no hot pixels or cosmic rays unless a test adds them.
CLEAN = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)


def _match(truth_x, truth_y, stars, radius=1.5):
    """Index of the nearest detection per truth star (-1 if none within radius) and distance."""
    if len(stars) == 0:
        return np.full(len(truth_x), -1), np.full(len(truth_x), np.inf)
    d = np.hypot(truth_x[:, None] - stars["x"][None, :], truth_y[:, None] - stars["y"][None, :])
    j = d.argmin(axis=1)
    dist = d[np.arange(len(truth_x)), j]
    return np.where(dist <= radius, j, -1), dist


def _grid_stars(n_side, shape, rng, spacing_margin=20):
    """Star positions on a jittered grid: isolated, away from the border."""
    rows, cols = shape
    gy, gx = np.meshgrid(np.linspace(spacing_margin, rows - spacing_margin, n_side),
                         np.linspace(spacing_margin, cols - spacing_margin, n_side), indexing="ij")
    return (gx.ravel() + rng.uniform(-0.5, 0.5, gx.size),
            gy.ravel() + rng.uniform(-0.5, 0.5, gy.size))


def _sensor_variance(frame):
    """Pixel variance (e-^2) of the sensor model for a star's own light: shot + sky + read."""
    sky = frame.truth["noise"]["sky_e"] + SimConfig().dark_current_e_s * 0.1
    gain = frame.truth["noise"]["gain_e_per_adu"]
    return lambda s: s + sky + SimConfig().read_noise_e ** 2 + gain ** 2 / 12.0


def test_centroids_reach_the_cramer_rao_bound_for_bright_stars():
    """RMSE within 1.5x the Cramer-Rao bound at peak SNR >= 20 (the issue's target).

    With 144 stars per level the RMSE estimate itself scatters by about
    1/sqrt(2 * 144) = 6 %, far inside the 50 % margin.
    """
    rng = np.random.default_rng(11)
    shape = (400, 400)
    det = make_detector(CFG, shape, 10)
    for electrons in (5000.0, 10000.0):  # 10000 e-: peak ~1050 e-, below ADC full scale
        xs, ys = _grid_stars(12, shape, rng)
        frame = render_points(shape, xs, ys, np.full(len(xs), electrons), CLEAN, rng,
                              noise_model="realistic")
        assert frame.stars["peak_snr"].min() >= 20
        result = det.detect(frame.image)
        idx, dist = _match(xs, ys, result.stars)
        assert np.all(idx >= 0)
        rmse = float(np.sqrt(np.mean(dist ** 2)))
        bound = centroid_crb(xs, ys, frame.stars["flux_e"], SimConfig().psf_sigma_px,
                             _sensor_variance(frame))
        crb = float(np.sqrt(np.mean(bound ** 2)))
        assert rmse <= 1.5 * crb, (electrons, rmse, crb)


def test_noise_free_star_is_centred_to_a_hundredth_of_a_pixel():
    """Without noise only the estimator's own bias is left: < 0.01 px for sigma 1.2 px."""
    rng = np.random.default_rng(3)
    shape = (120, 120)
    xs, ys = _grid_stars(4, shape, rng)
    frame = render_points(shape, xs, ys, np.full(len(xs), 4000.0), CLEAN, rng,
                          noise_model="none")
    result = make_detector(CFG, shape, 10).detect(frame.image)
    idx, dist = _match(xs, ys, result.stars)
    assert np.all(idx >= 0)
    assert dist.max() < 0.01
    assert result.count == len(xs)


def test_faint_stars_found_and_noise_not_reported():
    """Recall of stars at peak SNR >= 5 and no false detections on a realistic sensor.

    At the default threshold of 6 sigma a 256 x 256 frame of pure noise has
    about 1e-3 false peaks (Gaussian tail), so zero is expected over 8 frames.
    Hot pixels and cosmic rays are present and must be counted, not reported.
    """
    rng = np.random.default_rng(5)
    shape = (256, 256)
    det = make_detector(CFG, shape, 10)
    found = detectable = false = 0
    counted = 0
    for _ in range(8):
        xs, ys = _grid_stars(6, shape, rng)
        electrons = 10 ** rng.uniform(2.2, 4.0, len(xs))
        frame = render_points(shape, xs, ys, electrons, SimConfig(), rng,
                              noise_model="realistic")
        result = det.detect(frame.image)
        ok = frame.stars["peak_snr"] >= 5
        idx, _ = _match(xs, ys, result.stars)
        detectable += int(ok.sum())
        found += int((idx[ok] >= 0).sum())
        matched = np.zeros(result.count, bool)
        matched[idx[idx >= 0]] = True
        false += int((~matched).sum())
        counted += result.counters["hot_pixels"] + result.counters["cosmic_rays"]
    assert detectable > 150
    assert found / detectable >= 0.99
    assert false == 0
    assert counted > 8 * 10  # about 13 hot pixels per frame at this size (SimConfig)


def test_hot_pixel_and_cosmic_ray_are_counted_not_reported():
    shape = (64, 64)
    image = np.full(shape, 64, np.uint16)
    image += np.random.default_rng(0).integers(0, 3, shape, dtype=np.uint16)
    image[10, 12] = 900                       # hot pixel
    image[40, 20:25] = 700                    # cosmic-ray track, one pixel wide
    image[50, 50] = 300                       # another hot pixel, fainter
    result = make_detector(CFG, shape, 10).detect(image)
    assert result.count == 0
    assert result.counters["hot_pixels"] == 2
    assert result.counters["cosmic_rays"] == 1
    assert result.counters["impulse_pixels"] == 7


def test_cosmic_ray_tracks_are_rejected_and_a_trailed_star_is_kept():
    """150 cosmic rays (tracks up to 6 px, a pixel wide): counted, never reported.

    A track's second moment across it is a pixel's (~0.1 px^2), the PSF's
    is 0.76 px^2 and an 8 px star trail keeps it; the test is across the
    narrowest axis, so a track's length does not hide its width (a test of
    the total size lets 5 of these tracks through as stars).
    """
    rng = np.random.default_rng(0)
    shape = (300, 300)
    path_x = np.linspace(146.0, 154.0, 17)[None, :]
    frame = render_points(shape, path_x, np.full_like(path_x, 150.0), [20000.0], CLEAN, rng,
                          noise_model="realistic")
    hits, _ = cosmic_rays(shape, 150, SimConfig().cosmic_ray_e, rng)
    adu = frame.image + hits / frame.truth["noise"]["gain_e_per_adu"]
    image = np.clip(np.rint(adu), 0, 1023).astype(np.uint16)
    result = make_detector(CFG, shape, 10).detect(image)
    assert result.count == 1, result.stars[["x", "y", "snr", "flags"]]
    assert abs(result.stars["x"][0] - 150.0) < 0.5 and abs(result.stars["y"][0] - 150.0) < 0.5
    assert result.stars["flags"][0] & StarFlag.ELONGATED
    assert result.counters["cosmic_rays"] >= 150 * 0.9, result.counters


def test_close_pair_is_split_and_flagged_blended():
    """Two equal stars 4.5 px apart (3.7 PSF sigma): two detections, both BLENDED."""
    rng = np.random.default_rng(8)
    shape = (64, 64)
    xs, ys = np.array([30.2, 34.7]), np.array([31.6, 31.6])
    frame = render_points(shape, xs, ys, [5000.0, 5000.0], CLEAN, rng,
                          noise_model="realistic")
    result = make_detector(CFG, shape, 10).detect(frame.image)
    idx, dist = _match(xs, ys, result.stars, radius=0.5)
    assert result.count == 2 and np.all(idx >= 0)
    assert np.all(result.stars["flags"] & StarFlag.BLENDED)


def test_flags_saturated_edge_and_elongated():
    rng = np.random.default_rng(9)
    shape = (80, 80)
    path_x = np.linspace(50.0, 58.0, 17)[None, :]       # an 8 px trail
    frame = render_points(shape, [20.3], [20.6], [2e5], CLEAN, rng, noise_model="realistic")
    saturated = make_detector(CFG, shape, 10).detect(frame.image)
    assert saturated.count == 1 and saturated.stars["flags"][0] & StarFlag.SATURATED
    assert abs(saturated.stars["x"][0] - 20.3) < 0.1
    frame = render_points(shape, [1.2], [40.4], [4000.0], CLEAN, rng, noise_model="realistic")
    edge = make_detector(CFG, shape, 10).detect(frame.image)
    assert edge.count == 1 and edge.stars["flags"][0] & StarFlag.EDGE
    frame = render_points(shape, path_x, np.full_like(path_x, 60.0), [20000.0], CLEAN, rng,
                          noise_model="realistic")
    trail = make_detector(CFG, shape, 10).detect(frame.image)
    assert trail.count >= 1 and np.all(trail.stars["flags"] & StarFlag.ELONGATED)


def test_glare_gradient_does_not_make_detections():
    """Glare of 900 e- peak (r0 = 150 px) over 25 stars: the stars and nothing else.

    The glare's slope reaches 3.6 e-/px, 1.4 noise sigma per pixel; a
    background taken as flat would cross the threshold over whole tiles.
    """
    rng = np.random.default_rng(12)
    shape = (300, 300)
    sim = dataclasses.replace(CLEAN, glare_e=900.0, glare_radius_px=150.0)
    xs, ys = _grid_stars(5, shape, rng, spacing_margin=30)
    frame = render_points(shape, xs, ys, np.full(len(xs), 5000.0), sim, rng,
                          noise_model="realistic")
    result = make_detector(CFG, shape, 10).detect(frame.image)
    idx, dist = _match(xs, ys, result.stars)
    assert np.all(idx >= 0)
    assert result.count == len(xs)
    assert dist.max() < 0.3


def test_every_opencv_call_writes_into_its_buffer(monkeypatch):
    """Each cv2 call given dst= returns that very array (no hidden reallocation)."""
    import tracker.detect.background as background
    import tracker.detect.default as default
    import tracker.detect.impulse as impulse
    import tracker.detect.peaks as peaks

    calls = []

    class Spy:
        def __getattr__(self, name):
            real = getattr(cv2, name)
            if not callable(real):
                return real

            def wrapped(*args, **kwargs):
                out = real(*args, **kwargs)
                if "dst" in kwargs:
                    calls.append((name, out is kwargs["dst"]))
                return out
            return wrapped

    for module in (background, default, impulse, peaks):
        monkeypatch.setattr(module, "cv2", Spy())
    rng = np.random.default_rng(4)
    shape = (128, 160)
    xs, ys = _grid_stars(4, shape, rng)
    frame = render_points(shape, xs, ys, np.full(len(xs), 2000.0), SimConfig(), rng,
                          noise_model="realistic")
    make_detector(CFG, shape, 10).detect(frame.image)
    names = {name for name, _ in calls}
    assert {"GaussianBlur", "medianBlur", "resize", "compare", "absdiff"} <= names
    assert all(same for _, same in calls), [c for c in calls if not c[1]]


def test_effective_sigma_adds_the_pixel_width():
    assert effective_sigma(1.2) == pytest.approx(np.sqrt(1.44 + 1 / 12))


def test_crowded_frame_raises_the_threshold_above_the_background():
    """Too many pixels above threshold: the height above the background doubles, not the level.

    A raised threshold keeps only the brightest stars (here a few of 25
    equal ones, by noise). A pedestal of 300 ADU must not change which: were
    the whole threshold (background included, about 365 ADU) doubled at
    the first step, it would rise above every star's filtered peak (at most
    about 340 ADU above the background here) and drop them all.
    """
    rng = np.random.default_rng(12)
    shape = (200, 240)
    xs, ys = _grid_stars(5, shape, rng)
    frame = render_points(shape, xs, ys, np.full(len(xs), 8000.0), CLEAN, rng,
                          noise_model="realistic").image
    det = make_detector(dataclasses.replace(CFG, max_pixels_above=300), shape, 10)
    found = []
    for pedestal in (0, 300):
        result = det.detect(frame + np.uint16(pedestal))
        assert result.reason == "crowded"
        assert result.count >= 3
        idx, dist = _match(result.stars["x"], result.stars["y"],
                           np.rec.fromarrays([xs, ys], names="x,y"))
        assert np.all(idx >= 0) and dist.max() < 0.2  # every star reported is a real one
        found.append(result.stars[["x", "y"]].copy())
    np.testing.assert_allclose(found[0]["x"], found[1]["x"], atol=0.01)
    np.testing.assert_allclose(found[0]["y"], found[1]["y"], atol=0.01)


def test_sparse_photon_noise_moves_the_threshold_and_keeps_false_stars_rare():
    """A background of a few photon counts (mostly 0, sometimes 1) is skewed even after the filter.

    On 8-bit frames of Poisson(0.15) counts a Gaussian-calibrated threshold
    lets clumps of counts through (0.375 per 512 x 512 frame for a
    Cornish-Fisher 6.3 sigma, measured); the saddlepoint of the frame's own
    pixel distribution (tracker.detect.threshold) moves the cut out by more
    than a sigma. Clumps of independent counts still come through somewhat
    more often than independent pixels predict (0.3 per frame measured for
    this seed against the budget's 0.1): 20 frames must stay below 0.5 per
    frame on average, which a Gaussian threshold (about 25 per frame at
    5 sigma) misses by far. Gaussian noise keeps the budget's own level:
    the saddlepoint of a normal histogram is the Gaussian threshold.
    """
    rng = np.random.default_rng(13)
    shape = (512, 512)
    det = make_detector(CFG, shape, 8)
    false = 0
    ks = []
    for _ in range(20):
        false += det.detect(rng.poisson(0.15, shape).astype(np.uint8)).count
        ks.append(det.threshold_k)
    assert np.mean(ks) > det.peak_threshold + 1.0
    assert false / 20 < 0.5
    gaussian = np.rint(rng.normal(100.0, 5.0, shape)).astype(np.uint8)
    assert det.detect(gaussian).count == 0
    assert det.peak_threshold - 0.01 <= det.threshold_k < det.peak_threshold + 0.3


def test_broad_source_is_flagged_extended_a_body_is_masked_and_stars_are_neither():
    """Among point stars: a comet-like blob (sigma 2.2 px, flux/peak ~3x a star's) is
    reported EXTENDED; a body as wide as the window (sigma 6 px, a ghost or a planet's
    disc) is masked and counted, not reported."""
    rng = np.random.default_rng(21)
    shape = (300, 300)
    xs, ys = _grid_stars(5, shape, rng, spacing_margin=40)
    frame = render_points(shape, xs, ys, np.full(len(xs), 6000.0), CLEAN, rng,
                          noise_model="realistic")
    yy, xx = np.mgrid[:300, :300]
    comet = 120.0 * np.exp(-((xx - 122.5) ** 2 + (yy - 177.5) ** 2) / (2 * 2.2 ** 2))
    body = 60.0 * np.exp(-((xx - 237.5) ** 2 + (yy - 120.5) ** 2) / (2 * 6.0 ** 2))
    image = np.clip(frame.image + np.rint(comet + body), 0, 1023).astype(np.uint16)
    det = make_detector(CFG, shape, 10).detect(image)
    near_comet = np.hypot(det.stars["x"] - 122.5, det.stars["y"] - 177.5) < 4
    assert np.count_nonzero(near_comet) >= 1
    assert np.all(det.stars["flags"][near_comet] & StarFlag.EXTENDED)
    assert not np.any(np.hypot(det.stars["x"] - 237.5, det.stars["y"] - 120.5) < 12)
    assert det.counters["masked"] >= 1
    idx, _ = _match(xs, ys, det.stars)
    assert (idx >= 0).all()
    assert not np.any(det.stars["flags"][idx] & StarFlag.EXTENDED)


def test_saturated_stars_are_centred_from_their_unclipped_wings():
    """Clipped cores: the fit of the wings keeps the error near the bound (~0.01 px here)."""
    rng = np.random.default_rng(31)
    shape = (300, 300)
    xs, ys = _grid_stars(4, shape, rng, spacing_margin=50)
    frame = render_points(shape, xs, ys, np.full(len(xs), 4e4), CLEAN, rng,
                          noise_model="realistic")       # cores 8x full scale
    det = make_detector(CFG, shape, 10).detect(frame.image)
    idx, dist = _match(xs, ys, det.stars)
    assert (idx >= 0).all()
    assert np.all(det.stars["flags"][idx] & StarFlag.SATURATED)
    # a plain windowed centroid of these clipped spots errs by ~0.05 px RMS
    assert np.sqrt(np.mean(dist ** 2)) < 0.03


def test_multiplicative_noise_centroid_nears_the_bound_on_speckle():
    """Speckle (variance 0.15 of the light, 8-bit): the likelihood fit nears the exact bound.

    Bound: the exact Fisher information of the speckled, rounded pixel.
    Measured for this seed: 0.057 px fitted, 0.295 px windowed, bound 0.060 px.
    """
    rng = np.random.default_rng(41)
    shape = (300, 300)
    xs, ys = _grid_stars(6, shape, rng, spacing_margin=30)
    electrons = np.full(len(xs), 3e3)                     # peak ~127 of 255: unclipped
    frame = render_points(shape, xs, ys, electrons, SimConfig(), rng,
                          noise_model="speckle", bit_depth=8)
    full_scale = frame.truth["noise"]["full_scale_e"]
    bound = centroid_crb(xs, ys, electrons / full_scale, SimConfig().psf_sigma_px,
                         bound_variance("speckle", 0.15), 1.0)
    rms = {}
    for noise in ("additive", "multiplicative"):
        cfg = dataclasses.replace(CFG, centroid_noise=noise)
        det = make_detector(cfg, shape, 8).detect(frame.image)
        idx, dist = _match(xs, ys, det.stars)
        assert (idx >= 0).all()
        rms[noise] = float(np.sqrt(np.mean(dist ** 2)))
    limit = float(np.sqrt(np.mean(bound ** 2)))
    assert rms["multiplicative"] < 1.3 * limit, (rms, limit)
    assert rms["multiplicative"] < 0.5 * rms["additive"], (rms, limit)


def test_multiplicative_noise_finds_faint_speckled_stars_on_a_black_sky():
    """Speckle of variance 1 on a black sky: 24 faint stars (about 80 ADU each, a few
    dozen lit pixels) among 12 bright ones, every one found within 1 px, nothing else.

    A faint speckled star is a cluster of spikes over a sky that is exactly 0:
    the impulse stage clears most of them (their 3x3 median is the sky), and
    with its peak cleared its flux/peak reads as a bright body's. Searching the
    cleaned frame and judging that ratio lost 4 of the 24 faint stars here.
    """
    rng = np.random.default_rng(43)
    shape = (360, 360)
    xs, ys = _grid_stars(6, shape, rng, spacing_margin=30)
    electrons = np.where(np.arange(len(xs)) % 3 == 0, 3e3, 200.0)
    sim = dataclasses.replace(SimConfig(), speckle_variance=1.0)
    frame = render_points(shape, xs, ys, electrons, sim, rng, noise_model="speckle",
                          bit_depth=8)
    cfg = dataclasses.replace(CFG, centroid_noise="multiplicative")
    det = make_detector(cfg, shape, 8).detect(frame.image)
    idx, dist = _match(xs, ys, det.stars, radius=1.0)
    assert (idx >= 0).all(), (np.flatnonzero(idx < 0), electrons[idx < 0])
    assert len(det.stars) == len(xs), len(det.stars)


def test_psf_constants_kept_per_step_equal_those_computed_afresh(monkeypatch):
    """Every PSF step's constants are computed at construction (tracker.detect.sigma_steps)
    and none on a frame: a PSF that moves from step to step reads the table, whose
    thresholds, contrasts, lowest phase width, weighted flux's capture, roughness and
    border gains are those computed afresh for the step, and the same as a detector
    started at that PSF uses."""
    shape = (200, 240)
    moving = make_detector(CFG, shape, 10)
    assert moving.steps.known.all()
    afresh = moving._step_constants

    def computed_on_a_frame(step):
        raise AssertionError(f"step {step} computed after construction")

    def capture_on_a_frame(*args):
        raise AssertionError("weighted capture computed after construction")

    moving._step_constants = computed_on_a_frame
    names = ("filter_gain", "peak_threshold", "impulse_contrast", "impulse_ring", "phase_low",
             "capture")
    for sigma in (0.7, 2.9, 1.6, 0.7, 0.45, 3.5):
        with monkeypatch.context() as patch:
            patch.setattr(default_module, "weighted_capture", capture_on_a_frame)
            moving._configure(sigma)
        scalars, gains = afresh(moving._sigma_step)
        assert [getattr(moving, name) for name in names] == list(scalars[:6])
        assert moving.star_roughness.values() == tuple(scalars[6:])
        fresh = make_detector(dataclasses.replace(CFG, psf_sigma_px=sigma), shape, 10)
        assert moving.psf_sigma_used == fresh.psf_sigma_used
        for name in (*names, "star_roughness"):
            assert getattr(moving, name) == getattr(fresh, name), name
        for ours, theirs, computed in zip(moving.edge_gain, fresh.edge_gain, gains,
                                          strict=True):
            assert ours.dtype == np.float32 and np.array_equal(ours, theirs)
            assert np.array_equal(ours, computed)


def test_salt_on_a_star_core_is_repaired_in_a_salt_and_pepper_frame():
    """Salt and pepper at the seed's density 0.05 over 16 stars
    of core 120-170 ADU, each with a grain of salt (255) on its brightest pixel: the grain
    stands above its 3x3 median by only 0.3-0.5 of its height, less than the contrast test
    asks, and the spot read as a clipped particle's hit (sharper than the optics). A lone
    pixel at full scale in such a frame is salt: all 16 found within 0.3 px, no more than
    one false detection. The frame takes the whole-frame impulse pass a full 1600 x 1300
    frame at this density does (104,000 impulses, over the 32,768 listed one by one)."""
    rng = np.random.default_rng(23)
    shape = (240, 240)
    grid = np.arange(30.0, 240.0, 55.0)
    xs, ys = (a.ravel() + rng.uniform(-0.5, 0.5, a.size) for a in np.meshgrid(grid, grid))
    flux = rng.uniform(7000.0, 9500.0, xs.size)
    frame = render_points(shape, xs, ys, flux, SimConfig(), rng, noise_model="salt_pepper")
    image = frame.image.copy()
    r, c = np.rint(ys).astype(int), np.rint(xs).astype(int)
    assert np.all((image[r, c] >= 110) | (image[r, c] == 0) | (image[r, c] == 255))
    image[r, c] = 255
    det = make_detector(DetectConfig(max_impulses=1024), shape, 8)
    found = det.detect(image).stars
    assert det.counters["impulse_pixels"] > 0.02 * image.size   # the salt; pepper on black is 0
    d = np.hypot(found["x"][:, None] - xs[None], found["y"][:, None] - ys[None])
    assert np.all(d.min(axis=0) < 0.3)
    assert np.count_nonzero(d.min(axis=1) > 2.0) <= 1
