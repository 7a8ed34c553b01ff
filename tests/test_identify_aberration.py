"""The solver reports the ICRS attitude from aberrated stars (issue 14).

Exact centroids of the apparent directions (tracker.astrometry.aberration:
the Earth's velocity at a date plus an observer's) through the camera model:
with the observer context the attitude is the true (ICRS) one to numerical
precision, lost in space and tracking alike; without it, it is off by the
aberration of the field's centre, as the formula says.
"""

import math

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation

from tracker.astrometry.aberration import aberrate
from tracker.astrometry.observer import Observer, TimeSource
from tracker.astrometry.timescale import tai_ns_from_utc_iso
from tracker.attitude import attitude_error
from tracker.config import IdentifyConfig
from tracker.detect import STAR_DTYPE
from tracker.identify import make_solver
from tracker.sim.sequence import attitude_at

_ARCSEC = math.degrees(1.0) * 3600.0
T = tai_ns_from_utc_iso("2026-06-21T03:00:00Z")


def _stars(cam, R, beta, mag_limit=6.5):
    """Exact pixel centroids of the catalogue's stars seen at attitude R moving at beta."""
    cat = catalogue()
    seen = cat.vectors if beta is None else aberrate(cat.vectors, beta)
    v = seen @ R.T
    front = v[:, 2] > 0.5
    pix = cam.vector_to_pixel(v[front])
    keep = cam.in_frame(pix, 1.0) & (cat.mag[front] <= mag_limit)
    stars = np.zeros(int(np.count_nonzero(keep)), STAR_DTYPE)
    stars["x"], stars["y"] = pix[keep, 0], pix[keep, 1]
    stars["flux"] = 10 ** (-0.4 * (cat.mag[front][keep] - 10.0))
    return stars


@pytest.mark.parametrize("velocity", [None, (5.3, -4.1, 3.2)], ids=["earth", "leo"])
@pytest.mark.parametrize("focal_mm", [8.0, 16.0])
def test_lost_in_space_gives_the_icrs_attitude_with_the_observer(focal_mm, velocity):
    cam = camera(focal_mm)
    # one solver each: the lens filter of the one without the observer takes
    # aberration's scale (|beta| cos(angle to the apex), up to 1e-4) for a focal length
    solver, blind = (make_solver(IdentifyConfig(), cam, catalogue()) for _ in range(2))
    observer = Observer(T, velocity, TimeSource.RECORD)
    beta = observer.beta()
    rng = np.random.default_rng(int(focal_mm) + (velocity is not None))
    for _ in range(4):
        R = random_rotation(rng)
        stars = _stars(cam, R, beta)
        solver.reset()
        corrected = solver.solve(stars, 0, observer)
        blind.reset(lens=True)         # this frame's scale alone
        apparent = blind.solve(stars, 0)
        assert corrected.ok and apparent.ok
        cross, roll = attitude_error(corrected.R, R)
        assert cross * _ARCSEC < 0.005 and abs(roll) * _ARCSEC < 0.05
        # the lens: exact with the observer; without, aberration's scale 1 - b.beta
        # (b the boresight) is taken for a focal length by issue 11's lens fit (most
        # of it: k1 takes a share, which depends on where the stars are)
        assert corrected.focal_length_mm == pytest.approx(focal_mm, rel=1e-9)
        assert apparent.focal_length_mm / focal_mm - 1 == pytest.approx(-(R[2] @ beta),
                                                                        rel=0.25)
        # uncorrected: the boresight is about where aberration puts it; the field's
        # second-order terms (|beta| x the field's mean squared radius) add a few %
        boresight = R[2]
        shift = math.acos(min(1.0, float(aberrate(boresight, beta) @ boresight)))
        cross, _ = attitude_error(apparent.R, R)
        assert cross == pytest.approx(shift, rel=0.1)


def test_tracking_predicts_and_solves_in_apparent_directions():
    """A slew at 0.5 deg/s, 10 fps: every tracked frame's attitude is the ICRS one."""
    cam = camera(16.0)
    solver = make_solver(IdentifyConfig(), cam, catalogue())
    rng = np.random.default_rng(7)
    R0 = random_rotation(rng)
    rate = np.radians([0.3, -0.35, 0.1])
    modes = []
    for i in range(12):
        t_ns = i * 100_000_000
        observer = Observer(T + t_ns, (-6.0, 1.5, 4.4), TimeSource.TIME_SYNC)
        R = attitude_at(R0, rate, t_ns / 1e9)
        sol = solver.solve(_stars(cam, R, observer.beta()), t_ns, observer)
        assert sol.ok
        modes.append(sol.mode)
        cross, roll = attitude_error(sol.R, R)
        assert cross * _ARCSEC < 0.005 and abs(roll) * _ARCSEC < 0.05
        if sol.rate_rad_s is not None:
            np.testing.assert_allclose(sol.rate_rad_s, rate, atol=1e-7)
    assert modes[0] == "lost_in_space" and set(modes[1:]) == {"tracking"}
