"""How narrow a star can measure: the width test that tells a particle's charge from a star.

A spot's width here is its Gaussian-weighted second moment across its
narrowest axis over a round star's of the frame's PSF under the same weight
(tracker.detect.default: 1 for a star centred on a pixel's centre; the
weight is the pixel-integrated PSF's sigma). A particle's charge is not
convolved with the optics: diffused over about 0.45 px it reads 0.3-0.6 of
a star's width under PSF sigmas of 0.8-2.5 px, and a star reads less than
its frame's stars only by

* its noise: the width of a spot of windowed SNR ``known`` (its own shot
  noise counted, tracker.detect.significance) spreads by about
  sqrt(2) / known of itself (the spread of a second moment under the
  matched weight; 0.65-0.9 of that on simulated stars of sigma 1.3-2.5 px at
  SNR 10-80);
* the lens's field: a PSF sigma varying by ``FIELD_SPREAD`` (one standard
  deviation, relative) across the field moves a star's width under the
  matched weight by as much (d ln width / d ln sigma = 1 there);
* its pixel phase: an undersampled star centred on a pixel's edge reads
  narrower across it than one centred on a pixel (:func:`lowest_phase_width`:
  0.99 of the mean at sigma 0.8 px, 0.86 at 0.6 px, 1.00 from 1.0 px).

A spot narrower than the frame's star width times the lowest phase's ratio,
by more than ``spreads`` of the first two in quadrature, is sharper than the
optics deliver: :func:`sharper_than_stars`.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.normal import pixel_fractions

__all__ = ["FIELD_SPREAD", "lowest_phase_width", "sharper_than_stars"]

FIELD_SPREAD = 0.05       # a star's width across the field, relative standard deviation
# a pixel's centre, its edge, its corner and between
_PHASES = ((0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.25, 0.0), (0.25, 0.25))


def _narrowest_width(sigma_px: float, phase: tuple[float, float]) -> float:
    """Weighted second moment across the narrowest axis of a pixel-integrated Gaussian star
    of optical sigma ``sigma_px`` centred at ``phase`` (px from a pixel's centre), under
    the round Gaussian weight of the pixel-integrated sigma centred on the star, over
    half that weight's variance."""
    weight = math.sqrt(sigma_px ** 2 + 1.0 / 12.0)
    radius = int(math.ceil(4.0 * weight)) + 1
    edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
    light = np.outer(pixel_fractions(edges - phase[1], sigma_px)[0],
                     pixel_fractions(edges - phase[0], sigma_px)[0])
    axis = np.arange(-radius, radius + 1, dtype=np.float64)
    ex, ey = axis[None, :] - phase[0], axis[:, None] - phase[1]
    w = light * np.exp(-0.5 * (ex * ex + ey * ey) / weight ** 2)
    total = w.sum()
    mxx, myy, mxy = (w * ex * ex).sum() / total, (w * ey * ey).sum() / total, \
        (w * ex * ey).sum() / total
    size = mxx + myy
    return 0.5 * (size - math.hypot(mxx - myy, 2.0 * mxy)) / (0.5 * weight ** 2)


def lowest_phase_width(sigma_px: float) -> float:
    """The narrowest width a star of optical sigma ``sigma_px`` reads over its pixel phase,
    over the mean over phases (<= 1)."""
    widths = [_narrowest_width(sigma_px, p) for p in _PHASES]
    return min(widths) / (sum(widths) / len(widths))


def sharper_than_stars(width: np.ndarray, known: np.ndarray, reference: float,
                       phase_low: float, spreads: float) -> np.ndarray:
    """Spots narrower than any star of the frame can measure (module docstring): (n,) bool.

    ``width``: the spots' widths; ``known``: their SNR with their own shot
    noise; ``reference``: the frame's stars' median width; ``phase_low``:
    :func:`lowest_phase_width` of its PSF; ``spreads``: the significance.
    """
    noise = math.sqrt(2.0) / np.maximum(known, 1e-12)
    spread = np.hypot(noise, FIELD_SPREAD)
    return width < reference * (phase_low - spreads * spread)
