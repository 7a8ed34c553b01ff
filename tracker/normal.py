"""The standard normal distribution, vectorised over numpy arrays, numpy only.

One approximation serves everything: Numerical Recipes' ``erfcc``, whose
fractional error in erfc(x) is below 1.2e-7 for every x >= 0. Because it
gives erfc as exp(poly), its logarithm stays accurate far into the tails
where the probability itself underflows, which is what a likelihood of
rare pixel values needs.
"""

from __future__ import annotations

import numpy as np

__all__ = ["erf", "log_pdf", "log_tail", "log_interval", "pixel_fractions",
           "spaced_pixel_fractions"]

_LOG_HALF = float(np.log(0.5))
_LOG_SQRT_2PI = float(0.5 * np.log(2.0 * np.pi))
_SQRT2 = float(np.sqrt(2.0))


def _log_erfc_abs(x: np.ndarray) -> np.ndarray:
    """log erfc(|x|) (NR erfcc; fractional error of erfc < 1.2e-7)."""
    z = np.abs(x)
    t = 1.0 / (1.0 + 0.5 * z)
    poly = -1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277))))))))
    return np.log(t) - z * z + poly


def erf(x: np.ndarray) -> np.ndarray:
    """Error function; absolute error < 2.4e-7."""
    x = np.asarray(x, dtype=np.float64)
    erfc = np.exp(_log_erfc_abs(x))
    return np.where(x >= 0, 1.0 - erfc, erfc - 1.0)


def log_pdf(z: np.ndarray) -> np.ndarray:
    """log of the standard normal density at z."""
    return -0.5 * np.square(z) - _LOG_SQRT_2PI


def log_tail(z: np.ndarray) -> np.ndarray:
    """log Q(z) = log P(Z > z); accurate in both tails, -inf at z = +inf."""
    z = np.asarray(z, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        small = _LOG_HALF + _log_erfc_abs(z / _SQRT2)      # log Q(|z|)
        out = np.where(z >= 0, small, np.log1p(-np.exp(small)))
    out = np.where(z == np.inf, -np.inf, out)
    return np.where(z == -np.inf, 0.0, out)


def log_interval(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """log P(lo < Z < hi) for lo < hi (infinite ends allowed), accurate in the tails.

    An interval in one tail is the difference of two tail probabilities
    taken on that side, Q(a) - Q(b) with 0 <= a < b, so nothing cancels
    when both are tiny; one that contains 0 is 1 - Q(hi) - Q(-lo), at least
    its width times 0.24. Either way only two tail values are needed.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    upper = lo >= 0.0
    across = (lo < 0.0) & (hi > 0.0)
    first = np.where(upper, lo, np.where(across, hi, -hi))    # all >= 0
    second = np.where(upper, hi, -lo)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        a = _LOG_HALF + _log_erfc_abs(first / _SQRT2)          # log Q(first)
        b = _LOG_HALF + _log_erfc_abs(second / _SQRT2)
        one_side = a + np.log1p(-np.exp(b - a))
        both = np.log(np.maximum(1.0 - np.exp(a) - np.exp(b), 1e-300))
    return np.where(across, both, one_side)


def pixel_fractions(edges: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """A Gaussian of ``sigma`` integrated over pixels, and its derivative by the centre.

    ``edges``: pixel edges minus the Gaussian's centre along the last axis
    (size + 1 values for size pixels, px). Returns the fraction of the
    Gaussian in each pixel and the derivative of that fraction with
    respect to the centre, both of the last axis' length minus one.
    """
    cdf, pdf = _edge_values(edges, sigma)
    return np.diff(cdf, axis=-1), -np.diff(pdf, axis=-1)


def spaced_pixel_fractions(edges: np.ndarray, per_px: int,
                           sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pixel_fractions` of unit-wide pixels whose edges lie on one grid.

    ``edges``: 1-D, evenly spaced 1 / ``per_px`` px apart (minus the
    Gaussian's centre); pixel i spans ``edges[i]`` to ``edges[i + per_px]``.
    Each edge's values are computed once, not once per pixel side: half the
    error functions of the same pixels listed edge by edge, the same values.
    """
    cdf, pdf = _edge_values(edges, sigma)
    return cdf[per_px:] - cdf[:-per_px], -(pdf[per_px:] - pdf[:-per_px])


def _edge_values(edges: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The cumulative Gaussian of ``sigma`` less one half, and its density, at ``edges``."""
    scaled = np.asarray(edges, dtype=np.float64) / sigma
    return 0.5 * erf(scaled / _SQRT2), np.exp(log_pdf(scaled)) / sigma
