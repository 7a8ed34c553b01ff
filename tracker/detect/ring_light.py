"""Light under a faint spot that the background grid does not hold: a star's halo, the local sky.

The background (tracker.detect.background) is a grid of tile medians,
smooth over a tile; the threshold stands a number of filtered noises above
it. Two kinds of light under a spot escape it, and the sky's noise on them
crosses the threshold. Both are read as the median of the filtered image
(less the background) on a ring of pixels one pixel wide (their centres
within half a pixel of its radius):

* A bright star's halo. A star's light does not end at its core: an Airy
  pattern's rings hold 16 % of it, falling as r^-3 (a pixel at r px from a
  star of flux F under an Airy disc of Gaussian-equivalent sigma s holds
  about 0.07 s F / r^3 on average over the rings), a Moffat's wings as
  r^-2 beta, and scattered light further out. Around a saturated star that
  halo stands at the sky's noise 10-15 PSF sigmas out (a magnitude 0.9
  star on a RAW8 frame: 0.5-1 ADU at 9.7 px under sigma 0.89). It is the
  star's own radial profile, the same at every azimuth (to the PSF's
  ellipticity); a companion star adds light at one azimuth. So a spot at
  r px from a star at least :data:`HALO_CONTRAST` times brighter (their
  filtered peaks over the background) is judged over the ring of radius r
  around that star, the pixels near the spot (its own light,
  :data:`SPOT_SIGMAS`) and beyond the frame left out, where it stands
  :data:`HALO_ERRORS` standard errors above the sky's filtered level.
* The local sky. Where the light under the sky changes within a tile (the
  curvature of glare, a lens ghost's ring, scattered light beside the lit
  ground), the grid lags it. The ring :data:`LOCAL_SKY_SIGMAS` PSF sigmas
  around the spot itself (past its own light: 0.2 % of its filtered peak
  there) tells the sky under it, counted where it stands
  :data:`LOCAL_ERRORS` standard errors above the sky's filtered level.
  At 3 standard errors the ring dropped 13 spots of the bench's draw (seed
  1), 6 of them faint real stars (peak SNR 0.6-2.6, the ring 3.0-4.3
  errors up): the ring's median has heavier tails than the normal
  approximation below gives it (a ring of a few independent samples,
  unresolved faint stars). At 5, only spots beside the lunar scene's glare,
  ghosts and lit ground went (seeds 1 and 41).

The spot keeps its detection only if its filtered peak less that light
still clears the threshold over the background; a companion's light and a
star's on a sky the ring measured are their own and still do.

A spot only a ring's median at or above a floor takes away (its filtered peak
over the threshold, above the sky's level) keeps its detection when fewer than
half the ring's pixels reach that floor: the median is at most the upper middle
value. Most rings are that far below (a spot well above the threshold on a
flat sky), and their medians are not reckoned.

The median's standard error is sqrt(pi / 2) times the filtered noise over
the root of the ring's independent samples: the filtered noise is
correlated along the ring over 2 sqrt(pi) filter sigmas (white noise
through a Gaussian of sigma k correlates as a Gaussian of sigma sqrt(2) k,
whose integral is 2 sqrt(pi) k), so a ring of m pixels holds
m / max(1, 2 sqrt(pi) k) of them.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["HALO_CONTRAST", "HALO_ERRORS", "LOCAL_ERRORS", "LOCAL_SKY_SIGMAS", "LightRings",
           "SPOT_SIGMAS", "light_over_sky"]

HALO_CONTRAST = 10.0   # a star this many times the spot's filtered peak may hold it in its halo
HALO_ERRORS = 3.0      # the halo's light counts this many standard errors above the sky's
LOCAL_SKY_SIGMAS = 5.0 # the local sky's ring lies this many PSF sigmas around the spot,
LOCAL_ERRORS = 5.0     # ... and counts this many standard errors above the sky's
SPOT_SIGMAS = 3.0      # a spot's own filtered light reaches this many of its sigmas (sqrt(2)
                       # filter sigmas: the PSF's through the matched filter)
_RING_HALF_WIDTH = 0.5     # px: a ring's pixels lie this close to its radius
_CENTRE_REACH = math.sqrt(0.5)   # px: a pixel's distance from a star's centre differs from
                                 # its distance from the star's own pixel by at most this
_ELEMENTS = 8192           # pixel offsets examined at a time (bounds the temporaries)
_MIN_PIXELS = 8            # a ring of fewer pixels in the frame tells no halo
_MEDIAN_SE = math.sqrt(math.pi / 2.0)   # a median's standard error over the mean's


class LightRings:
    """Rings of pixels around stars, out to ``max_radius_px``: their medians.

    Holds the integer pixel offsets within ``max_radius_px`` + 1 px sorted by
    length, made once; each ring is read from the stretch of them that can lie
    within half a pixel of its radius around a star's sub-pixel centre.
    """

    def __init__(self, max_radius_px: float) -> None:
        reach = int(math.ceil(max_radius_px + _RING_HALF_WIDTH + _CENTRE_REACH))
        dy, dx = (a.ravel() for a in np.mgrid[-reach:reach + 1, -reach:reach + 1])
        length = np.hypot(dx, dy)
        order = np.argsort(length, kind="stable")
        self.dx, self.dy = dx[order].astype(np.intp), dy[order].astype(np.intp)
        self.length = length[order]

    def offsets(self, radius: float, stride: int) -> np.ndarray:
        """Flat offsets (rows ``stride`` elements long) of the pixels whose centres lie
        within half a pixel of ``radius`` px from a pixel's centre: its ring."""
        near = np.abs(self.length - radius) <= _RING_HALF_WIDTH
        return self.dy[near] * stride + self.dx[near]

    @staticmethod
    def around(image: np.ndarray, minus: np.ndarray, centre: np.ndarray,
               offsets: np.ndarray, floor: np.ndarray) -> np.ndarray:
        """The median of ``image`` less ``minus`` (flat, alike) on the ring ``offsets``
        (:meth:`offsets`) around each flat index ``centre`` (rings inside the arrays):
        (p,) float; -inf where the ring's upper half lies below ``floor`` (p,), the
        median not reckoned (:func:`_below_floor`)."""
        at = centre[:, None] + offsets[None, :]
        values = np.take(image, at).astype(np.float64)
        values -= np.take(minus, at)
        reach = np.flatnonzero(~_below_floor(
            np.count_nonzero(values >= floor[:, None], axis=1), offsets.size))
        median = np.full(len(centre), -np.inf)
        if len(reach):
            median[reach] = _middle(values[reach])
        return median

    def light(self, image: np.ndarray, minus: np.ndarray, star_x: np.ndarray,
              star_y: np.ndarray, radius: np.ndarray, spot_x: np.ndarray,
              spot_y: np.ndarray, spot_reach: float,
              floor: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(median, pixels) of ``image`` less ``minus`` (2-D, frame-shaped) on each ring: the pixels
        whose centres lie within half a pixel of ``radius`` (px) from (``star_x``,
        ``star_y``), none within ``spot_reach`` px of (``spot_x``, ``spot_y``) or beyond
        the frame; (p,) float each (median NaN where a ring has no pixel, -inf where its
        upper half lies below ``floor`` (p,), not reckoned: :func:`_below_floor`). Pixel
        convention of tracker.detect.result."""
        first = np.searchsorted(self.length, radius - _RING_HALF_WIDTH - _CENTRE_REACH)
        end = np.searchsorted(self.length, radius + _RING_HALF_WIDTH + _CENTRE_REACH,
                              side="right")
        median = np.full(len(radius), np.nan)
        pixels = np.zeros(len(radius), np.intp)
        floor = np.full(len(radius), -np.inf) if floor is None else floor
        total = np.cumsum(end - first)
        start = 0
        while start < len(radius):   # rings of at most _ELEMENTS offsets read at a time
            stop = max(int(np.searchsorted(total, total[start] - (end[start] - first[start])
                                           + _ELEMENTS, side="right")), start + 1)
            part = slice(start, stop)
            median[part], pixels[part] = self._medians(
                image, minus, star_x[part], star_y[part], radius[part], spot_x[part],
                spot_y[part], spot_reach, floor[part], first[part], end[part])
            start = stop
        return median, pixels

    def _medians(self, image, minus, star_x, star_y, radius, spot_x, spot_y, spot_reach,
                 floor, first, end) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`light` of rings whose offsets are ``first``..``end`` of the sorted ones."""
        h, w = image.shape
        cx, cy = np.rint(star_x).astype(np.intp), np.rint(star_y).astype(np.intp)
        fx, fy = star_x - cx, star_y - cy
        counts = end - first
        ring = np.repeat(np.arange(len(radius)), counts)
        at = np.arange(int(counts.sum())) + np.repeat(first - (np.cumsum(counts) - counts),
                                                       counts)
        dx, dy = self.dx[at], self.dy[at]
        x, y = cx[ring] + dx, cy[ring] + dy
        keep = np.abs(np.hypot(dx - fx[ring], dy - fy[ring]) - radius[ring]) <= _RING_HALF_WIDTH
        keep &= (x >= 0) & (x < w) & (y >= 0) & (y < h)
        keep &= np.hypot(x - spot_x[ring], y - spot_y[ring]) > spot_reach
        ring, x, y = ring[keep], x[keep], y[keep]
        values = image[y, x].astype(np.float64) - minus[y, x]
        pixels = np.bincount(ring, minlength=len(radius))
        low = _below_floor(np.bincount(ring[values >= floor[ring]], minlength=len(radius)),
                          pixels)
        median = np.where(low & (pixels > 0), -np.inf, np.nan)
        if low.all():
            return median, pixels
        reckoned = ~low[ring]
        ring, values = ring[reckoned], values[reckoned]
        values = values[np.lexsort((values, ring))]
        count = np.where(low, 0, pixels)
        start = np.cumsum(count) - count
        some = count > 0
        lower = start[some] + (count[some] - 1) // 2
        upper = start[some] + count[some] // 2
        median[some] = 0.5 * (values[lower] + values[upper])
        return median, pixels


def _middle(values: np.ndarray) -> np.ndarray:
    """The median of each row of ``values`` (p, m), the mean of its two middle values."""
    m = values.shape[1]
    middle = np.partition(values, ((m - 1) // 2, m // 2), axis=1)
    return 0.5 * (middle[:, (m - 1) // 2] + middle[:, m // 2])


def _below_floor(reaching: np.ndarray, pixels: np.ndarray | int) -> np.ndarray:
    """Whether a ring of ``pixels`` pixels, ``reaching`` of them at or above a floor, has
    its median below it: fewer than half reach it (its upper middle value lies below).
    A ring's median is at most its upper middle value, so a spot that only a median at
    the floor takes away keeps its detection without the median reckoned."""
    return reaching < pixels - pixels // 2


def light_over_sky(median: np.ndarray, pixels: np.ndarray, sky_level: np.ndarray,
                noise_f: np.ndarray, filter_sigma_px: float,
                errors: float = HALO_ERRORS) -> np.ndarray:
    """The light under each spot (module docstring): the ring's ``median`` of the
    filtered image over the background (of ``pixels`` pixels) less the sky's filtered
    level ``sky_level`` where that stands ``errors`` standard errors above it
    (filtered noise ``noise_f``, filter sigma ``filter_sigma_px``), else 0; ADU, (p,)."""
    samples = pixels / max(1.0, 2.0 * math.sqrt(math.pi) * filter_sigma_px)
    with np.errstate(divide="ignore", invalid="ignore"):
        error = _MEDIAN_SE * noise_f / np.sqrt(samples)
        excess = median - sky_level
        counted = (pixels >= _MIN_PIXELS) & (excess > errors * error)
    return np.where(counted, excess, 0.0)
