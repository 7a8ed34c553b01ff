"""Cramer-Rao bound on a star's centroid: the limit column of the detection benchmark.

Model: a star of ``flux`` (any unit, e.g. electrons) at (x, y) puts
``flux * wx(c) * wy(r)`` into pixel (c, r), with wx, wy the Gaussian of
sigma ``sigma_px`` integrated over the pixel (tracker.sim.psf's model; pixel
convention: origin at the centre of the top-left pixel). Unknowns are x, y
and the flux; the background is taken as known (it is estimated from far
more pixels than the star covers). Each pixel's noise is Gaussian with the
variance ``variance(signal)`` returns for the star's light in it (for
Poisson light plus background and read noise: signal + background + read^2),
so the Fisher information is

    I_jk = sum over pixels of d(mu)/d(theta_j) d(mu)/d(theta_k) / variance,

summed numerically over a box of +-(4 sigma + 2) pixels around the star, and
the bound on the Euclidean centroid error is sqrt([I^-1]_xx + [I^-1]_yy).
For noise that is not Gaussian, pass as ``variance`` the reciprocal of the
pixel's Fisher information about its mean: the sum is then exact (the
benchmark does so for the seed's speckle); passing the noise power
instead gives the bound of Gaussian noise of that power, which a
non-Gaussian model's estimator can beat.

Saturation: a pixel whose expected star light reaches ``saturation`` is
clipped by the sensor, so its value says only "at least full scale"; it is
left out of the sum (censored), which is what makes the bound of a
saturated star honest instead of that of an ideal, unclipped sensor.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from tracker.normal import pixel_fractions

__all__ = ["centroid_crb", "gaussian_model", "PsfModel"]


def _axis(centre: np.ndarray, first: np.ndarray, size: int, sigma: float):
    """Pixel fractions (N, size) and their derivatives with respect to the centre."""
    edges = first[:, None] + np.arange(size + 1)[None, :] - 0.5 - centre[:, None]
    return pixel_fractions(edges, sigma)


PsfModel = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int],
                   tuple[np.ndarray, np.ndarray, np.ndarray]]


def gaussian_model(sigma_px: float) -> PsfModel:
    """The pixel-integrated Gaussian of ``sigma_px`` as a :data:`PsfModel`."""

    def model(x, y, x0, y0, size):
        wx, dwx = _axis(x, x0, size, sigma_px)
        wy, dwy = _axis(y, y0, size, sigma_px)
        return (wy[:, :, None] * wx[:, None, :], wy[:, :, None] * dwx[:, None, :],
                dwy[:, :, None] * wx[:, None, :])
    return model


def centroid_crb(x: np.ndarray, y: np.ndarray, flux: np.ndarray, sigma_px: float,
                 variance: Callable[[np.ndarray], np.ndarray],
                 saturation: float | None = None, model: PsfModel | None = None) -> np.ndarray:
    """Lower bound on the RMS Euclidean centroid error of each star, px.

    ``x``, ``y``, ``flux``: (N,) arrays. ``variance(signal)`` maps the star's
    light per pixel, an (N, K, K) array, to the noise variance of those
    pixels in the same unit squared. ``saturation`` (same unit as ``flux``;
    None = never) is the star light at which a pixel clips. Stars with no
    information give inf. ``model(x, y, x0, y0, size)`` gives each star's
    fraction of light per pixel of the size x size box from column x0, row
    y0, and its derivatives by x and y (:data:`PsfModel`); by default the
    pixel-integrated Gaussian of ``sigma_px``, which also sets the box
    (+-(4 sigma + 2) px).
    """
    x = np.atleast_1d(np.asarray(x, np.float64))
    y = np.atleast_1d(np.asarray(y, np.float64))
    flux = np.atleast_1d(np.asarray(flux, np.float64))
    half = int(math.ceil(4.0 * sigma_px)) + 2
    size = 2 * half + 1
    x0 = np.floor(x + 0.5) - half
    y0 = np.floor(y + 0.5) - half
    shape, dx, dy = (model or gaussian_model(sigma_px))(x, y, x0, y0, size)
    signal = flux[:, None, None] * shape
    var = np.asarray(variance(signal), np.float64)
    if saturation is not None:
        var = np.where(signal >= saturation, np.inf, var)   # censored: no information
    grads = np.stack([flux[:, None, None] * dx, flux[:, None, None] * dy, shape],
                     axis=1)                                 # (N, 3, rows, cols)
    fisher = np.einsum("npij,nqij->npq", grads, grads / var[:, None])
    out = np.full(len(x), np.inf)
    ok = np.linalg.det(fisher) > 0
    if np.any(ok):
        inv = np.linalg.inv(fisher[ok])
        out[ok] = np.sqrt(inv[:, 0, 0] + inv[:, 1, 1])
    return out
