"""A star's flux from its PSF-weighted sum, not from the plain sum over its window.

The centroid window (tracker.detect.windowed) sums the background-subtracted
pixels S over a square of side 2 r + 1 (r = 3 effective PSF sigmas: 49-121
pixels for sigma 1-1.6 px) and also their weighted sum sum(W S), W a
Gaussian of the effective PSF sigma centred on the centroid. For a star of
flux F on white noise of sigma per pixel, both are unbiased estimates of F
once the weighted one is divided by C = sum(W P), P the star's pixel-
integrated profile (C is 1/2 for a Gaussian weight as wide as the PSF), but:

* the plain sum's noise is sigma sqrt(N) (N the window's pixels), the
  weighted estimate's sigma sqrt(sum W^2) / C = sigma sqrt(4 pi s^2) (s the
  effective sigma: 15 pixels' worth at s = 1.1 px against 121);
* an error b per pixel in the background model (glare curving between the
  background grid's nodes, light of a body nearby) biases the plain sum by
  N b, the weighted estimate by b sum(W) / C = 4 pi s^2 b.

So a faint star on a bright, structured background (a star of Hp 4.5 on the
Sun's glare at 16 mm, 1230 e- over 900 e- a pixel) reads 15 % of its flux
from the plain sum and ranks below stars of Hp 6.5 on dark sky, and a
lost-in-space solver, which draws its patterns from the brightest stars,
misses it. The weighted estimate is the one reported.

A saturated star keeps its plain sum: its clipped core is where the weight
is, while its unclipped wings are not, and the plain sum is the larger,
nearer its flux, keeping it above the unsaturated stars, as it is.
"""

from __future__ import annotations

import numpy as np

from tracker.normal import erf

__all__ = ["weighted_capture"]

_PHASES = 16   # sub-pixel phases averaged over, per axis


def weighted_capture(psf_sigma_px: float, weight_sigma_px: float, radius: int) -> float:
    """sum(W P) for a round Gaussian PSF of ``psf_sigma_px`` (optical, before the pixel),
    integrated over square pixels, and a Gaussian weight of ``weight_sigma_px`` centred on
    the star, over a window of ``radius`` px each side, averaged over the star's
    sub-pixel phase (uniform); a pure number (0.5 for a weight as wide as the
    pixel-integrated PSF, a little less for the window's truncation)."""
    phase = (np.arange(_PHASES) + 0.5) / _PHASES - 0.5
    pixel = np.arange(-radius, radius + 1, dtype=np.float64)
    offset = pixel[None, :] - phase[:, None]             # (phase, pixel): pixel - centre
    scale = 1.0 / (np.sqrt(2.0) * psf_sigma_px)
    profile = 0.5 * (erf((offset + 0.5) * scale) - erf((offset - 0.5) * scale))
    weight = np.exp(-0.5 * np.square(offset / weight_sigma_px))
    per_axis = np.sum(weight * profile, axis=1)
    # separable: the 2-D sum is the product of the axes', averaged over both phases
    return float(np.mean(per_axis) ** 2)
