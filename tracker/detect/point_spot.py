"""Whether a faint spot is a point (a hot pixel, a particle's charge) rather than a star.

A star's light on the 3 x 3 pixels around its centre is the frame's PSF,
pixel-integrated, at the star's sub-pixel phase; a hot pixel's charge sits
in one pixel, and a particle's diffuses by about 0.45 px
(tracker.detect.star_width), neither blurred by the optics. On those nine
pixels the light S (background subtracted, ADU) is modelled as

    S = a P + bx dP/dx + by dP/dy + c D + noise,

P the pixel-integrated Gaussian of the frame's PSF sigma at the spot's
centre (unit flux), its derivatives by the centre (a centre off by a
fraction of a pixel, as a faint star's is, moves its light along them),
and D the part of a unit point (all its light in the pixel nearest the
centre) that none of the three can make: the point less its least-squares
projection on them. A star has c = 0; a point has c equal to its flux.

The statistic is z = D'S / sqrt(sum_i D_i^2 v_i), the least-squares c over
its standard deviation, with each pixel's variance v_i = noise^2 + g a P_i
(the background's and the star's own shot noise, g ADU^2 per ADU:
tracker.detect.significance's convention; a from the fit of P alone). D is
orthogonal to P and to the first-order effect of a centring error, so for a
star of the frame's PSF z is a standard normal whatever its flux, and a test
z > :data:`Z_STAR_LOSS` loses a star 1 time in 1000 (Gaussian noise). A
point of flux F reads z near F |D|^2 / sqrt(sum D^2 v): under a PSF of sigma
0.85 px a hot pixel at windowed SNR 5 reads about 6, a 0.45 px charge cloud
2-3 (less at a pixel's corner). Under sigma 0.6 px a hot pixel at SNR 5
reads 3.4: below the PSF's own charge width (tracker.detect.psf's
CHARGE_SIGMA_PX) a point and a star look alike and the test is not made.

The variances are measured on the frame's tested spots together
(:func:`pixel_noise_model`), not taken as the background's noise and 1
ADU^2 per ADU: a RAW8 OV2311 frame (its 10-bit ADC's top 8 bits) has
g = 0.12-0.26, and its near-noiseless integer sky reads a noise up to 1.5
times its pixels' spread (tracker.detect.background), so there the faint
stars' z spread 0.57, not 1, and the faint hot pixels that passed as stars
read 1.2-2.7 (held-out frames of tracker.bench.detect_data). The residual
of each tested spot's pixels from the fit of P and its derivatives has the
variance (1 - h_i)(s noise^2 + g a P_i), h_i the pixel's leverage in that
fit; s and g are the weighted least-squares fit of the squared residuals
on it (each a chi-square of one degree of freedom: weights 1 / its
variance^2, and each counted at most :data:`_RESIDUAL_CAP` times its
variance, so a point among the spots does not pull them up), taken at
their upper bounds :data:`_SCALE_SE` standard errors out and never above 1
and :data:`SHOT_ADU`; fewer than :data:`_SCALE_SPOTS` spots keep the
background's noise and 1 ADU^2 per ADU. Nine pixels a spot, six degrees
of freedom, measure g to 0.02-0.1 on the 40-200 faint spots of a held-out
frame (a single z per spot, one degree of freedom, left the upper bound of
g at 1 on most frames). A PSF that is no Gaussian (a Moffat's or an Airy
disc's core) adds residual light growing with the flux, which reads as more
shot noise: the test is then the more lenient.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.detect.significance import SHOT_ADU
from tracker.normal import pixel_fractions

__all__ = ["POINT_OFFSETS", "Z_STAR_LOSS", "pixel_noise_model", "point_significance"]

Z_STAR_LOSS = 3.09    # one-sided standard normal quantile of 0.1 %: a star's chance to fail
_RESIDUAL_CAP = 9.0   # a squared residual counts at most this many times its variance
_SCALE_SE = 3.0       # the noise model is taken this many standard errors above its fit
                      # (its approximations, Gaussian residuals of few-count pixels and
                      # the leverage, are not in them: at 2 a photon-counting frame's g
                      # read 0.83 against its true 1)
_SCALE_FLOOR = 0.01   # ... from a fit of s and g kept at least this (a variance's scale)
_SCALE_STEPS = 10     # reweighting steps of that fit at most (it settles in four or five)
_SCALE_SETTLED = 1e-3 # ... ending when neither s nor g moves by this fraction of itself
_SCALE_SPOTS = 20     # ... made on at least this many spots (120 residuals' degrees of
                      # freedom: fewer tell their own standard error too poorly)
_EDGES = np.array([-1.5, -0.5, 0.5, 1.5])   # the 3 x 3 pixels' edges about their centre
# (row, column) offsets of the 3 x 3 pixels from the central one, in ``light``'s order
POINT_OFFSETS = np.stack([a.ravel() for a in np.mgrid[-1:2, -1:2]], axis=1).astype(np.intp)


def _star_basis(phase_x: np.ndarray, phase_y: np.ndarray, sigma_px: float) -> np.ndarray:
    """(m, 9, 3): P, dP/dx, dP/dy on each spot's 3 x 3 (module docstring)."""
    m = len(phase_x)
    fx, dx = pixel_fractions(_EDGES[None, :] - np.asarray(phase_x)[:, None], sigma_px)
    fy, dy = pixel_fractions(_EDGES[None, :] - np.asarray(phase_y)[:, None], sigma_px)
    basis = np.empty((m, 9, 3))
    basis[:, :, 0] = (fy[:, :, None] * fx[:, None, :]).reshape(m, 9)
    basis[:, :, 1] = (fy[:, :, None] * dx[:, None, :]).reshape(m, 9)
    basis[:, :, 2] = (dy[:, :, None] * fx[:, None, :]).reshape(m, 9)
    return basis


