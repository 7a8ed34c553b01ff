"""PSF shapes rendered by supersampling (tracker.sim.psf_shapes): checked against theory
and against the exact erf integration of tracker.sim.psf."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker.sim.psf import psf_stamps
from tracker.sim.psf_shapes import FWHM_PER_SIGMA, PsfShape, bessel_j1, shaped_stamps


def test_bessel_j1_matches_its_integral_representation():
    """J1(x) = (1/pi) int_0^pi cos(t - x sin t) dt; A&S 9.4.4/9.4.6 claim < 1e-7."""
    x = np.linspace(0.0, 30.0, 601)
    tau = np.linspace(0.0, np.pi, 40001)
    reference = np.trapz(np.cos(tau[None, :] - x[:, None] * np.sin(tau[None, :])), tau,
                         axis=1) / np.pi
    assert np.max(np.abs(bessel_j1(x) - reference)) < 2e-7


@pytest.mark.parametrize("sigma", [0.6, 1.2, 2.5])
def test_supersampled_gaussian_equals_the_exact_pixel_integral(sigma):
    """Two code paths, one PSF: they agree to the midpoint rule's error.

    At least 8 sample points per sigma along each axis: the rule's error is
    about (1/8)^2 / 24 of the profile's curvature, under 5e-4 of the star's
    light in any pixel (2e-4 measured at sigma 0.6, the sharpest).
    """
    xs, ys = np.array([40.3, 70.0]), np.array([50.7, 71.5])
    exact = psf_stamps(xs, ys, sigma)
    sampled = shaped_stamps(xs, ys, PsfShape("gaussian", sigma, ellipticity=1e-12))
    canvas = [np.zeros((140, 140)), np.zeros((140, 140))]
    for out, st in zip(canvas, (exact, sampled), strict=True):
        for i in range(2):
            ky, kx = st.values[i].shape
            out[st.y0[i]:st.y0[i] + ky, st.x0[i]:st.x0[i] + kx] += st.values[i]
    assert np.max(np.abs(canvas[0] - canvas[1])) < 5e-4
    assert canvas[1].sum() == pytest.approx(2.0, abs=1e-6)


@pytest.mark.parametrize("kind", ["gaussian", "moffat", "airy"])
def test_each_shape_has_the_fwhm_of_its_sigma(kind):
    """FWHM = 2 sqrt(2 ln 2) sigma whatever the family (the detector's sigma means that)."""
    psf = PsfShape(kind, 1.3, beta=2.5)
    r = np.linspace(0.0, 4.0 * psf.sigma_px, 40001)
    profile = psf.density(r, np.zeros_like(r))
    half = r[np.argmax(profile < 0.5 * profile[0])]
    assert 2.0 * half == pytest.approx(FWHM_PER_SIGMA * psf.sigma_px, rel=1e-3)


@pytest.mark.parametrize("kind", ["gaussian", "moffat", "airy"])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.5, 0.5), (0.3, -0.2)])
def test_symmetric_shapes_are_centred_on_the_star(kind, offset):
    """Every family, elliptical and rotated, is point-symmetric: its light centroid is the
    star's position up to the stamp's cut (the box reaches half a pixel further on one side
    of a star off a pixel centre; the Airy pattern's r^-3 wings, 3-4 % of its light beyond
    8 sigma, move the centroid by 0.01 px) and the supersampling (< 1e-3 px)."""
    psf = PsfShape(kind, 1.0, beta=3.0, ellipticity=0.15, angle_rad=0.6)
    x, y = 30.0 + offset[0], 31.0 + offset[1]
    st = shaped_stamps([x], [y], psf)
    v = st.values[0]
    rows, cols = np.indices(v.shape)
    assert (v * (cols + st.x0[0])).sum() / v.sum() == pytest.approx(x, abs=0.02)
    assert (v * (rows + st.y0[0])).sum() / v.sum() == pytest.approx(y, abs=0.02)


def test_ellipticity_is_that_of_the_second_moments():
    """Axes sqrt(1 +- e) times sigma: (Mxx - Myy, 2 Mxy) / (Mxx + Myy) has length e."""
    psf = PsfShape("gaussian", 2.0, ellipticity=0.2, angle_rad=math.radians(30.0))
    st = shaped_stamps([50.0], [50.0], psf)
    v = st.values[0]
    rows, cols = np.indices(v.shape)
    dx, dy = cols + st.x0[0] - 50.0, rows + st.y0[0] - 50.0
    mxx, myy, mxy = ((v * dx * dx).sum(), (v * dy * dy).sum(), (v * dx * dy).sum())
    mxx, myy = mxx - 1.0 / 12.0, myy - 1.0 / 12.0                # the pixel's own width
    assert math.hypot(mxx - myy, 2.0 * mxy) / (mxx + myy) == pytest.approx(0.2, abs=0.005)
    assert 0.5 * math.atan2(2.0 * mxy, mxx - myy) == pytest.approx(math.radians(30.0),
                                                                  abs=0.01)


def test_bad_shapes_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="unknown PSF shape"):
        PsfShape("square", 1.0)
    with pytest.raises(ValueError, match="ellipticity"):
        PsfShape("gaussian", 1.0, ellipticity=1.0)
    with pytest.raises(ValueError, match="beta"):
        PsfShape("moffat", 1.0, beta=1.0)
