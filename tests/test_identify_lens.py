"""Focal length and distortion: fitted per frame, followed by the slow filter while tracking."""

import dataclasses
import math

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.attitude import matrix_from_rotation_vector
from tracker.config import IdentifyConfig
from tracker.identify import make_solver
from tracker.identify.lens import LensFilter, LensPrior, fit_frame
from tracker.sim.sequence import attitude_at


def test_one_frame_gives_focal_length_and_k1_with_honest_sigmas():
    """50-odd stars, 0.1 px noise, a lens 2 % long with k1 = 0.05, from the nominal lens.

    The errors must be within 4 of the reported sigmas, and the sigmas
    small: f to better than 1e-4 relative, k1 to better than 0.01.
    """
    nominal = camera(16.0)
    true_cam = dataclasses.replace(nominal, f_px=nominal.f_px * 1.02, k1=0.05)
    rng = np.random.default_rng(31)
    cat = catalogue()
    R = random_rotation(rng)
    stars, truth = synthetic_stars(true_cam, R, rng, noise_px=0.1, n_false=0)
    rows = np.argsort(cat.hip)[np.searchsorted(cat.hip, truth, sorter=np.argsort(cat.hip))]
    xy = np.column_stack((stars["x"], stars["y"]))
    start = matrix_from_rotation_vector([2e-4, -1e-4, 3e-4]) @ R
    prior = LensPrior(nominal.f_px, 0.03 * nominal.f_px, 0.0, 0.1)
    fit = fit_frame(xy, cat.vectors[rows], start, nominal, prior, 0.25)
    sigma_f, sigma_k1 = np.sqrt(np.diag(fit.cov))
    assert abs(fit.camera.f_px - true_cam.f_px) < 4 * sigma_f
    assert abs(fit.camera.k1 - 0.05) < 4 * sigma_k1
    assert sigma_f < 1e-4 * true_cam.f_px and sigma_k1 < 0.01
    assert fit.sigma_px == pytest.approx(0.1, rel=0.3)
    assert np.median(fit.residuals) < 0.3


def test_filter_keeps_its_prior_and_forgets_old_frames():
    prior = LensPrior(1000.0, 10.0, 0.0, 0.1)
    lens = LensFilter(prior, time_constant_s=10.0)
    state = lens.state()
    assert (state.f_px, state.sigma_f_px, state.k1, state.frames) == (1000.0, 10.0, 0.0, 0)

    class Frame:   # information as from fit_frame: f = 1010 with sigma 1, k1 unmeasured
        info = np.diag([1.0, 0.0])
        info_vector = info @ [1010.0, 0.0]

    lens.update(Frame, 0)
    assert lens.state().f_px == pytest.approx(1010.0 - 10.0 / 101, rel=1e-9)
    lens.update(Frame, 0)
    assert lens.state().frames == 2
    # ten time constants later the two frames weigh e^-10 of themselves
    lens.update(Frame, int(100e9))
    assert lens.state().sigma_f_px == pytest.approx(1 / math.sqrt(1 + 2 * math.exp(-10)
                                                                   + 1e-2), rel=1e-6)


def test_tracking_follows_a_focal_length_that_jumps():
    """A slew at 5 fps; after 20 s the lens grows 1000 ppm longer (a temperature step).

    With a 5 s time constant the filter has settled at the old value by 20 s
    and at the new one 40 s after the step (8 time constants: the lag is
    e^-8, under 1 ppm); each estimate is within 5 of its reported sigmas, and
    those are tens of ppm (single frames give about 100 ppm).
    """
    f0 = camera(16.0)
    cfg = IdentifyConfig(lens_time_constant_s=5.0)
    solver = make_solver(cfg, camera(16.0 * 1.03), catalogue())
    rng = np.random.default_rng(32)
    R0 = random_rotation(rng)
    rate = np.radians([0.3, -0.2, 0.4])
    seen = {}
    for i in range(300):
        t = i / 5.0
        f_true = f0.f_px * (1.001 if t >= 20.0 else 1.0)
        cam = dataclasses.replace(f0, f_px=f_true)
        stars, _ = synthetic_stars(cam, attitude_at(R0, rate, t), rng, noise_px=0.15)
        sol = solver.solve(stars, int(t * 1e9))
        assert sol.ok, (t, sol.reason)
        if i in (99, 299):
            seen[i] = (sol.lens, f_true)
        if i > 2:
            assert sol.mode == "tracking"
    for lens, f_true in seen.values():
        true_mm = f_true * 3.0 / 1000
        assert abs(lens.focal_length_mm - true_mm) < 5 * lens.sigma_focal_length_mm
        assert lens.sigma_focal_length_mm < 60e-6 * true_mm
        assert lens.drift_ppm == pytest.approx(1e6 * (true_mm / (16.0 * 1.03) - 1), abs=300)
    assert seen[299][0].frames == 300
