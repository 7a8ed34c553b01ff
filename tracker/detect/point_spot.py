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
"""

from __future__ import annotations

import numpy as np

from tracker.detect.significance import SHOT_ADU
from tracker.normal import pixel_fractions

__all__ = ["POINT_OFFSETS", "Z_STAR_LOSS", "point_significance"]

Z_STAR_LOSS = 3.09    # one-sided standard normal quantile of 0.1 %: a star's chance to fail
_EDGES = np.array([-1.5, -0.5, 0.5, 1.5])   # the 3 x 3 pixels' edges about their centre
# (row, column) offsets of the 3 x 3 pixels from the central one, in ``light``'s order
POINT_OFFSETS = np.stack([a.ravel() for a in np.mgrid[-1:2, -1:2]], axis=1).astype(np.intp)


def point_significance(light: np.ndarray, phase_x: np.ndarray, phase_y: np.ndarray,
                       noise: np.ndarray, sigma_px: float,
                       shot_adu: float = SHOT_ADU) -> np.ndarray:
    """z of each spot's point component (module docstring): (m,) float.

    ``light``: (m, 9) background-subtracted ADU of the 3 x 3 pixels around
    the pixel nearest each spot's centre, row-major; ``phase_x``,
    ``phase_y``: (m,) the centre's offset from that pixel's centre, px (-0.5
    .. 0.5); ``noise``: (m,) the background's pixel noise, ADU;
    ``sigma_px``: the frame's optical PSF sigma.
    """
    m = len(light)
    fx, dx = pixel_fractions(_EDGES[None, :] - np.asarray(phase_x)[:, None], sigma_px)
    fy, dy = pixel_fractions(_EDGES[None, :] - np.asarray(phase_y)[:, None], sigma_px)
    basis = np.empty((m, 9, 3))
    basis[:, :, 0] = (fy[:, :, None] * fx[:, None, :]).reshape(m, 9)
    basis[:, :, 1] = (fy[:, :, None] * dx[:, None, :]).reshape(m, 9)
    basis[:, :, 2] = (dy[:, :, None] * fx[:, None, :]).reshape(m, 9)
    gram = np.einsum("mik,mil->mkl", basis, basis)
    # D: the central pixel's unit vector less its projection on the basis
    coef = np.linalg.solve(gram, basis[:, 4, :, None])[:, :, 0]
    d = -np.einsum("mik,mk->mi", basis, coef)
    d[:, 4] += 1.0
    p = basis[:, :, 0]
    flux = np.maximum(np.einsum("mi,mi->m", p, light) / np.einsum("mi,mi->m", p, p), 0.0)
    variance = np.square(noise)[:, None] + shot_adu * flux[:, None] * p
    spread = np.sqrt(np.einsum("mi,mi->m", d * d, variance))
    return np.einsum("mi,mi->m", d, light) / np.maximum(spread, 1e-12)

