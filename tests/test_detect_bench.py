"""Pieces of `tracker bench detect`: matching, scoring, peers in our pixel convention."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.bench.detect_data import _sensor_saturation, _sensor_variance
from tracker.bench.detect_peers import PEERS
from tracker.bench.detect_score import FrameTruth, Score, match
from tracker.config import SimConfig
from tracker.sim import render_points


def test_match_is_one_to_one_and_nearest_first():
    tx, ty = np.array([10.0, 20.0]), np.array([10.0, 10.0])
    dx, dy = np.array([10.3, 10.1, 20.0, 50.0]), np.array([10.0, 10.0, 11.9, 50.0])
    owner = match(tx, ty, dx, dy, radius=2.0)
    # 10.1 is nearer to star 0 than 10.3, so 10.3 is a duplicate (false); 50,50 is far
    assert owner.tolist() == [-1, 0, 1, -1]


def test_score_counts_recall_fdr_and_errors():
    def truth(match_px=2.0):
        return FrameTruth(np.array([10.0, 30.0, 50.0]), np.array([10.0, 10.0, 10.0]),
                          np.array([3.0, 4.5, 6.5]), np.array([30.0, 8.0, 2.0]),
                          np.array([True, True, False]), np.array([0.02, 0.1, np.nan]),
                          match_px=match_px)

    # a star of a wide PSF found 2.5 px from its truth: a poor centroid of that star
    # when the PSF's sigma is 3 px, a false detection when it is 1 px
    wide, narrow = Score(), Score()
    wide.add(truth(3.0), np.array([32.5]), np.array([10.0]), 1.0)
    narrow.add(truth(), np.array([32.5]), np.array([10.0]), 1.0)
    assert (wide.false, wide.found, narrow.false, narrow.found) == (0, 1, 1, 0)

    score = Score()
    score.add(truth(), np.array([10.03, 50.2, 90.0]), np.array([10.04, 10.0, 90.0]), 5.0)
    s = score.summary()
    assert s["detected"] == 3 and s["false"] == 1  # the faint star found is not false
    assert s["recall"] == pytest.approx(0.5)
    assert s["fdr"] == pytest.approx(1 / 3)
    assert s["rmse_px"] == pytest.approx(0.05)
    assert s["rmse_over_crb_snr20"] == pytest.approx(0.05 / 0.02)


def test_a_star_on_a_background_at_full_scale_is_not_detectable():
    """Two stars of equal light: one on the sky, one under light that takes its pixels past
    full scale (glare, lit ground). The second leaves no trace in the frame (every pixel
    around it reads full scale), so the recall does not count it; the first it does."""
    rng = np.random.default_rng(5)
    shape = (64, 128)
    light = np.zeros(shape)
    light[:, 64:] = 40000.0                       # far past full scale at the default gain
    frame = render_points(shape, np.array([32.0, 96.0]), np.array([32.0, 32.0]),
                          np.full(2, 20000.0), SimConfig(), rng, noise_model="realistic",
                          light_e=light)
    assert np.all(frame.image[24:41, 88:105] == 1023)
    truth = FrameTruth.from_frame(frame, "peak_snr >= 5", _sensor_variance, 1.0, 1.2,
                                  _sensor_saturation(10))
    assert truth.detectable.tolist() == [True, False]


@pytest.mark.parametrize("peer", sorted(PEERS))
def test_peer_positions_use_our_pixel_convention(peer):
    """A noise-free star at a known sub-pixel position: each peer, converted, within
    0.1 px (both centre a symmetric spot to far better; a half-pixel slip would fail)."""
    pytest.importorskip({"sep": "sep", "tetra3": "tetra3"}[peer])
    sim = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    xs, ys = np.array([40.3, 90.8]), np.array([60.6, 30.2])
    frame = render_points((120, 140), xs, ys, [20000.0, 20000.0], sim,
                          np.random.default_rng(0), noise_model="realistic")
    x, y = PEERS[peer](frame.image)
    d = np.hypot(xs[:, None] - np.asarray(x)[None], ys[:, None] - np.asarray(y)[None])
    assert d.min(axis=1).max() < 0.1


def test_aperture_flux_of_the_peers_sums_a_star_over_its_local_background():
    """sep and tetra3 give positions only; the lunar solves give them the flux of a 7x7 box
    less its border's median: within 15 % for a star of sigma 1.2 px on a sky of 100 ADU
    (the border still holds the star's wings, so the median takes some of its light:
    10 % measured; the same fraction for every star, which the solver's magnitude zero
    point absorbs)."""
    from tracker.bench.detect_solve import aperture_flux

    sim = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    frame = render_points((60, 60), [30.3], [29.6], [5000.0], sim, np.random.default_rng(3),
                          noise_model="none")
    image = frame.image.astype(np.float64) + 100.0
    expected = 5000.0 / frame.truth["noise"]["gain_e_per_adu"]
    got = aperture_flux(image, np.array([30.3]), np.array([29.6]))[0]
    assert 0.85 * expected < got <= expected


def _camera_rotation(axis: int, angle_rad: float) -> np.ndarray:
    """The camera turned by ``angle_rad`` about its own ``axis`` (0 = x, 2 = z)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = [k for k in range(3) if k != axis]
    rot = np.eye(3)
    rot[i, i] = rot[j, j] = c
    rot[i, j], rot[j, i] = -s, s
    return rot


@pytest.mark.parametrize("cross_arcsec, names_wrong_star, outcome", [
    (62.0, False, "solved"),    # within 3 px of an 8 mm lens (232 arcsec): seed 43's faint frame
    (62.0, True, "solved"),     # a mislabel inside the tolerances still gives the attitude
    (400.0, False, "off"),      # beyond the tolerances on right stars only
    (400.0, True, "false"),     # beyond them naming a wrong star: a misidentification
])
def test_a_lunar_solve_is_false_only_when_off_and_naming_a_wrong_star(cross_arcsec,
                                                                      names_wrong_star,
                                                                      outcome):
    from types import SimpleNamespace

    from tracker.attitude import matrix_from_radec_roll
    from tracker.bench.detect_solve import _outcome
    from tracker.camera import CameraModel
    from tracker.config import CameraConfig
    from tracker.detect import STAR_DTYPE

    camera = CameraModel.from_config(dataclasses.replace(CameraConfig(), focal_length_mm=8.0))
    rendered = np.zeros(4, [("x", float), ("y", float), ("hip", np.int32)])
    rendered["x"], rendered["y"] = [100.0, 400.0, 700.0, 1000.0], [200.0, 900.0, 500.0, 300.0]
    rendered["hip"] = [11, 22, 33, 44]
    stars = np.zeros(4, STAR_DTYPE)
    stars["x"], stars["y"] = rendered["x"] + 0.3, rendered["y"] - 0.2
    R_true = matrix_from_radec_roll(1.0, -0.5, 0.3)
    named = rendered["hip"].copy()
    if names_wrong_star:
        named[1] = 55
    solution = SimpleNamespace(ok=True, hip=named,
                               R=_camera_rotation(0, np.radians(cross_arcsec / 3600)) @ R_true)
    solver = SimpleNamespace(reset=lambda: None, solve=lambda s, t: solution)
    frame = SimpleNamespace(R=R_true, stars=rendered)
    assert _outcome(solver, stars, frame, camera) == outcome