def _symmetric_inverse(gram: np.ndarray) -> np.ndarray:
    """Inverses (m, 3, 3) of symmetric 3 x 3 matrices ``gram`` (m, 3, 3), by cross
    products of their rows over the determinant: no LAPACK call, whose BLAS threads
    would spin on the core the detector's own slab thread runs on."""
    a, b, c = gram[:, 0], gram[:, 1], gram[:, 2]
    rows = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=1)
    return rows / np.einsum("mk,mk->m", a, rows[:, 0])[:, None, None]


def pixel_noise_model(light: np.ndarray, phase_x: np.ndarray, phase_y: np.ndarray,
                      noise: np.ndarray, sigma_px: float) -> tuple[float, float]:
    """(s, g): each pixel's variance is s noise^2 + g (its star light), ADU^2, measured
    on the spots' residuals from the star's fit (module docstring); (1, SHOT_ADU) when
    they do not tell it better. Arguments as :func:`point_significance`'s."""
    if len(light) < _SCALE_SPOTS:
        return 1.0, SHOT_ADU
    basis = _star_basis(phase_x, phase_y, sigma_px)
    inverse = _symmetric_inverse(np.einsum("mik,mil->mkl", basis, basis))
    coef = np.einsum("mkl,mil,mi->mk", inverse, basis, light)
    residual = light - np.einsum("mik,mk->mi", basis, coef)
    kept = 1.0 - np.einsum("mik,mkl,mil->mi", basis, inverse, basis)    # 1 - leverage
    square = np.square(residual).ravel()
    background = (kept * np.square(noise)[:, None]).ravel()
    shot = (kept * np.maximum(coef[:, 0], 0.0)[:, None] * basis[:, :, 0]).ravel()
    # the normal equations' products, (3, n): background^2, background shot, shot^2
    products = np.stack([background * background, background * shot, shot * shot])
    scale, gain = 1.0, SHOT_ADU
    for _ in range(_SCALE_STEPS):
        variance = np.maximum(scale * background + gain * shot, 1e-12)
        weight = 1.0 / np.square(variance)
        bb, bs, ss = products @ weight
        if bb * ss - bs * bs <= 1e-12 * bb * ss:
            return 1.0, SHOT_ADU
        capped = weight * np.minimum(square, _RESIDUAL_CAP * variance)
        rb, rs = float(np.dot(capped, background)), float(np.dot(capped, shot))
        det = bb * ss - bs * bs
        last = (scale, gain)
        scale = max((ss * rb - bs * rs) / det, _SCALE_FLOOR)
        gain = max((bb * rs - bs * rb) / det, _SCALE_FLOOR)
        if abs(scale - last[0]) <= _SCALE_SETTLED * scale and (
                abs(gain - last[1]) <= _SCALE_SETTLED * gain):
            break
    # each squared residual's variance is 2 variance^2: the fit's covariance 2 normal^-1
    return (min(scale + _SCALE_SE * math.sqrt(2.0 * ss / det), 1.0),
            min(gain + _SCALE_SE * math.sqrt(2.0 * bb / det), SHOT_ADU))


def point_significance(light: np.ndarray, phase_x: np.ndarray, phase_y: np.ndarray,
                       noise: np.ndarray, sigma_px: float,
                       shot_adu: float = SHOT_ADU) -> np.ndarray:
    """z of each spot's point component (module docstring): (m,) float.

    ``light``: (m, 9) background-subtracted ADU of the 3 x 3 pixels around
    the pixel nearest each spot's centre, row-major; ``phase_x``,
    ``phase_y``: (m,) the centre's offset from that pixel's centre, px (-0.5
    .. 0.5); ``noise``: (m,) the pixel noise without the spot's light, ADU;
    ``sigma_px``: the frame's optical PSF sigma; ``shot_adu``: g, one for all or (m,).
    """
    basis = _star_basis(phase_x, phase_y, sigma_px)
    gram = np.einsum("mik,mil->mkl", basis, basis)
    # D: the central pixel's unit vector less its projection on the basis
    coef = np.linalg.solve(gram, basis[:, 4, :, None])[:, :, 0]
    d = -np.einsum("mik,mk->mi", basis, coef)
    d[:, 4] += 1.0
    p = basis[:, :, 0]
    flux = np.maximum(np.einsum("mi,mi->m", p, light) / np.einsum("mi,mi->m", p, p), 0.0)
    variance = np.square(noise)[:, None] + (shot_adu * flux)[:, None] * p
    spread = np.sqrt(np.einsum("mi,mi->m", d * d, variance))
    return np.einsum("mi,mi->m", d, light) / np.maximum(spread, 1e-12)

