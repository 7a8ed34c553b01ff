"""The lean window detector (tracker.detect.stamps) against the truth and the full frame."""

import dataclasses
import math

import numpy as np

from tracker.attitude import matrix_from_radec_roll
from tracker.catalogue import load_catalogue
from tracker.config import Config, DetectConfig, SimConfig
from tracker.detect import make_detector
from tracker.detect.result import StarFlag
from tracker.detect.stamps import StampDetector
from tracker.pipeline import Pipeline
from tracker.sim import render_points, render_sky

CELL = 24


def _frame(seed: int, psf: float = 1.3):
    cfg = Config()
    cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, psf_sigma_px=psf))
    cat = load_catalogue(epoch_year=2026.0, mag_limit=cfg.catalogue.mag_limit)
    frame = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((84, -3, 10))),
                       cfg.sim, np.random.default_rng(seed))
    full = make_detector(cfg.detect, frame.image.shape, 10)
    for _ in range(2):       # the PSF's running estimate settles
        stars = full.detect(frame.image).stars.copy()
    return cfg, frame, full, stars


def _origins(xy, shape):
    h, w = shape
    return np.clip(np.rint(xy - 0.5 * (CELL - 1)), 0, [w - CELL, h - CELL]).astype(np.intp)


def _nearest(xy, truth_xy):
    d = np.hypot(xy[:, None, 0] - truth_xy[None, :, 0], xy[:, None, 1] - truth_xy[None, :, 1])
    return d.min(axis=1), d.argmin(axis=1)


def test_stamp_centroids_are_as_good_as_the_full_frame():
    """Windows around the full frame's 40 brightest true stars: every one found once,
    the same centre as the full frame's (most to 0.01 px), RMS against the truth no worse."""
    cfg, frame, full, stars = _frame(5)
    truth = frame.stars[frame.stars["in_frame"]]
    txy = np.stack((truth["x"], truth["y"]), 1)
    bright = stars[:40]
    bxy = np.stack((bright["x"], bright["y"]), 1)
    bxy = bxy[_nearest(bxy, txy)[0] < 1.0]
    origins = _origins(bxy, frame.image.shape)
    origins = np.concatenate((origins, origins[:4]))     # overlapping windows: found once
    detector = StampDetector(cfg.detect, frame.image.shape, CELL, len(origins), 4, 10,
                             frame.image.dtype)
    found = detector.detect(frame.image, origins, full.psf_tracker.current)
    got = np.stack((found.stars["x"], found.stars["y"]), 1)
    d = np.hypot(got[:, None, 0] - got[None, :, 0], got[:, None, 1] - got[None, :, 1])
    np.fill_diagonal(d, np.inf)
    assert d.min() > 1.0                                  # no star twice
    gap, which = _nearest(bxy, got)
    assert np.all(gap < 0.3) and np.median(gap) < 0.01, gap   # the same fit, mostly
    rms_full = math.sqrt(np.mean(_nearest(bxy, txy)[0] ** 2))
    rms_stamps = math.sqrt(np.mean(_nearest(got[which], txy)[0] ** 2))
    print(f"RMS against the truth: full frame {rms_full:.4f} px, stamps {rms_stamps:.4f}")
    assert rms_stamps < 1.05 * rms_full
    # the same significance scale as the full frame's within the noise estimates' spread
    snr_full = bright["snr"][:len(bxy)]
    ratio = np.median(found.stars["snr"][which] / snr_full)
    assert 0.8 < ratio < 1.3, ratio
    assert found.psf_sigma_px == full.psf_tracker.current.sigma_px


def test_impulses_are_rejected_and_cleaned_from_stars():
    """A hot pixel alone in a window is not a star; one beside a star does not move it;
    a saturated star is flagged."""
    cfg, frame, full, stars = _frame(7)
    image = frame.image.copy()
    star = stars[5]
    sx, sy = int(round(star["x"])), int(round(star["y"]))
    image[sy + 1, sx + 3] = min(1023, int(image[sy, sx]) + 400)    # a hit on the star's wing
    empty = np.array([[800, 40]])
    for _ in range(50):     # a place with no star in a window around it
        x0, y0 = np.random.default_rng(len(empty)).integers(100, 1200, 2)
        if np.hypot(stars["x"] - x0 - 11.5, stars["y"] - y0 - 11.5).min() > 30:
            empty = np.array([[x0, y0]])
            break
    image[empty[0, 1] + 12, empty[0, 0] + 12] = 1023                 # a lone hot pixel
    bright = stars[0]
    origins = np.concatenate((_origins(np.array([[star["x"], star["y"]],
                                                 [bright["x"], bright["y"]]]),
                                       image.shape), empty))
    detector = StampDetector(cfg.detect, image.shape, CELL, len(origins), 4, 10, image.dtype)
    plain = detector.detect(frame.image, origins, full.psf_tracker.current)
    clean, frame_hot = plain.stars.copy(), plain.counters["hot_pixels"]
    hit = detector.detect(image, origins, full.psf_tracker.current)
    got = hit.stars
    # the lone one adds one (the frame's own hot pixels may fall in the windows too)
    assert hit.counters["hot_pixels"] == frame_hot + 1
    assert hit.counters["impulse_pixels"] >= 2
    far = np.hypot(got["x"] - empty[0, 0] - 12, got["y"] - empty[0, 1] - 12)
    assert np.all(far > 3.0)                                         # the hot pixel: no star
    i = np.argmin(np.hypot(got["x"] - star["x"], got["y"] - star["y"]))
    j = np.argmin(np.hypot(clean["x"] - star["x"], clean["y"] - star["y"]))
    assert math.hypot(got["x"][i] - clean["x"][j], got["y"][i] - clean["y"][j]) < 0.02
    k = np.argmin(np.hypot(got["x"] - bright["x"], got["y"] - bright["y"]))
    assert bool(got["flags"][k] & StarFlag.SATURATED) == bool(bright["flags"]
                                                              & StarFlag.SATURATED)


