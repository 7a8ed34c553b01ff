"""Whether a spot is a particle's short track rather than a star: elongated and sharp across.

A particle's charge is deposited along its path without the optics' blur:
across the track it is as narrow as its diffusion (about 0.45 px), along it
a line of its projected length. A star is the frame's PSF, whatever its
brightness, so its light's shape is the frame's stars' shape. Under a sharp
PSF (sigma 0.6-0.8 px) a track one to four pixels long is about as wide
overall as a star, and the moments' tests (tracker.detect.spot_shapes),
which must allow for the worst sub-pixel phase, pass it; its light's
second-order shape at its own phase does not.

On the 5 x 5 pixels around the pixel nearest each spot's centre the light
S (background subtracted, ADU) is modelled as

    S = a P + bx Px + by Py + hxx Pxx + hxy Pxy + hyy Pyy + noise,

P the pixel-integrated round Gaussian of the PSF's sigma at the spot's
centre (unit flux) and Px ... Pyy its first and second derivatives by the
centre. A Gaussian light of covariance sigma^2 I + dC is, to first order in
dC, P + (dCxx Pxx + 2 dCxy Pxy + dCyy Pyy) / 2 (the heat equation), so
``shear`` = ((hxx - hyy) / a, hxy / a) is (dCxx - dCyy, 2 dCxy) / 2: how
much longer than wide the light is, px^2, measured at the spot's own pixel
phase (the derivatives carry it) and with its centring error absorbed by
Px and Py. A star's is its frame's stars' (0 for a round PSF, the PSF's own
ellipticity otherwise), a track's grows as its length squared over 24 and
points along it; the spot's light across that direction, dC there, is the
frame's stars' for a star (a trailed star, a blend of two keep the PSF's
width across) and below it for a track.

A spot is a track (:func:`track_spots`) when its shear differs from the
frame's stars' (the median over its bright unsaturated spots) by more than
:data:`Z_LINE` standard errors (chi-square of two degrees of freedom: a
star's chance 1 in 10^4; each standard error includes :data:`_FIELD_SHEAR`
of the PSF's variance, what the lens's field may change a star by), by
more than :data:`_LINE_SHEAR` of that variance (a track at least 1.5 px
long under a sharp PSF), and its light across is narrower than the stars'
by :data:`Z_ACROSS` standard errors (a star a track touches keeps its own
width across: at 2 a star with a track 1.5 px from its centre was lost).
Each pixel's variance is noise^2 + g a P (the background's and the
star's own shot noise, g ADU^2 per ADU: tracker.detect.significance's
convention). The frame's stars set the reference only when at least
:data:`LINE_REFERENCE_SPOTS` of them are bright, and a frame whose stars are
trailed (their shear over the PSF's variance beyond
:data:`_TRAILED_SHEAR`) is not tested: a trail is no second-order change of
the PSF.

The 6 x 6 normal equations are solved by a Cholesky factorisation written
out over the spots (no LAPACK call, whose BLAS threads would spin on the
core the detector's own slab thread runs on).
"""

from __future__ import annotations

import math

import numpy as np

from tracker.detect.order import median
from tracker.detect.significance import SHOT_ADU
from tracker.normal import erf

__all__ = ["LINE_RADIUS", "LINE_REFERENCE_SNR", "LINE_REFERENCE_SPOTS", "Z_ACROSS", "Z_LINE",
           "line_fit", "track_spots"]

LINE_RADIUS = 2                # the 5 x 5 pixels around the spot's central pixel
Z_LINE = math.sqrt(-2.0 * math.log(1e-4))   # chi(2) at a star's chance of 1 in 10^4: 4.29
Z_ACROSS = 3.0                 # ... and narrower across than the frame's stars by this
_FIELD_SHEAR = 0.05            # a star's shear varies across the field by this x sigma^2
_LINE_SHEAR = 0.25             # a track's shear beyond the stars' is at least this x sigma^2
LINE_REFERENCE_SNR = 30.0          # spots this significant, unsaturated, set the stars' shear
LINE_REFERENCE_SPOTS = 5           # ... when there are at least this many
_TRAILED_SHEAR = 0.25          # the stars' shear over sigma^2 beyond this: a trailed frame
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _pixel_terms(offset: np.ndarray, sigma_px: float) -> tuple[np.ndarray, ...]:
    """A unit Gaussian of ``sigma_px`` integrated over unit pixels, and its first and
    second derivatives by the centre: ``offset`` (m, k) is each pixel's centre less
    the Gaussian's, px."""
    u = np.stack([offset - 0.5, offset + 0.5]) / sigma_px       # (2, m, k) edges
    pdf = np.exp(-0.5 * u * u) / _SQRT_2PI
    cdf = 0.5 * (1.0 + erf(u / math.sqrt(2.0)))
    return (cdf[1] - cdf[0], -(pdf[1] - pdf[0]) / sigma_px,
            -(u[1] * pdf[1] - u[0] * pdf[0]) / sigma_px ** 2)


def _basis(phase_x: np.ndarray, phase_y: np.ndarray, sigma_px: float) -> np.ndarray:
    """(m, 25, 6): P, Px, Py, Pxx, Pxy, Pyy on each spot's 5 x 5, row-major."""
    axis = np.arange(-LINE_RADIUS, LINE_RADIUS + 1, dtype=np.float64)
    fx, dx, ddx = _pixel_terms(axis[None, :] - phase_x[:, None], sigma_px)
    fy, dy, ddy = _pixel_terms(axis[None, :] - phase_y[:, None], sigma_px)
    m, k = len(phase_x), len(axis)
    out = np.empty((m, k * k, 6))
    for j, (row, col) in enumerate(((fy, fx), (fy, dx), (dy, fx), (fy, ddx), (dy, dx),
                                    (ddy, fx))):
        out[:, :, j] = (row[:, :, None] * col[:, None, :]).reshape(m, k * k)
    return out


