"""Lost-in-space identification on synthetic centroid lists (tests/identify_sim.py)."""

import dataclasses
import json
import math

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, same_star, synthetic_stars

from tracker.attitude import attitude_error, radec_roll_from_matrix
from tracker.config import IdentifyConfig
from tracker.identify import make_solver

ARCSEC = math.radians(1 / 3600)


@pytest.fixture(scope="module", params=[16.0, 8.0], ids=["16mm", "8mm"])
def lens(request):
    cam = camera(request.param)
    return cam, make_solver(IdentifyConfig(), cam, catalogue())


def test_random_attitudes_are_solved_with_correct_stars(lens):
    """40 random skies, 0.15 px noise, 2 false stars: every one solved, no wrong HIP.

    (Stars closer than 1.5 px are one spot; either component's HIP is right.)

    Tolerances: with ~0.15 px noise (5.8 arcsec at 16 mm, 11.6 at 8 mm) on
    tens of stars the boresight is good to a few arcsec; 15 arcsec cross and
    90 arcsec roll are > 5 sigma of the reported uncertainties.
    """
    cam, solver = lens
    rng = np.random.default_rng(11)
    for i in range(40):
        R = random_rotation(rng)
        stars, truth = synthetic_stars(cam, R, rng)
        solver.reset()
        sol = solver.solve(stars, i * 10**10)
        assert sol.ok, sol.reason
        assert sol.mode == "lost_in_space"
        cross, roll = attitude_error(sol.R, R)
        assert cross < 15 * ARCSEC
        assert abs(roll) < 90 * ARCSEC
        named = sol.hip != 0
        assert np.all(same_star(sol.hip[named], truth[named]))
        assert np.count_nonzero(named) >= 0.9 * np.count_nonzero(truth)
        assert sol.prob_false < 1e-7
        ra, dec, roll_rad = radec_roll_from_matrix(sol.R)
        assert sol.ra_deg == pytest.approx(math.degrees(ra), abs=1e-3)
        assert sol.roll_deg == pytest.approx(math.degrees(roll_rad), abs=1e-3)


def test_sparse_fields_of_five_to_seven_stars():
    """Only the 5-7 brightest stars plus one false star: at least 90 % solved, none wrong.

    (Measured with this seed: 56 of 60; 96 % over 300 frames, 100 % with 7
    stars. Five stars leave one beyond a four-star pattern as evidence.)
    """
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rng = np.random.default_rng(12)
    solved = 0
    trials = 60
    for i in range(trials):
        R = random_rotation(rng)
        stars, truth = synthetic_stars(cam, R, rng, keep_brightest=5 + i % 3, n_false=1)
        solver.reset()
        sol = solver.solve(stars, 0)
        if sol.ok:
            solved += 1
            named = sol.hip != 0
            assert np.all(same_star(sol.hip[named], truth[named]))
        else:
            assert sol.reason in ("no_match", "not_verified", "budget")
    assert solved >= 0.9 * trials


def test_solution_json_and_quaternion_convention(lens):
    cam, solver = lens
    rng = np.random.default_rng(13)
    R = random_rotation(rng)
    stars, _ = synthetic_stars(cam, R, rng)
    solver.reset()
    sol = solver.solve(stars, 0)
    record = sol.to_json()
    assert set(record) == {"q", "ra_deg", "dec_deg", "roll_deg", "matched", "sigma_arcsec",
                           "sigma_roll_arcsec", "mode", "prob_false", "focal_length_mm",
                           "sigma_focal_length_mm", "lens"}
    assert set(record["lens"]) == {"focal_length_mm", "sigma_focal_length_mm", "k1",
                                   "sigma_k1", "drift_ppm", "frames"}
    assert json.loads(json.dumps(record)) == record
    assert record["q"][0] >= 0
    assert abs(np.linalg.norm(record["q"]) - 1) < 1e-12
    assert record["matched"] == np.count_nonzero(sol.hip)
    assert set(sol.stages_ms) >= {"prepare", "lost_in_space", "refine"}


