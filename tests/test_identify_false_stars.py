"""Lost in space with bright false stars the detector flagged (issue 12).

On the lunar surface particle hits saturating on glare, glare and crescent
fragments and sources cut by the frame's edge rank among the brightest
sources. The detector flags most of them (saturated, elongated, edge);
lost in space draws its patterns from the clean stars first
(tracker.identify.lost.clean_first), so they cost no pattern. Each test
also solves the same list with the flags cleared (brightness order, as
before): it must fail, or the test would not show anything.
"""

import math

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, same_star, synthetic_stars

from tracker.attitude import attitude_error
from tracker.config import IdentifyConfig
from tracker.detect.result import StarFlag
from tracker.identify import make_solver
from tracker.identify.lost import DOUBTFUL, clean_first

ARCSEC = math.radians(1 / 3600)
_KINDS = (StarFlag.SATURATED, StarFlag.ELONGATED, StarFlag.EDGE,
          StarFlag.SATURATED | StarFlag.BLENDED)


def _with_false(cam, R, rng, ranks):
    """Synthetic stars (no unflagged false ones) with flagged false stars inserted at the
    brightness ``ranks`` (0 = brightest); returns (stars sorted brightest first, HIP)."""
    stars, hip = synthetic_stars(cam, R, rng, n_false=0)
    order = np.argsort(-stars["flux"], kind="stable")
    stars, hip = stars[order], hip[order]
    n = len(stars) + len(ranks)
    real = np.setdiff1d(np.arange(n), ranks)
    out = np.zeros(n, stars.dtype)
    truth = np.zeros(n, hip.dtype)
    out[real], truth[real] = stars, hip
    out["x"][ranks] = rng.uniform(0, cam.width - 1, len(ranks))
    out["y"][ranks] = rng.uniform(0, cam.height - 1, len(ranks))
    out["flags"][ranks] = [_KINDS[i % len(_KINDS)] for i in range(len(ranks))]
    # each false star a little brighter than the star after it: the real fluxes kept
    below = 0.0
    for i in range(n - 1, -1, -1):
        if truth[i] == 0:
            out["flux"][i] = 1.05 * below
        below = out["flux"][i]
    return out, truth


def _check(sol, R, truth):
    assert sol.ok, sol.reason
    cross, roll = attitude_error(sol.R, R)
    assert cross < 20 * ARCSEC and abs(roll) < 120 * ARCSEC
    named = sol.hip != 0
    assert np.all(same_star(sol.hip[named], truth[named]))   # no false star named


def _cleared(stars):
    out = stars.copy()
    out["flags"] = 0
    return out


@pytest.mark.parametrize("focal_mm", [16.0, 8.0])
def test_nine_flagged_false_stars_ahead_of_every_real_one(focal_mm):
    """The 12 brightest hold 3 real stars: brightness order has no pattern of four real
    ones to try; drawn from the clean stars, every frame solves with the right stars."""
    cam = camera(focal_mm)
    solver = make_solver(IdentifyConfig(focal_search=0.0), cam, catalogue())
    rng = np.random.default_rng(12)
    ranks = np.array([0, 1, 2, 4, 5, 6, 8, 9, 10])
    for _ in range(6):
        R = random_rotation(rng)
        stars, truth = _with_false(cam, R, rng, ranks)
        assert np.count_nonzero(truth[:12]) == 3
        solver.reset()
        _check(solver.solve(stars, 0), R, truth)
        solver.reset()
        assert not solver.solve(_cleared(stars), 0).ok


def test_three_flagged_false_stars_among_six_within_a_small_budget():
    """False stars at ranks 0, 2 and 4, ten patterns allowed: brightness order spends them
    all on patterns holding a false star ("budget"); clean stars first solve at once."""
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(focal_search=0.0, max_patterns=10), cam, catalogue())
    rng = np.random.default_rng(3)
    for _ in range(10):
        R = random_rotation(rng)
        stars, truth = _with_false(cam, R, rng, np.array([0, 2, 4]))
        solver.reset()
        sol = solver.solve(stars, 0)
        _check(sol, R, truth)
        solver.reset()
        old = solver.solve(_cleared(stars), 0)
        assert (old.ok, old.reason) == (False, "budget")


def test_a_flagged_real_star_is_still_matched():
    """The brightest real star saturated: not a pattern star first, still named."""
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(focal_search=0.0), cam, catalogue())
    rng = np.random.default_rng(4)
    R = random_rotation(rng)
    stars, truth = synthetic_stars(cam, R, rng, n_false=0)
    first = int(np.argmax(stars["flux"]))
    stars["flags"][first] = StarFlag.SATURATED
    sol = solver.solve(stars, 0)
    _check(sol, R, truth)
    assert sol.hip[first] == truth[first]


def test_clean_first_takes_clean_stars_first_and_fills_with_doubtful_ones():
    flags = np.array([StarFlag.SATURATED, 0, StarFlag.EDGE, 0, StarFlag.BLENDED, 0,
                      StarFlag.ELONGATED], dtype=np.uint8)
    np.testing.assert_array_equal(clean_first(7, 4, flags), [1, 3, 4, 5])
    np.testing.assert_array_equal(clean_first(7, 6, flags), [1, 3, 4, 5, 0, 2])
    np.testing.assert_array_equal(clean_first(5, 12, flags), [1, 3, 4, 0, 2])
    np.testing.assert_array_equal(clean_first(7, 5, None), np.arange(5))
    assert not StarFlag.BLENDED & DOUBTFUL


def test_verification_tests_the_clean_stars_first():
    """36 flagged false stars at ranks 4-39: the 40 brightest (identify.verify_stars)
    hold four real stars, too few to verify any pattern; the 40 clean-first hold them all.
    """
    cam = camera(8.0)
    solver = make_solver(IdentifyConfig(focal_search=0.0), cam, catalogue())
    rng = np.random.default_rng(7)
    for _ in range(4):
        R = random_rotation(rng)
        stars, truth = _with_false(cam, R, rng, np.arange(4, 40))
        assert np.count_nonzero(truth[:40]) == 4
        solver.reset()
        _check(solver.solve(stars, 0), R, truth)
        solver.reset()
        assert not solver.solve(_cleared(stars), 0).ok
