"""Windowed tracking: predictions and their uncertainty, windows, detection in them, lock.

Outcomes against the simulator's truth: predicted positions within their
stated uncertainty, centroids from windows as good as the full frame's,
attitudes from windows within bounds, lock kept through a slew and regained
after a dark frame.
"""

import dataclasses
import math

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.attitude import attitude_error, matrix_from_radec_roll, matrix_from_rotation_vector
from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.config import Config, IdentifyConfig
from tracker.detect import make_detector
from tracker.detect.default import effective_sigma
from tracker.detect.fit import PixelGaussianFit
from tracker.detect.result import StarFlag
from tracker.detect.trail import TrailFit, normal_cdf
from tracker.detect.windows import WindowDetector
from tracker.identify import make_solver
from tracker.identify.predict import (
    CENTROID_FLOOR_PX,
    CENTROID_SPREAD_PX,
    TrackPrediction,
    informative,
    pinhole_travel,
    pixel_jacobian,
)
from tracker.identify.skyindex import DecSorted
from tracker.identify.solver import Solver
from tracker.identify.windows import WindowPlanner
from tracker.pipeline import Pipeline
from tracker.sim import render_sequence, render_sky

ARCSEC = math.radians(1 / 3600)


def _sky(seed: int = 5, **sim_changes):
    cfg = Config()
    cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, **sim_changes))
    cat = load_catalogue(epoch_year=2026.0, mag_limit=cfg.catalogue.mag_limit)
    return cfg, cat, np.random.default_rng(seed)


def _nearest(xy, truth_xy):
    d = np.hypot(xy[:, None, 0] - truth_xy[None, :, 0], xy[:, None, 1] - truth_xy[None, :, 1])
    return d.min(axis=1)


def test_jacobian_matches_a_small_rotation():
    """J theta is how far a pixel moves when the attitude turns by theta (predict.py)."""
    cam = camera(16.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], size=(20, 2))
    v = cam.pixel_to_vector(xy)
    theta = np.array([2e-5, -3e-5, 4e-5])
    moved = cam.vector_to_pixel(v @ matrix_from_rotation_vector(theta).T)
    np.testing.assert_allclose(moved - xy, pixel_jacobian(cam, v) @ theta, atol=2e-3)


def test_pinhole_travel_is_a_small_rotations_motion():
    """pinhole_travel (the smear's closed form) moves pixels as a small turn of a pinhole
    camera does, and agrees with J theta to rounding."""
    cam = dataclasses.replace(camera(16.0), k1=0.0, k2=0.0)
    rng = np.random.default_rng(2)
    xy = rng.uniform([0, 0], [cam.width - 1, cam.height - 1], size=(30, 2))
    v = cam.pixel_to_vector(xy)
    theta = np.array([3e-5, 2e-5, -5e-5])
    moved = cam.vector_to_pixel(v @ matrix_from_rotation_vector(theta).T)
    travel = pinhole_travel(cam, xy, theta)
    np.testing.assert_allclose(travel, moved - xy, atol=2e-3)
    np.testing.assert_allclose(travel, pixel_jacobian(cam, v) @ theta, rtol=0, atol=1e-12)


def test_predictions_fall_within_their_uncertainty():
    """A tracked slew: the next frame's stars lie within their predictions' uncertainty.

    At a constant rate, with no acceleration allowed, the uncertainty is the
    last attitude's and the rate's alone: the errors must be of its size.
    """
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(track_accel_deg_s2=0.0), cam, catalogue())
    rng = np.random.default_rng(7)
    R0, rate = random_rotation(rng), np.radians([0.7, -0.5, 0.3])
    normalised = []
    for i in range(12):
        R = matrix_from_rotation_vector(-rate * i / 10.0) @ R0
        if i >= 3:
            pred = solver.prediction(int(i * 1e8), 0.02)
            assert pred is not None and len(pred.xy) >= 20
            named = pred.catalogue >= 0
            truth = cam.vector_to_pixel(catalogue().vectors[pred.catalogue[named]] @ R.T)
            err = np.hypot(*(pred.xy[named] - truth).T)
            normalised.extend(err / pred.sigma_px[named])
            # the smear: the body rate moves the stars by J (-omega) T
            travel = np.hypot(*pred.smear_px[named].T)
            assert np.allclose(travel, np.linalg.norm(rate[:2]) * cam.f_px * 0.02, rtol=0.3)
        stars, _ = synthetic_stars(cam, R, rng)
        assert solver.solve(stars, int(i * 1e8)).ok
    normalised = np.array(normalised)
    print(f"radial error / sigma: median {np.median(normalised):.2f}, "
          f"p99 {np.percentile(normalised, 99):.2f}")
    assert np.mean(normalised < 3.0) > 0.99
    assert 0.2 < np.median(normalised) < 1.5     # the median of a radial Gaussian: 0.83