def test_the_same_frame_gives_the_same_stars_and_no_new_buffers():
    cfg, frame, full, stars = _frame(9)
    origins = _origins(np.stack((stars["x"][:30], stars["y"][:30]), 1), frame.image.shape)
    detector = StampDetector(cfg.detect, frame.image.shape, CELL, len(origins), 4, 10,
                             frame.image.dtype)
    psf = full.psf_tracker.current
    first = detector.detect(frame.image, origins, psf).stars.copy()
    buffers = [id(detector.stack), id(detector.filt), id(detector.table.stars)]
    second = detector.detect(frame.image, origins, psf).stars
    np.testing.assert_array_equal(first, second)
    assert buffers == [id(detector.stack), id(detector.filt), id(detector.table.stars)]


def test_the_pipeline_tracks_with_stamps_and_measures_the_psf_on_its_turns():
    """Windowed frames go to the stamp detector, but one in ``track_lens_every``, which
    measures the PSF through the mosaic; ``track_stamps: false`` is the mosaic always."""
    cfg = Config()
    cat = load_catalogue(epoch_year=2026.0, mag_limit=cfg.catalogue.mag_limit)
    R = matrix_from_radec_roll(*np.radians((84.0, -3.0, 10.0)))
    every = 3
    for stamps in (True, False):
        cfg_arm = dataclasses.replace(cfg, identify=dataclasses.replace(
            cfg.identify, track_lens_every=every, track_stamps=stamps))
        pipe = Pipeline(cfg_arm)
        rng = np.random.default_rng(4)
        kinds = []
        for i in range(9):
            r = pipe.process(render_sky(cfg.camera, cat, R, cfg.sim, rng).image, 10, int(i * 1e8))
            assert r.solution.ok
            if r.windows:
                kinds.append("stack" if "windows.stack" in r.stages_ms else "mosaic")
        assert len(kinds) >= 5
        if stamps:
            assert kinds.count("mosaic") == sum(1 for k in range(1, len(kinds) + 1)
                                                if k % every == 0)
            assert kinds.count("stack") >= 3
        else:
            assert set(kinds) == {"mosaic"}


def test_stars_the_frame_edge_cuts_are_found_in_their_windows():
    """Stars 2-5 px inside each of the four edges (SNR about 50, as HIP 45080 4.9 px from
    the right edge in the bench's 16 mm 0 deg/s slew, seed 13), in windows clipped into
    the frame as the planner clips them. The stamps kept only peaks a stamp's reach
    (radius + 1) from the frame's edge: all those within 4 px were lost, which the full
    frame fits on the pixels inside it. Each is found, flagged as the full frame flags
    it, and the centres' RMS against the truth is within 5 % of the full frame's
    (3 frames, 48 edge stars)."""
    shape = (400, 400)
    offsets = np.array([2.0, 3.0, 4.0, 5.0])
    along = 40.0 + 80.0 * np.arange(4) + np.array([0.1, 0.35, 0.6, 0.85])
    x = np.concatenate([offsets, along, shape[1] - 1 - offsets, along + 0.2])
    y = np.concatenate([along + 0.45, offsets, along + 0.7, shape[0] - 1 - offsets])
    grid = np.arange(60, 341, 56) + 0.37            # brighter stars inside: the PSF
    gx, gy = (a.ravel() for a in np.meshgrid(grid, grid + 0.21))
    sim = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    origins = _origins(np.stack((x, y), 1), shape)
    errors = {"full": [], "stamps": []}
    for seed in range(3):
        frame = render_points(shape, np.concatenate((x, gx)), np.concatenate((y, gy)),
                              np.concatenate((np.full(len(x), 6e3), np.full(len(gx), 3e4))),
                              sim, np.random.default_rng(seed), noise_model="realistic",
                              psf_sigma_px=1.2)
        full = make_detector(DetectConfig(), shape, 10)
        for _ in range(2):       # the PSF's running estimate settles
            whole = full.detect(frame.image).stars.copy()
        stamps = StampDetector(DetectConfig(), shape, CELL, len(origins), 4, 10,
                               frame.image.dtype).detect(frame.image, origins,
                                                         full.psf_tracker.current).stars
        for name, found in (("full", whole), ("stamps", stamps)):
            d = np.hypot(x[:, None] - found["x"][None, :], y[:, None] - found["y"][None, :])
            j = d.argmin(axis=1)
            assert np.all(d[np.arange(len(x)), j] < 0.5), (name, d.min(axis=1))
            errors[name].append(d[np.arange(len(x)), j])
            if name == "full":
                flags = found["flags"][j]
            else:
                np.testing.assert_array_equal(found["flags"][j], flags)
                assert np.all(found["snr"][j] > 25.0)
    rms = {name: math.sqrt(np.mean(np.square(e))) for name, e in errors.items()}
    print(rms)
    assert rms["stamps"] < 1.05 * rms["full"], rms



