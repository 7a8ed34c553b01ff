"""Is a candidate a star on open sky, or a bump on a bright, textured body?

A star's light is gone a few PSF sigmas from its centre: beyond that its
surroundings are sky, at the background level and no noisier than the sky.
A crater rim on sunlit terrain, a twig of a lit tree, a cloud on the
Earth's disc or a knot along the edge of glare is a local maximum of a
textured surface: its surroundings are that surface, far brighter or far
noisier than sky. A star right beside such a body (above the horizon, next
to the Earth's limb) has sky on at least one side.

So the ring of pixels at ``inner``-``outer`` px around each candidate is cut
into eight sectors. A sector is sky when its mean is within three standard
errors (plus a twentieth of the candidate's peak, for the faint wings of a
broad PSF and neighbours' light) of the background and its spread is
under 1.5 times the sky's noise (plus a hundredth of the peak, for the
slope of those wings across the ring). A candidate with fewer than ``min_sky``
sky sectors is embedded in a body and is masked.

"The sky's noise" is not the tile's (a tile on textured terrain has a large
noise, which would excuse its texture) but that of the frame's smooth sky
at the candidate's background level: var = var0 + slope * (level - level0),
photon noise rising with the light (tracker.detect.background's tiles give
var0, the noise of the darkest tiles, and the slope, a low quantile of the
brighter tiles' var / level ratios, so that textured tiles, whose ratios
are high, do not raise it).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Surroundings", "sky_noise_model"]

_SECTORS = 8
_MEAN_ERRORS = 3.0
_PEAK_FRACTION = 0.05
_SPREAD = 1.5
_PEAK_SPREAD = 0.01


def sky_noise_model(level: np.ndarray, noise: np.ndarray,
                    saturation: float) -> tuple[float, float, float]:
    """(level0, var0, slope) of the smooth sky's pixel variance var0 + slope (level - level0).

    From per-tile ``level`` and ``noise`` (ADU): level0 and var0 are the
    10th percentiles of the tiles' levels and variances; the slope is the
    25th percentile of (var - var0) / (level - level0) over tiles at least
    5 noise brighter than level0 (0 when fewer than 8 such tiles). Tiles
    within a tenth of ``saturation`` (ADU), flat because clipped, are left out.
    """
    live = np.asarray(level, np.float64).ravel() < 0.9 * saturation
    if not np.any(live):
        live[:] = True
    level = np.asarray(level, np.float64).ravel()[live]
    var = np.square(np.asarray(noise, np.float64).ravel()[live])
    level0 = float(np.percentile(level, 10))
    var0 = float(np.percentile(var, 10))
    brighter = level - level0 > 5.0 * math.sqrt(max(var0, 1e-12))
    if np.count_nonzero(brighter) < 8:
        return level0, var0, 0.0
    ratio = (var[brighter] - var0) / (level[brighter] - level0)
    return level0, var0, max(0.0, float(np.percentile(ratio, 25)))


class Surroundings:
    """The eight-sector sky test in padded buffers of uint16 frames: up to ``capacity``
    candidates, ``chunk`` at a time."""

    def __init__(self, stride: int, max_outer: int, capacity: int, chunk: int) -> None:
        self.stride = int(stride)
        self.max_outer = int(max_outer)
        self.capacity = int(chunk)
        side = 2 * self.max_outer + 1
        self._index = np.zeros(self.capacity * side * side, np.intp)
        self._values = np.zeros(self.capacity * side * side, np.float32)
        self._reads = np.zeros(self.capacity * side * side, np.uint16)
        self._bg = np.zeros(self.capacity * side * side, np.float32)
        self._sums = np.zeros((3, self.capacity, _SECTORS), np.float64)
        self.sky_sectors = np.zeros(int(capacity), np.int32)
        self.configure(2, 3)

    def configure(self, inner: int, outer: int) -> None:
        """The ring inner < r <= outer px, at most the constructor's ``max_outer``."""
        outer = min(int(outer), self.max_outer)
        inner = min(int(inner), outer - 1)
        dy, dx = np.mgrid[-outer:outer + 1, -outer:outer + 1]
        r = np.hypot(dx, dy)
        ring = (r > inner) & (r <= outer)
        dx, dy = dx[ring], dy[ring]
        sector = ((np.arctan2(dy, dx) + math.pi) / (2.0 * math.pi) * _SECTORS).astype(int)
        sector = np.minimum(sector, _SECTORS - 1)
        order = np.argsort(sector, kind="stable")
        self.offsets = (dy * self.stride + dx)[order].astype(np.intp)
        member = np.zeros((_SECTORS, len(order)))
        member[sector[order], np.arange(len(order))] = 1.0
        self.member = member.T                         # (ring pixels, sectors)
        self.counts = member.sum(axis=1)

    def sky_sectors_of(self, n: int, image_pad: np.ndarray, bg_pad: np.ndarray,
                       cand: np.ndarray, sky_noise: np.ndarray, peak: np.ndarray) -> np.ndarray:
        """How many of the eight sectors around each of ``cand[:n]`` are sky; (n,) view.

        ``image_pad`` and ``bg_pad``: the impulse-cleaned frame and its
        background, padded alike; ``sky_noise`` (n,) the smooth sky's pixel
        noise at each candidate and ``peak`` (n,) its peak above the
        background, ADU.
        """
        k = len(self.offsets)
        out = self.sky_sectors[:n]
        for a in range(0, n, self.capacity):
            b = min(n, a + self.capacity)
            m = b - a
            idx = self._index[: m * k].reshape(m, k)
            np.add(cand[a:b, None], self.offsets[None, :], out=idx)
            values = self._values[: m * k].reshape(m, k)
            background = self._bg[: m * k].reshape(m, k)
            reads = self._reads[: m * k].reshape(m, k)
            np.take(image_pad.ravel(), idx, out=reads, mode="clip")
            np.copyto(values, reads)
            np.take(bg_pad.ravel(), idx, out=background, mode="clip")
            np.subtract(values, background, out=values)
            total, square, _ = (s[:m] for s in self._sums)
            np.matmul(values, self.member, out=total)
            np.multiply(values, values, out=values)
            np.matmul(values, self.member, out=square)
            mean = total / self.counts
            spread = np.sqrt(np.maximum(square / self.counts - mean * mean, 0.0))
            noise = sky_noise[a:b, None]
            level_ok = np.abs(mean) < (_MEAN_ERRORS * noise / np.sqrt(self.counts)
                                       + _PEAK_FRACTION * peak[a:b, None])
            spread_ok = spread < _SPREAD * noise + _PEAK_SPREAD * peak[a:b, None]
            np.sum(level_ok & spread_ok, axis=1, out=out[a:b])
        return out