def test_no_prediction_without_a_rate():
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rng = np.random.default_rng(8)
    stars, _ = synthetic_stars(cam, random_rotation(rng), rng)
    assert solver.prediction(0, 0.02) is None
    assert solver.solve(stars, 0).ok
    assert solver.prediction(int(1e8), 0.02) is None     # one solution: no rate yet
    assert solver.solve(stars, int(1e8)).ok
    assert solver.prediction(int(2e8), 0.02) is not None
    assert solver.prediction(int(5e9), 0.02) is None     # beyond track_max_gap_s


def _prediction(xy, sigma=0.3, smear=(0.0, 0.0)):
    xy = np.asarray(xy, dtype=float)
    n = len(xy)
    return TrackPrediction(R=np.eye(3), xy=xy, sigma_px=np.full(n, sigma),
                           smear_px=np.tile(smear, (n, 1)).astype(float),
                           catalogue=np.arange(n), dt_s=0.1)


def test_windows_hold_their_stars_and_grow_with_uncertainty_and_smear():
    planner = WindowPlanner(1600, 1300, capacity=12, sweep=4, sigmas=3.0, reach_px=4,
                            max_cell_px=96)
    xy = [[800.2, 650.7], [3.0, 4.0], [1598.0, 1200.0], [400.0, 1299.0]]
    plan = planner.plan(_prediction(xy))
    assert plan.cell == 24 and plan.stars == 4 and len(plan.origins) == 12
    for (x, y), (x0, y0) in zip(xy, plan.origins[:4], strict=True):
        assert x0 <= x <= x0 + plan.cell - 1 and y0 <= y <= y0 + plan.cell - 1
    assert planner.plan(_prediction(xy, sigma=3.0)).cell == 48          # 2 (3 x 3 + 4) + 1
    assert planner.plan(_prediction(xy, sigma=8.0)).cell == 72          # 2 (3 x 8 + 4) + 1
    assert planner.plan(_prediction(xy, smear=(60.0, 0.0))).cell == 72  # 2 (30 + 0.9 + 4) + 1
    assert planner.plan(_prediction(xy, sigma=20.0)) is None            # beyond 96 px


def test_the_sweep_covers_the_whole_frame_in_turn():
    planner = WindowPlanner(480, 288, capacity=6, sweep=2, sigmas=3.0, reach_px=4,
                            max_cell_px=96)
    seen = np.zeros((288, 480), bool)
    for _ in range(48):          # 240 windows of 24 px, 5 a frame
        assert not seen.all()
        plan = planner.plan(_prediction([[100.0, 100.0]]))
        assert plan.cell == 24
        for x0, y0 in plan.origins[plan.stars:]:
            seen[y0:y0 + 24, x0:x0 + 24] = True
    assert seen.all()