def _cholesky_inverse(gram: np.ndarray) -> np.ndarray:
    """Inverses (m, k, k) of symmetric positive definite ``gram`` (m, k, k), by a
    Cholesky factorisation over the spots at once (no LAPACK)."""
    m, k, _ = gram.shape
    low = np.zeros_like(gram)
    for j in range(k):
        d = gram[:, j, j] - np.einsum("mi,mi->m", low[:, j, :j], low[:, j, :j])
        low[:, j, j] = np.sqrt(np.maximum(d, 1e-300))
        for i in range(j + 1, k):
            low[:, i, j] = (gram[:, i, j] - np.einsum("mi,mi->m", low[:, i, :j],
                                                      low[:, j, :j])) / low[:, j, j]
    # inverse of the lower factor by forward substitution, then inv = L^-T L^-1
    inv_low = np.zeros_like(gram)
    for j in range(k):
        inv_low[:, j, j] = 1.0 / low[:, j, j]
        for i in range(j + 1, k):
            inv_low[:, i, j] = -np.einsum("mr,mr->m", low[:, i, j:i],
                                          inv_low[:, j:i, j]) / low[:, i, i]
    return np.einsum("mri,mrj->mij", inv_low, inv_low)


def line_fit(light: np.ndarray, phase_x: np.ndarray, phase_y: np.ndarray,
             noise: np.ndarray, sigma_px: float,
             shot_adu: float = SHOT_ADU) -> tuple[np.ndarray, np.ndarray]:
    """The model's coefficients (m, 6) and their covariance (m, 6, 6) (module docstring).

    ``light``: (m, 25) background-subtracted ADU of the 5 x 5 pixels around
    the pixel nearest each spot's centre, row-major; ``phase_x``, ``phase_y``:
    (m,) the centre's offset from that pixel's centre, px; ``noise``: (m,) the
    pixel noise without the spot's light, ADU; ``sigma_px``: the frame's PSF sigma.
    """
    basis = _basis(np.asarray(phase_x, float), np.asarray(phase_y, float), sigma_px)
    p = basis[:, :, 0]
    flux = np.maximum(np.einsum("mi,mi->m", p, light) / np.einsum("mi,mi->m", p, p), 0.0)
    weight = 1.0 / (np.square(noise)[:, None] + (shot_adu * flux)[:, None] * p)
    cov = _cholesky_inverse(np.einsum("mik,mi,mil->mkl", basis, weight, basis))
    coef = np.einsum("mkl,mil,mi,mi->mk", cov, basis, weight, light)
    return coef, cov


def track_spots(coef: np.ndarray, cov: np.ndarray, reference: np.ndarray,
                sigma_px: float) -> np.ndarray:
    """The spots that are particles' tracks (module docstring): (m,) bool.

    ``coef``, ``cov``: :func:`line_fit`'s; ``reference``: the spots (m,) bool
    that may set the frame's stars' shear (bright, unsaturated).
    """
    m = len(coef)
    out = np.zeros(m, bool)
    flux = coef[:, 0]
    fit = flux > 0.0
    # (dCxx - dCyy) / 2, dCxy and (dCxx + dCyy) / 2 as combinations of the coefficients
    combos = np.array([[0, 0, 0, 1, 0, -1], [0, 0, 0, 0, 1, 0], [0, 0, 0, 1, 0, 1]], float)
    value = np.einsum("jk,mk->mj", combos, coef) / np.where(fit, flux, 1.0)[:, None]
    ref = reference & fit
    if np.count_nonzero(ref) < LINE_REFERENCE_SPOTS:
        return out
    stars = np.array([median(value[ref, j]) for j in range(3)])
    variance = sigma_px ** 2
    if math.hypot(stars[0], stars[1]) > _TRAILED_SHEAR * variance:
        return out
    diff = value - stars[None, :]
    var = np.einsum("jk,mkl,jl->mj", combos, cov, combos) / np.square(
        np.where(fit, flux, 1.0))[:, None]
    field = (_FIELD_SHEAR * variance) ** 2
    z_shear = np.hypot(diff[:, 0] / np.sqrt(var[:, 0] + field),
                       diff[:, 1] / np.sqrt(var[:, 1] + field))
    # across the elongation: its unit normal (nx, ny) = (-sin t, cos t) for the shear's
    # angle 2t; dC_nn / 2 = nx^2 hxx + nx ny hxy + ny^2 hyy over the flux
    angle = 0.5 * np.arctan2(diff[:, 1], diff[:, 0])
    nx, ny = -np.sin(angle), np.cos(angle)
    across = np.stack([np.zeros(m)] * 3 + [nx * nx, nx * ny, ny * ny], axis=1)
    across_value = np.einsum("mk,mk->m", across, coef) / np.where(fit, flux, 1.0)
    across_ref = (stars[2] - np.cos(2 * angle) * stars[0] - np.sin(2 * angle) * stars[1]) / 2
    across_var = np.einsum("mk,mkl,ml->m", across, cov, across) / np.square(
        np.where(fit, flux, 1.0))
    z_across = (across_ref - across_value) / np.sqrt(across_var + field)
    shear = np.hypot(diff[:, 0], diff[:, 1])
    return fit & (z_shear > Z_LINE) & (z_across > Z_ACROSS) & (shear > _LINE_SHEAR * variance)