def test_the_stars_the_edge_cuts_share_the_first_steps_of_the_others_fit():
    """Unblended stars are fitted in one run of their first two steps; only the edge's
    stars (four steps) take two more in a second run (a run's cost is mostly its steps'
    numpy calls): 4 steps' passes a frame instead of 2 + 4, the star-steps unchanged
    (2 per whole star, 4 per cut one), the edge stars found within 0.5 px."""
    shape = (200, 200)
    x = np.array([2.5, 60.3, 120.7, 196.4])
    y = np.array([80.2, 3.1, 140.6, 100.9])
    sim = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    frame = render_points(shape, x, y, np.full(4, 2e4), sim, np.random.default_rng(5),
                          noise_model="realistic", psf_sigma_px=1.2)
    full = make_detector(DetectConfig(), shape, 10)
    for _ in range(2):       # the PSF's running estimate settles
        full.detect(frame.image)
    origins = _origins(np.stack((x, y), 1), shape)
    stamps = StampDetector(DetectConfig(), shape, CELL, len(origins), 4, 10, frame.image.dtype)
    passes = []
    solve = stamps.fit._solve
    stamps.fit._solve = lambda normal, grad: passes.append(len(normal)) or solve(normal, grad)
    found = stamps.detect(frame.image, origins, full.psf_tracker.current).stars
    d, _ = _nearest(np.stack((x, y), 1), np.stack((found["x"], found["y"]), 1))
    assert np.all(d < 0.5), d
    assert passes == [4, 4, 3, 3], passes      # 3 cut stars, 1 whole one



def test_peaks_in_the_filter_gaps_are_never_candidates():
    """The peak tests run over the whole filtered image, its gaps between windows too
    (whole rows): with noise in every pixel, gaps included, the candidates are exactly the
    3 x 3 maxima above threshold inside the windows' allowed rows and columns (a reference
    over the windows' own view), none from a gap."""
    shape = (300, 400)
    origins = np.array([[0, 10], [100, 0], [376, 140], [200, 276], [150, 150], [150, 200]])
    stamps = StampDetector(DetectConfig(), shape, CELL, len(origins), 4, 10, np.uint16)
    stamps._configure(1.2)
    rng = np.random.default_rng(11)
    stamps.filt[...] = rng.normal(0.0, 1.0, stamps.filt.shape)
    stamps.noise[:] = rng.uniform(0.05, 0.2, len(origins))
    np.equal(origins, 0, out=stamps.edge[:, :2])
    np.equal(origins, stamps.far_origin, out=stamps.edge[:, 2:])
    win, py, px = stamps._peaks(origins)
    n, c = len(origins), CELL
    filt = stamps.filt.reshape(c, n, -1)
    assert filt.shape[2] > c                       # there are gaps
    peak = filt[:, :, :c] >= stamps.dilated.reshape(c, n, -1)[:, :, :c]
    peak &= filt[:, :, :c] > (stamps.k_sigma * stamps.filter_gain) * stamps.noise[None, :, None]
    ry, rw, rx = peak.nonzero()
    low = np.where(stamps.edge[:, :2], 0, stamps.margin)[rw]
    high = np.where(stamps.edge[:, 2:], c - 1, c - 1 - stamps.margin)[rw]
    ok = (rx >= low[:, 0]) & (rx <= high[:, 0]) & (ry >= low[:, 1]) & (ry <= high[:, 1])
    gap = filt[:, :, c:] >= stamps.dilated.reshape(c, n, -1)[:, :, c:]
    assert gap.any()                               # the gaps hold maxima of their own
    assert len(win) == np.count_nonzero(ok) > 0
    assert set(zip(win.tolist(), py.tolist(), px.tolist(), strict=True)) == set(
        zip(rw[ok].tolist(), ry[ok].tolist(), rx[ok].tolist(), strict=True))