def test_window_centroids_are_as_good_as_the_full_frame():
    """The same stars, detected in 48 px windows around them, against the truth."""
    cfg, cat, rng = _sky(psf_sigma_px=1.3)
    frame = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((84, -3, 10))),
                       cfg.sim, rng)
    full = make_detector(cfg.detect, frame.image.shape, 10).detect(frame.image).stars.copy()
    truth = frame.stars[frame.stars["in_frame"]]
    txy = np.stack((truth["x"], truth["y"]), 1)
    bright = full[:48]
    bright = bright[_nearest(np.stack((bright["x"], bright["y"]), 1), txy) < 1.0]
    origins = np.clip(np.rint(np.stack((bright["x"], bright["y"]), 1) - 23.5), 0,
                      [1600 - 48, 1300 - 48]).astype(np.intp)
    origins = np.concatenate((origins, origins[:4]))     # overlapping windows: found once
    windows = WindowDetector(lambda shape: make_detector(dataclasses.replace(
        cfg.detect, threads=1, background_tile_px=16, background_step_px=2), shape, 10),
        frame.image.shape, 48, len(origins), 4, 256, frame.image.dtype)
    got = windows.detect(frame.image, origins).stars
    assert len(got) >= len(bright)       # every star (and perhaps a faint neighbour)
    gxy = np.stack((got["x"], got["y"]), 1)
    assert np.all(later_free(gxy))
    bxy = np.stack((bright["x"], bright["y"]), 1)
    same = np.argmin(np.hypot(*(bxy[:, None, :] - gxy[None, :, :]).transpose(2, 0, 1)), 1)
    assert np.all(np.hypot(*(gxy[same] - bxy).T) < 0.3)
    rms_full = math.sqrt(np.mean(_nearest(bxy, txy) ** 2))
    rms_win = math.sqrt(np.mean(_nearest(gxy[same], txy) ** 2))
    print(f"RMS error against the truth: full frame {rms_full:.4f} px, windows {rms_win:.4f}")
    assert rms_win < 1.1 * rms_full
    edge = (gxy[:, 0] < 4) | (gxy[:, 1] < 4) | (gxy[:, 0] > 1595) | (gxy[:, 1] > 1295)
    np.testing.assert_array_equal((got["flags"] & StarFlag.EDGE) != 0, edge)


def later_free(xy):
    d = np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
    np.fill_diagonal(d, np.inf)
    return d.min(axis=1) > 1.0


@pytest.mark.slow
def test_windowed_tracking_holds_a_slew_and_returns_after_a_dark_frame():
    """1 deg/s (9 px of smear in 100 ms) at 10 fps, 16 mm, one frame dark in the middle.

    Each frame goes through two pipelines: windowed tracking and the whole
    frame every frame, both re-centring trailed stars (tracker.detect.trail).
    Tracking runs in windows from the third frame on, the dark frame fails
    and the next one tracks again (in windows from the one after); the
    windowed attitudes are as close to the truth as the full frame's (RMS
    within 30 % on these 20 frames) and within 8 arcsec cross-boresight and
    40 arcsec roll RMS (without the trail fit: about 12 and 46), and so is
    the rate.
    """
    cfg, cat, rng = _sky(seed=9, psf_sigma_px=1.4)
    R0 = matrix_from_radec_roll(*np.radians((120.0, 30.0, 40.0)))
    rate = (0.6, 0.75, 0.27)                     # |rate| 1.0 deg/s
    frames = list(render_sequence(cfg.camera, cat, R0, cfg.sim, rng, 24, fps=10.0,
                                  rate_deg_s=rate))
    dark = 12
    full_cfg = dataclasses.replace(cfg, identify=dataclasses.replace(cfg.identify,
                                                                     track_windows=False))
    arms = {"windows": Pipeline(cfg), "full": Pipeline(full_cfg)}
    rows = {name: [] for name in arms}
    errors = {name: [] for name in arms}
    for i, f in enumerate(frames):
        image = np.full_like(f.image, int(np.median(f.image))) if i == dark else f.image
        for name, pipe in arms.items():
            r = pipe.process(image, 10, int(i * 1e8), exposure_s=cfg.sim.exposure_ms / 1e3)
            rows[name].append(r)
            if i == dark:
                assert not r.solution.ok
                continue
            assert r.solution.ok, (name, i, r.solution.reason)
            if i >= 3:
                cross, roll = attitude_error(r.solution.R, f.R)
                rate_err = np.degrees(r.solution.rate_rad_s) - rate
                errors[name].append((cross / ARCSEC, roll / ARCSEC, *rate_err))
    win = rows["windows"]
    for i in range(2, len(frames)):
        if i not in (dark, dark + 1):
            assert win[i].solution.mode == "tracking" and win[i].windows > 0, i
    assert win[dark + 1].solution.mode == "tracking"       # the lock returns at once
    rms = {name: np.sqrt(np.mean(np.square(e), axis=0)) for name, e in errors.items()}
    print({name: np.round(v, 3) for name, v in rms.items()})
    assert rms["windows"][0] < 8.0 and rms["windows"][1] < 40.0
    assert rms["windows"][0] < 1.3 * rms["full"][0]        # cross-boresight
    assert rms["windows"][1] < 1.3 * rms["full"][1]        # roll
    assert np.all(rms["windows"][2:] < 1.3 * rms["full"][2:] + 0.002)   # rate, deg/s


