"""Issue 10, item 8: no angular rate across a time gap longer than track_max_gap_s.

A 0.5 deg/s slew observed again one hour later is back where it started
(1800 deg = 5 turns): a rate averaged over the gap reads 0 deg/s. The first
solve after the gap must report no rate (RATE_VALID clear), and the next one
a rate from the two frames after the gap only.
"""

import math

import numpy as np
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.attitude import matrix_from_rotation_vector
from tracker.config import IdentifyConfig
from tracker.identify import make_solver


def test_first_solve_after_a_long_gap_has_no_rate_and_the_next_one_is_right():
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rate = np.array([0.0, math.radians(0.5), 0.0])
    rng = np.random.default_rng(41)
    R0 = random_rotation(rng)

    def solve_at(t_s):
        R = matrix_from_rotation_vector(-rate * t_s) @ R0
        stars, _ = synthetic_stars(cam, R, rng)
        sol = solver.solve(stars, int(round(t_s * 1e9)))
        assert sol.ok, sol.reason
        return sol

    def assert_rate(sol):
        # tolerances as in test_identify_tracking: > 4 sigma of a rate from two
        # solutions 0.1 s apart (tilt ~2 arcsec, roll ~10 arcsec)
        assert np.allclose(sol.rate_rad_s[:2], rate[:2], atol=3e-4)
        assert abs(sol.rate_rad_s[2] - rate[2]) < 1.5e-3

    solve_at(0.0)
    assert_rate(solve_at(0.1))
    assert solve_at(3600.1).rate_rad_s is None
    assert_rate(solve_at(3600.2))