def test_reported_sigmas_track_the_observed_errors():
    """RMS reported sigma within a factor 1.5 of the RMS error over 60 frames (16 mm).

    60 frames give the RMS to about +-10 % (cross, 2 degrees of freedom each)
    and +-13 % (roll), well inside the factor 1.5 under test.
    """
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rng = np.random.default_rng(14)
    obs, rep = [], []
    for _ in range(60):
        R = random_rotation(rng)
        stars, _ = synthetic_stars(cam, R, rng, noise_px=0.3)
        solver.reset()
        sol = solver.solve(stars, 0)
        assert sol.ok
        obs.append(attitude_error(sol.R, R))
        rep.append((sol.sigma_cross_arcsec * ARCSEC, sol.sigma_roll_arcsec * ARCSEC))
    obs, rep = np.array(obs), np.array(rep)
    for k in (0, 1):
        ratio = np.sqrt(np.mean(rep[:, k] ** 2)) / np.sqrt(np.mean(obs[:, k] ** 2))
        assert 1 / 1.5 < ratio < 1.5


def test_solution_is_reported_at_the_image_centre_with_an_offset_principal_point():
    """RA/Dec/roll belong to the image centre, not the principal point (docs/conventions.md)."""
    cam = camera(16.0, cx=760.0, cy=700.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rng = np.random.default_rng(15)
    R = random_rotation(rng)
    stars, _ = synthetic_stars(cam, R, rng)
    sol = solver.solve(stars, 0)
    assert sol.ok
    centre = cam.pixel_to_vector(np.array([(cam.width - 1) / 2, (cam.height - 1) / 2]))
    v = sol.R.T @ centre
    ra = math.degrees(math.atan2(v[1], v[0])) % 360
    dec = math.degrees(math.asin(v[2]))
    assert sol.ra_deg == pytest.approx(ra, abs=2e-4)
    assert sol.dec_deg == pytest.approx(dec, abs=2e-4)


@pytest.mark.parametrize("error", [-0.05, 0.05], ids=["5% short", "5% long"])
def test_a_focal_length_five_percent_off_is_found(error):
    """Configured focal length 5 % off: every frame solved, the focal length found.

    With tens of stars and 0.15 px noise the fitted focal length is good to
    about 0.01 % (1 sigma, as reported); 0.1 % is the requirement, and the
    reported sigma must cover the error at 4 sigma.
    """
    true_cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), camera(16.0 * (1 + error)), catalogue())
    rng = np.random.default_rng(16)
    for _ in range(20):
        R = random_rotation(rng)
        stars, truth = synthetic_stars(true_cam, R, rng)
        solver.reset()
        solver.lens.reset()
        sol = solver.solve(stars, 0)
        assert sol.ok, sol.reason
        assert attitude_error(sol.R, R)[0] < 15 * ARCSEC
        assert sol.matched >= 15
        assert sol.focal_length_mm == pytest.approx(16.0, rel=1e-3)
        assert abs(sol.focal_length_mm - 16.0) < 4 * sol.sigma_focal_length_mm
        assert sol.lens.drift_ppm == pytest.approx(1e6 * (1 / (1 + error) - 1), rel=0.01)


def test_a_focal_length_far_off_fails_and_names_the_fix():
    """20 % off, outside the +-6 % prior: no attitude, and the reason says what to set."""
    true_cam = camera(19.2)
    rng = np.random.default_rng(17)
    stars, _ = synthetic_stars(true_cam, random_rotation(rng), rng)
    solver = make_solver(IdentifyConfig(), camera(16.0), catalogue())
    sol = solver.solve(stars, 0)
    assert not sol.ok and sol.R is None
    assert sol.reason.startswith("focal_length: the stars fit a focal length of ")
    named = float(sol.reason.split("focal length of ")[1].split(" mm")[0])
    assert named == pytest.approx(19.2, rel=1e-3)
    assert "set camera.focal_length_mm: " in sol.reason and "tracker calibrate" in sol.reason
    quiet = make_solver(dataclasses.replace(IdentifyConfig(), focal_search=0.0), camera(16.0),
                        catalogue())
    assert quiet.solve(stars, 0).reason in ("no_match", "not_verified", "budget")