def _rate_run(cfg: IdentifyConfig, seed: int, frames: int = 25):
    cam = camera(16.0)
    solver = make_solver(cfg, cam, catalogue())
    rng = np.random.default_rng(seed)
    R0, rate = random_rotation(rng), np.radians([0.5, -0.8, 0.6])
    sols = []
    for i in range(frames):
        stars, _ = synthetic_stars(cam, matrix_from_rotation_vector(-rate * i / 10.0) @ R0, rng)
        sols.append(solver.solve(stars, int(i * 1e8)))
    return rate, sols


def test_the_rate_sigma_describes_its_errors_and_gates_rate_valid():
    """The rate's stated 1-sigma (docs/protocol.md 2.2) against its errors from the truth."""
    rate, sols = _rate_run(IdentifyConfig(), seed=21)
    z = np.array([(s.rate_rad_s - rate) / s.sigma_rate_rad_s for s in sols[3:]])
    print("rate error / sigma RMS per axis:", np.sqrt(np.mean(z ** 2, axis=0)))
    assert np.all(np.abs(z) < 4.0)
    assert np.all(np.sqrt(np.mean(z ** 2, axis=0)) > 0.2)      # not vacuous either
    # a threshold below the roll axis' sigma withholds the rate (RATE_VALID clear) ...
    roll_sigma = np.median([math.degrees(s.sigma_rate_rad_s[2]) for s in sols[3:]])
    _, strict = _rate_run(IdentifyConfig(rate_valid_sigma_deg_s=0.5 * roll_sigma), seed=21)
    assert all(s.ok and s.rate_rad_s is None and s.sigma_rate_rad_s is None for s in strict)
    # ... while tracking goes on with the rate it keeps
    assert [s.mode for s in strict[2:]] == ["tracking"] * (len(strict) - 2)


@pytest.mark.parametrize("rate_deg_s, exposure_ms", [((0.6, 0.8, 0.0), 100.0),
                                                     ((1.8, 2.4, 0.0), 20.0),
                                                     ((1.8, 2.4, 0.0), 50.0)])
def test_trailed_stars_are_centred_by_the_line_spread_fit(rate_deg_s, exposure_ms):
    """Stars trailed 9, 6 and 14 px (1 and 3 deg/s, 16 mm): fitted centres against the truth.

    The detector's centroid wanders along a trail (median error 0.35-2.3 px
    here); the fit's median error stays near a third of a pixel.
    """
    cfg, cat, rng = _sky(seed=3, exposure_ms=exposure_ms, psf_sigma_px=1.3)
    cam = CameraModel.from_config(cfg.camera)
    frame = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((84, -3, 10))),
                       cfg.sim, rng, rate_deg_s=rate_deg_s)
    det = make_detector(cfg.detect, frame.image.shape, 10).detect(frame.image).stars
    xy = np.stack((det["x"], det["y"]), 1)
    smear = pixel_jacobian(cam, cam.pixel_to_vector(xy)) @ (-np.radians(rate_deg_s)
                                                            * exposure_ms / 1e3)
    fitted = TrailFit(effective_sigma(cfg.detect.psf_sigma_px)).refine(frame.image, xy, smear)
    truth = frame.stars[frame.stars["in_frame"]]
    txy = np.stack((truth["x"], truth["y"]), 1)
    d = np.hypot(*(xy[:, None, :] - txy[None]).transpose(2, 0, 1))
    near, which = d.min(axis=1) < 4.0, d.argmin(axis=1)
    before = np.median(np.hypot(*(xy[near] - txy[which[near]]).T))
    after = np.median(np.hypot(*(fitted[near] - txy[which[near]]).T))
    print(f"median error: windowed centroid {before:.2f} px, line-spread fit {after:.2f} px")
    # where the detector's own centroid already holds a short trail to 0.4 px (its PSF
    # fit, issue 12), the fit must not make it worse; elsewhere it must cut the error
    assert after < 0.4 and (after < 0.75 * before or after <= before < 0.4)


