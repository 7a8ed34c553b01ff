"""The simulator's sky: catalogue projection, attitudes, slews, determinism."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from tracker.attitude import matrix_from_radec_roll, quat_from_matrix, radec_to_vector
from tracker.catalogue import load_catalogue
from tracker.config import CameraConfig, SimConfig
from tracker.sim import random_attitude, render_sequence, render_sky

CAMERA = CameraConfig()
F_PX = CAMERA.focal_length_mm * 1000.0 / CAMERA.pixel_size_um


def _one_star_catalogue(ra, dec, mag=3.0):
    return SimpleNamespace(vectors=radec_to_vector(np.array([ra]), np.array([dec])),
                           mag=np.array([mag], np.float32), hip=np.array([7], np.int32),
                           epoch_year=2025.0)


def _window_centroid(light, x, y, half=5):
    r, c = int(round(y)), int(round(x))
    win = light[r - half:r + half + 1, c - half:c + half + 1].astype(np.float64)
    rows, cols = np.mgrid[r - half:r + half + 1, c - half:c + half + 1]
    return (win * cols).sum() / win.sum(), (win * rows).sum() / win.sum()


def test_vega_lands_where_the_pinhole_and_distortion_say():
    cat = load_catalogue(epoch_year=2025.0)
    vega = int(np.flatnonzero(cat.hip == 91262)[0])
    camera = dataclasses.replace(CAMERA, k1=0.05)
    # Boresight 2 deg south of Vega on its meridian, roll 0 (north = image up): Vega sits
    # straight above the centre at t = tan(2 deg), distorted by (1 + k1 t^2).
    R = matrix_from_radec_roll(cat.ra[vega], cat.dec[vega] - np.radians(2.0), 0.0)
    t = np.tan(np.radians(2.0))
    want_x, want_y = 799.5, 649.5 - F_PX * t * (1.0 + 0.05 * t * t)
    frame = render_sky(camera, cat, R, SimConfig(noise_model="none", exposure_ms=5.0),
                       np.random.default_rng(0))
    row = frame.stars[frame.stars["hip"] == 91262][0]
    assert row["x"] == pytest.approx(want_x, abs=1e-6)
    assert row["y"] == pytest.approx(want_y, abs=1e-6)
    # The image shows it there: noiseless light centroid (neighbours are > 20 px away;
    # 0.02 px allows for their wings) and the brightest ADC pixel.
    cx, cy = _window_centroid(frame.signal_e, want_x, want_y)
    assert (cx, cy) == (pytest.approx(want_x, abs=0.02), pytest.approx(want_y, abs=0.02))
    near = frame.image[int(want_y) - 3:int(want_y) + 4, int(want_x) - 3:int(want_x) + 4]
    peak_r, peak_c = np.unravel_index(np.argmax(near), near.shape)
    assert abs(int(want_y) - 3 + peak_r - want_y) <= 1 and abs(int(want_x) - 3 + peak_c
                                                               - want_x) <= 1
    truth = frame.truth
    assert truth["camera"]["k1"] == 0.05 and truth["camera"]["f_px"] == pytest.approx(F_PX)
    assert truth["q"] == pytest.approx(list(quat_from_matrix(R)))
    assert truth["dec_deg"] == pytest.approx(np.degrees(cat.dec[vega]) - 2.0)
    assert truth["roll_deg"] == pytest.approx(0.0, abs=1e-9)
    assert truth["epoch_year"] == 2025.0 and truth["rate_deg_s"] is None


def test_every_star_that_reaches_the_frame_is_rendered():
    cat = load_catalogue(epoch_year=2025.0)
    R = random_attitude(np.random.default_rng(11))
    frame = render_sky(CAMERA, cat, R, SimConfig(), np.random.default_rng(1))
    v_cam = cat.vectors @ R.T
    in_front = v_cam[:, 2] > 0
    pix = np.full((len(cat), 2), np.nan)
    pix[in_front] = v_cam[in_front, :2] / v_cam[in_front, 2:] * F_PX + [799.5, 649.5]
    inside = in_front & (np.abs(pix[:, 0] - 799.5) <= 800) & (np.abs(pix[:, 1] - 649.5) <= 650)
    assert set(cat.hip[inside]) == set(frame.stars["hip"][frame.stars["in_frame"]])
    assert len(frame.stars) == len(frame.truth["stars"]) >= inside.sum()


def test_same_seed_same_bytes_other_seed_other_bytes():
    cat = _one_star_catalogue(1.0, 0.3)
    R = matrix_from_radec_roll(1.0, 0.3, 0.5)
    a = render_sky(CAMERA, cat, R, SimConfig(), np.random.default_rng(5))
    b = render_sky(CAMERA, cat, R, SimConfig(), np.random.default_rng(5))
    c = render_sky(CAMERA, cat, R, SimConfig(), np.random.default_rng(6))
    assert a.image.tobytes() == b.image.tobytes() and a.truth == b.truth
    assert a.image.tobytes() != c.image.tobytes()


def test_slew_moves_stars_by_rate_times_dt():
    rng = np.random.default_rng(2)
    cat = load_catalogue(epoch_year=2025.0, mag_limit=6.0)
    R0 = matrix_from_radec_roll(np.radians(83.8), np.radians(-5.4), 0.0)
    cfg = SimConfig(noise_model="none", smear=False)
    f0, f1 = render_sequence(CAMERA, cat, R0, cfg, rng, 2, fps=10.0, rate_deg_s=(0, 0.5, 0))
    theta = np.radians(0.05)  # 0.5 deg/s * 0.1 s about the camera +y axis
    assert f1.truth["t_s"] == pytest.approx(0.1) and f1.truth["rate_deg_s"] == [0, 0.5, 0]
    common = np.intersect1d(f0.stars["hip"][f0.stars["in_frame"]],
                            f1.stars["hip"][f1.stars["in_frame"]])
    assert len(common) > 5
    for hip in common:
        s0 = f0.stars[f0.stars["hip"] == hip][0]
        s1 = f1.stars[f1.stars["hip"] == hip][0]
        # The camera turns by +theta about +y, so a direction's normalised coordinates
        # become u' = (u cos - sin) / (u sin + cos), v' = v / (u sin + cos).
        u, v = (s0["x"] - 799.5) / F_PX, (s0["y"] - 649.5) / F_PX
        den = u * np.sin(theta) + np.cos(theta)
        assert s1["x"] == pytest.approx(799.5 + F_PX * (u * np.cos(theta) - np.sin(theta)) / den,
                                        abs=1e-6)
        assert s1["y"] == pytest.approx(649.5 + F_PX * v / den, abs=1e-6)
        # Near the centre that is a shift of -f * rate * dt in x (4.65 px).
        if abs(u) < 0.02 and abs(v) < 0.02:
            assert s1["x"] - s0["x"] == pytest.approx(-F_PX * theta, rel=2e-3)


def test_smear_stretches_the_star_along_the_motion():
    R = matrix_from_radec_roll(2.0, 0.1, 0.0)
    cat = _one_star_catalogue(2.0, 0.1, mag=2.0)
    cfg = SimConfig(noise_model="none", psf_sigma_px=1.2)
    frame = render_sky(CAMERA, cat, R, cfg, np.random.default_rng(0), rate_deg_s=(0, 2.0, 0))
    light = frame.signal_e.astype(np.float64)
    rows, cols = np.indices(light.shape)
    mx, my = (light * cols).sum() / light.sum(), (light * rows).sum() / light.sum()
    var_x = (light * (cols - mx) ** 2).sum() / light.sum()
    var_y = (light * (rows - my) ** 2).sum() / light.sum()
    length = F_PX * np.radians(2.0) * 0.1  # 18.6 px travelled during the 100 ms exposure
    # Pixel sampling adds 1/12 px^2 to sigma^2 on both axes; a uniform streak adds L^2/12
    # along it (sub-sampled in steps <= sigma/2: at most 7 % more), nothing across it.
    assert var_x == pytest.approx(1.44 + 1 / 12 + length ** 2 / 12, rel=0.1)
    assert var_y == pytest.approx(1.44 + 1 / 12, rel=1e-4)
    assert (mx, my) == (pytest.approx(799.5, abs=0.01), pytest.approx(649.5, abs=0.01))
    assert frame.stars["x"][0] == pytest.approx(799.5, abs=1e-6)


def test_random_attitudes_are_rotations_spread_over_so3():
    rng = np.random.default_rng(0)
    Rs = np.array([random_attitude(rng) for _ in range(4000)])
    assert np.allclose(Rs @ Rs.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(Rs), 1.0)
    # Haar measure: E[R] = 0; each entry has std 1/sqrt(3), so the mean of 4000 has
    # std 0.009 and 0.05 is > 5 sigma. Boresights are uniform on the sphere: E[z^2] = 1/3.
    assert np.abs(Rs.mean(axis=0)).max() < 0.05
    assert np.mean(Rs[:, 2, 2] ** 2) == pytest.approx(1 / 3, abs=0.03)


def test_bad_attitude_and_rate_are_refused():
    cat = _one_star_catalogue(0.0, 0.0)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="R must be a 3x3 rotation matrix"):
        render_sky(CAMERA, cat, np.eye(3) * 2, SimConfig(), rng)
    with pytest.raises(ValueError, match="rate_deg_s must be three finite numbers"):
        render_sky(CAMERA, cat, np.eye(3), SimConfig(), rng, rate_deg_s=(1.0, 2.0))
    with pytest.raises(TypeError, match="camera must be a CameraConfig or CameraModel"):
        render_sky("ov2311", cat, np.eye(3), SimConfig(), rng)


def test_aberration_moves_a_star_toward_the_apex_by_beta_sin_theta():
    """With an absolute time, a star at 90 deg from the Earth's apex is drawn arcsin(v/c) off."""
    from tracker.astrometry.aberration import observer_beta
    from tracker.astrometry.timescale import tai_ns_from_utc_iso

    t = tai_ns_from_utc_iso("2026-03-20T00:00:00Z")
    leo = (3.0, -5.0, 4.0)
    beta = observer_beta(t, leo)
    apex = beta / np.linalg.norm(beta)
    star = np.cross(apex, [0.0, 0.0, 1.0])
    star /= np.linalg.norm(star)
    cat = SimpleNamespace(vectors=star[None, :], mag=np.array([3.0], np.float32),
                          hip=np.array([7], np.int32), epoch_year=2026.2)
    ra, dec = np.arctan2(star[1], star[0]), np.arcsin(star[2])
    R = matrix_from_radec_roll(ra, dec, 0.0)
    cfg = SimConfig(noise_model="none", exposure_ms=5.0)
    still = render_sky(CAMERA, cat, R, cfg, np.random.default_rng(0))
    moving = render_sky(CAMERA, cat, R, cfg, np.random.default_rng(0), t_tai_ns=t,
                        observer_velocity_km_s=leo)
    shift_px = np.hypot(moving.stars["x"][0] - still.stars["x"][0],
                        moving.stars["y"][0] - still.stars["y"][0])
    assert shift_px == pytest.approx(F_PX * np.tan(np.arcsin(np.linalg.norm(beta))), rel=1e-6)
    toward = (R @ apex)[:2]      # the apex's direction in the image plane
    step = np.array([moving.stars["x"][0] - still.stars["x"][0],
                     moving.stars["y"][0] - still.stars["y"][0]])
    assert step @ toward > 0.99 * np.linalg.norm(step) * np.linalg.norm(toward)
    assert moving.truth["utc"] == "2026-03-20T00:00:00.000000000Z"
    assert moving.truth["observer_velocity_km_s"] == list(leo)