def test_normal_cdf():
    z = np.linspace(-6, 6, 121)
    exact = np.array([0.5 * (1 + math.erf(v / math.sqrt(2))) for v in z])
    np.testing.assert_allclose(normal_cdf(z), exact, atol=2e-7)


def test_windows_that_do_not_verify_hand_the_frame_to_lost_in_space():
    """Locked on one field, shown another: the windows fail, the whole frame is solved."""
    cfg, cat, rng = _sky(seed=11)
    here = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((40, 20, 0))),
                      cfg.sim, rng)
    there = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((200, -50, 90))),
                       cfg.sim, rng)
    pipe = Pipeline(cfg)
    for i in range(4):
        r = pipe.process(here.image, 10, int(i * 1e8))
    assert r.windows > 0 and r.solution.mode == "tracking"
    r = pipe.process(there.image, 10, int(4 * 1e8))
    assert r.windows == 0 and r.solution.ok and r.solution.mode == "lost_in_space"
    assert attitude_error(r.solution.R, there.R)[0] < 10 * ARCSEC


def test_frames_carry_their_cpu_time():
    """Every frame reports its CPU time; a frame detected whole also its detector's (which
    the frame's contains), a windowed frame only the whole frame's (FrameResult)."""
    cfg, cat, rng = _sky(seed=11)
    sky = render_sky(cfg.camera, cat, matrix_from_radec_roll(*np.radians((40, 20, 0))),
                     cfg.sim, rng)
    pipe = Pipeline(cfg)
    results = [pipe.process(sky.image, 10, int(i * 1e8)) for i in range(4)]
    assert results[0].windows == 0 and results[-1].windows > 0
    for r in results:
        assert r.cpu_ms > 0
        if r.windows:
            assert r.detect_cpu_ms is None
        else:
            assert 0 < r.detect_cpu_ms <= r.cpu_ms


def test_windows_take_the_full_frames_psf_and_measure_it_in_turn():
    """The windows use the PSF the full frames measured; a change of focus reaches it
    within ``identify.track_lens_every`` windowed frames (their meter's turn), and
    between turns the PSF in use stays as it was."""
    cfg, cat, rng = _sky(seed=12)
    every = 4
    cfg = dataclasses.replace(cfg, identify=dataclasses.replace(cfg.identify,
                                                                track_lens_every=every))
    R = matrix_from_radec_roll(*np.radians((84.0, -3.0, 10.0)))
    pipe = Pipeline(cfg)
    sharp, change, frames = 1.1, 8, 8 + 2 * every
    reported = []
    for i in range(frames):
        sim = dataclasses.replace(cfg.sim, psf_sigma_px=sharp if i < change else 1.6)
        r = pipe.process(render_sky(cfg.camera, cat, R, sim, rng).image, 10, int(i * 1e8))
        assert r.solution.ok and (i < 3 or r.windows > 0), i
        reported.append((r.windows > 0, r.detections.psf_sigma_px))
    full = [psf for windowed, psf in reported[:change] if not windowed]
    given = [psf for windowed, psf in reported[:change] if windowed]
    assert abs(full[-1] / sharp - 1) < 0.1
    assert all(abs(psf / full[-1] - 1) < 0.05 for psf in given)   # the full frames' PSF
    after = [psf for _, psf in reported[change:]]
    assert after[0] == given[-1] or abs(after[0] / 1.6 - 1) < 0.1
    assert len(set(after[:every])) <= 2                  # moved at most once, on its turn
    assert all(abs(psf / 1.6 - 1) < 0.1 for psf in after[every:])


def test_windows_go_to_the_stars_that_carry_the_information():
    """Bright stars near the boresight hold the cross-boresight information, a few faint
    ones far out hold roll's: both kinds get windows, the faint ones near the centre
    do not, and each share is reached by the fewest stars that reach it."""
    rng = np.random.default_rng(3)
    centre = (800.0, 650.0)
    near = centre + rng.normal(0.0, 60.0, (12, 2))
    far = np.array([[20.0, 20.0], [1580.0, 1280.0], [20.0, 1280.0], [1580.0, 20.0]])
    xy = np.concatenate((near[:6], far, near[6:]))
    snr = np.concatenate((np.full(6, 200.0), np.full(4, 12.0), np.full(6, 4.0)))
    chosen = informative(xy, snr, centre, 0.95)
    assert set(range(10)) <= set(chosen) and len(chosen) < 16
    assert np.all(np.diff(chosen) > 0)                    # the input's order kept
    w = 1.0 / (CENTROID_FLOOR_PX ** 2 + (CENTROID_SPREAD_PX / snr) ** 2)
    rho2 = np.sum(np.square(xy - centre), axis=1)
    for info in (w, w * rho2):
        assert info[chosen].sum() >= 0.95 * info.sum()
    # the stars one ranking takes are the fewest that reach its share
    cross = np.sort(w)[::-1]
    k = np.count_nonzero(np.cumsum(cross) < 0.95 * w.sum()) + 1
    assert len(chosen) >= k and np.cumsum(cross)[k - 2] < 0.95 * w.sum()
    np.testing.assert_array_equal(informative(xy, snr, centre, 1.0), np.arange(16))
    assert len(informative(xy[:0], snr[:0], centre, 0.95)) == 0


def _windowed_trail_centres(cfg, frames, monkeypatch, point_fit_all: bool):
    """(point-fitted star-steps' stars, errors against the truth px) of the stars the solve
    gets on windowed frames; ``point_fit_all``: every star point-fitted (as before the
    stamp detector left trailed stars to the trail fit)."""
    pipe = Pipeline(cfg)
    if point_fit_all:
        monkeypatch.setattr(pipe, "_refit_plan", lambda *args: None)
    fitted, solved, errors = [0], [], []
    run, untrailed = PixelGaussianFit.run, pipe._untrailed

    def counted(fit, m, *args, **kwargs):
        fitted[0] += m
        return run(fit, m, *args, **kwargs)

    monkeypatch.setattr(PixelGaussianFit, "run", counted)
    monkeypatch.setattr(pipe, "_untrailed",
                        lambda *args: solved.append(untrailed(*args)) or solved[-1])
    windowed = 0
    for i, f in enumerate(frames):
        before = fitted[0]
        r = pipe.process(f.image, 10, int(i * 1e8), exposure_s=0.02)
        assert r.solution.ok, i
        if not r.windows:
            fitted[0] = before                   # the full frame's own fits not counted
            continue
        windowed += 1
        truth = f.stars[f.stars["in_frame"]]
        stars, _ = solved[-1]
        errors.extend(_nearest(np.stack((stars["x"], stars["y"]), 1),
                               np.stack((truth["x"], truth["y"]), 1)))
    monkeypatch.setattr(PixelGaussianFit, "run", run)
    assert windowed >= len(frames) - 4
    errors = np.array(errors)
    return fitted[0], errors[errors < 3.0]


def test_stars_the_trail_fit_centres_skip_the_point_fit_in_their_windows(monkeypatch):
    """3 deg/s across the boresight, 16 mm, 20 ms: every star trails 5.5 px, longer than the
    trail fit's minimum. On windowed frames the stamp detector leaves the stars the trail
    fit will centre anew at their filtered peaks' vertices instead of fitting the point
    PSF (whose centre the trail fit replaced): only stars whose trail box the frame's
    edge cuts are point-fitted, and the centres the solve gets are as close to the truth
    as when the trail fit started from the point fit (median and RMS within 5 %)."""
    cfg, cat, rng = _sky(seed=17, exposure_ms=20.0, psf_sigma_px=1.3)
    R0 = matrix_from_radec_roll(*np.radians((150.0, 20.0, 70.0)))
    frames = list(render_sequence(cfg.camera, cat, R0, cfg.sim, rng, 16, fps=10.0,
                                  rate_deg_s=(1.8, -2.4, 0.0)))
    fitted, errors = {}, {}
    for arm, point_fit_all in (("vertex", False), ("point fit", True)):
        fitted[arm], errors[arm] = _windowed_trail_centres(cfg, frames, monkeypatch,
                                                           point_fit_all)
    stats = {arm: (np.median(e), math.sqrt(np.mean(e * e)), len(e))
             for arm, e in errors.items()}
    print(fitted, stats)
    assert fitted["point fit"] > 100 and fitted["vertex"] < 0.1 * fitted["point fit"]
    assert stats["vertex"][2] >= stats["point fit"][2] - 2          # no star lost
    assert stats["vertex"][0] < 1.05 * stats["point fit"][0]
    assert stats["vertex"][1] < 1.05 * stats["point fit"][1]


def test_a_windowed_frame_reckons_the_smear_once_and_reuses_the_catalogue_cone(monkeypatch):
    """Work counted on a 3 deg/s slew (16 mm, 10 fps, 20 ms: trails of 5.5 px): each
    windowed frame reckons its stars' smear from the rate once, for the stamp detector's
    choice of the stars the trail fit centres, at the filtered peaks; the trail fit and
    the solve's weights take those (it reckoned them a second time, at the detected
    centres), within 0.002 px of the smear at the centres the solve gets (a few px
    along the trail from the peaks); and the catalogue's cone, 2 deg wider than the
    field, is searched anew at most every sixth frame (0.3 deg a frame; every second
    frame at 0.5 deg)."""
    cfg, cat, rng = _sky(seed=23, exposure_ms=20.0, psf_sigma_px=1.3)
    R0 = matrix_from_radec_roll(*np.radians((40.0, -35.0, 10.0)))
    frames = list(render_sequence(cfg.camera, cat, R0, cfg.sim, rng, 14, fps=10.0,
                                  rate_deg_s=(-2.4, 1.8, 0.0)))
    counts = {"smear": 0, "cone": 0}
    smear_px, solve = Solver.smear_px, Solver.solve

    def counting(name, method):
        def counted(*args, **kwargs):
            counts[name] += 1
            return method(*args, **kwargs)
        return counted

    handed = []

    def solving(solver, stars, t_ns, *args, **kwargs):
        xy = np.stack((stars["x"], stars["y"]), axis=1)
        handed.append((kwargs["smear_px"], smear_px(solver, xy, t_ns, kwargs["exposure_s"])))
        return solve(solver, stars, t_ns, *args, **kwargs)

    monkeypatch.setattr(Solver, "smear_px", counting("smear", Solver.smear_px))
    monkeypatch.setattr(DecSorted, "cone", counting("cone", DecSorted.cone))
    monkeypatch.setattr(Solver, "solve", solving)
    pipe = Pipeline(cfg)
    windowed, smears, cones, errors = 0, [], 0, []
    for i, f in enumerate(frames):
        counts.update(smear=0, cone=0)
        r = pipe.process(f.image, 10, int(i * 1e8), exposure_s=0.02)
        assert r.solution.ok, i
        if r.windows:
            windowed += 1
            smears.append(counts["smear"])
            cones += counts["cone"]
            given, at_centres = handed[-1]
            errors.append(np.abs(given - at_centres).max())
    assert windowed >= len(frames) - 3
    assert smears == [1] * windowed, smears
    assert max(errors) < 0.002, errors
    assert cones <= 2, cones
