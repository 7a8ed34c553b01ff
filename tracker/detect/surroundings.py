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
sky sectors is embedded in a body and is masked. A saturated star's peak is
clipped, so its wings may stand above a twentieth of what is left of it
on every side; but they fall away from it on every side, which
:meth:`Surroundings.falling_sectors` tells.

A thin line of light (a crescent of the Earth, the ring of a lens ghost) has
sky on two opposite sides and, along itself, light nearly as bright as the
candidate in the two sectors between them: :func:`across_a_line`. A star
beside a body has the body on one side only, and a star's own wings, even
under a PSF three times wider than the one assumed, hold under a third of
its peak all round.

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

from tracker.detect.order import percentile

__all__ = ["Surroundings", "across_a_line", "sky_noise_model"]

_SECTORS = 8
_MEAN_ERRORS = 3.0
_PEAK_FRACTION = 0.05
_SPREAD = 1.5
_PEAK_SPREAD = 0.01
_FALL = 0.5
_BODY_LIGHT = 1.6   # x falling_sectors' ceiling: a sector this bright is a body's light
_LINE_LIGHT = 0.3


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
    level0 = percentile(level, 10.0)
    var0 = percentile(var, 10.0)
    brighter = level - level0 > 5.0 * math.sqrt(max(var0, 1e-12))
    if np.count_nonzero(brighter) < 8:
        return level0, var0, 0.0
    ratio = (var[brighter] - var0) / (level[brighter] - level0)
    return level0, var0, max(0.0, percentile(ratio, 25.0))


def across_a_line(light: np.ndarray, sky: np.ndarray) -> np.ndarray:
    """Whether each candidate lies on a line: (n,) bool from (n, 8) bool sector masks.

    On a line, two opposite sectors (k and k + 4: :class:`Surroundings`
    numbers them by angle) hold ``light`` and the two at right angles to
    them (k + 2 and k + 6) are ``sky``.
    """
    half, quarter = _SECTORS // 2, _SECTORS // 4
    along = light[:, :half] & light[:, half:]
    across = sky & np.roll(sky, -half, axis=1)       # k and k + 4 both sky
    return np.any(along & np.roll(across, -quarter, axis=1)[:, :half], axis=1)


class _Ring:
    """Pixel offsets of the ring inner < r <= outer px around a pixel (padded buffers of
    row ``stride``), in eight sectors."""

    def __init__(self, stride: int, inner: int, outer: int) -> None:
        dy, dx = np.mgrid[-outer:outer + 1, -outer:outer + 1]
        r = np.hypot(dx, dy)
        ring = (r > inner) & (r <= outer)
        dx, dy = dx[ring], dy[ring]
        sector = ((np.arctan2(dy, dx) + math.pi) / (2.0 * math.pi) * _SECTORS).astype(int)
        sector = np.minimum(sector, _SECTORS - 1)
        order = np.argsort(sector, kind="stable")
        self.offsets = (dy * stride + dx)[order].astype(np.intp)
        member = np.zeros((_SECTORS, len(order)))
        member[sector[order], np.arange(len(order))] = 1.0
        self.member = member.T                         # (ring pixels, sectors)
        self.counts = member.sum(axis=1)


class Surroundings:
    """The eight-sector sky test in padded buffers of uint16 frames: up to ``capacity``
    candidates, ``chunk`` at a time; rings ``width`` px wide reaching at most
    ``max_outer`` px (the padding must be as wide)."""

    def __init__(self, stride: int, max_outer: int, capacity: int, chunk: int,
                 width: int = 2) -> None:
        self.stride = int(stride)
        self.max_outer = int(max_outer)
        self.width = int(width)
        self.capacity = int(chunk)
        # every ring a width wide out to max_outer, made once: configure only picks
        self._all_rings = [_Ring(self.stride, r - self.width, r)
                           for r in range(self.width + 1, self.max_outer + 1)]
        # the largest ring's pixels: on the pixel grid a ring's count does not grow
        # with its radius at every step (21 px: 244, 20 px: 248)
        size = self.capacity * max(len(ring.offsets) for ring in self._all_rings)
        self._index = np.zeros(size, np.intp)
        self._values = np.zeros(size, np.float32)
        self._reads = np.zeros(size, np.uint16)
        self._bg = np.zeros(size, np.float32)
        self._sums = np.zeros((3, self.capacity, _SECTORS), np.float64)
        self.sky_sectors = np.zeros(int(capacity), np.int32)
        self.sky = np.zeros((int(capacity), _SECTORS), np.bool_)   # which sectors are sky
        self.light = np.zeros((int(capacity), _SECTORS), np.bool_)  # hold _LINE_LIGHT x peak
        self.configure(1)

    def configure(self, inner: int) -> None:
        """The ring inner < r <= inner + width px; :meth:`falling_sectors` looks further
        out, a width at a time, up to the constructor's ``max_outer``."""
        width = self.width
        outer = max(width + 1, min(int(inner) + width, self.max_outer - width))
        first = outer - (width + 1)
        self.rings = self._all_rings[first::width]
        self.ring = self.rings[0]

    def _sector_stats(self, ring: _Ring, a: int, b: int, image_pad: np.ndarray,
                      bg_pad: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and spread (ADU above the background) of each sector around cand[a:b]."""
        k = len(ring.offsets)
        m = b - a
        idx = self._index[: m * k].reshape(m, k)
        np.add(cand[a:b, None], ring.offsets[None, :], out=idx)
        values = self._values[: m * k].reshape(m, k)
        background = self._bg[: m * k].reshape(m, k)
        reads = self._reads[: m * k].reshape(m, k)
        np.take(image_pad.ravel(), idx, out=reads, mode="clip")
        np.copyto(values, reads)
        np.take(bg_pad.ravel(), idx, out=background, mode="clip")
        np.subtract(values, background, out=values)
        total, square, _ = (s[:m] for s in self._sums)
        np.matmul(values, ring.member, out=total)
        np.multiply(values, values, out=values)
        np.matmul(values, ring.member, out=square)
        mean = total / ring.counts
        spread = np.sqrt(np.maximum(square / ring.counts - mean * mean, 0.0))
        return mean, spread

    @staticmethod
    def _is_sky(ring: _Ring, mean: np.ndarray, spread: np.ndarray, noise: np.ndarray,
                peak: np.ndarray) -> np.ndarray:
        counts = ring.counts
        level_ok = np.abs(mean) < (_MEAN_ERRORS * noise[:, None] / np.sqrt(counts)
                                   + _PEAK_FRACTION * peak[:, None])
        return level_ok & (spread < _SPREAD * noise[:, None] + _PEAK_SPREAD * peak[:, None])

    def sky_sectors_of(self, n: int, image_pad: np.ndarray, bg_pad: np.ndarray,
                       cand: np.ndarray, sky_noise: np.ndarray, peak: np.ndarray) -> np.ndarray:
        """How many of the eight sectors around each of ``cand[:n]`` are sky; (n,) view.

        Which ones are is kept in ``self.sky[:n]`` ((n, 8) bool), and which hold a
        mean of more than 0.3 of the candidate's peak in ``self.light[:n]``. ``image_pad``
        and ``bg_pad``: the impulse-cleaned frame and its background, padded
        alike; ``sky_noise`` (n,) the smooth sky's pixel noise at each
        candidate and ``peak`` (n,) its peak above the background, ADU.
        """
        out = self.sky_sectors[:n]
        for a in range(0, n, self.capacity):
            b = min(n, a + self.capacity)
            mean, spread = self._sector_stats(self.ring, a, b, image_pad, bg_pad, cand)
            self.sky[a:b] = self._is_sky(self.ring, mean, spread, sky_noise[a:b], peak[a:b])
            np.greater(mean, _LINE_LIGHT * peak[a:b, None], out=self.light[a:b])
            np.sum(self.sky[a:b], axis=1, out=out[a:b])
        return out

    def falling_sectors(self, image_pad: np.ndarray, bg_pad: np.ndarray, centre: np.ndarray,
                        sky_noise: np.ndarray, peak: np.ndarray,
                        ceiling: np.ndarray) -> np.ndarray:
        """For a saturated star at each of ``centre`` (padded flat indices of the pixels
        nearest its centroid): which sectors are sky, or fall by half or more to the
        next ring out, in the first ring whose mean is under ``ceiling`` (n,) ADU above
        the background (none if none is: saturated light as far as the rings reach).

        A saturated star's wings may stand far above a twentieth of its
        clipped peak on every side, but beyond its clipped core they fall
        away from it on every side; a body's edge, a slope of glare or
        textured ground does not. In that ring a sector brighter than
        ``_BODY_LIGHT`` x ``ceiling`` is a body's light reaching in (a star's
        ring is round: its sectors fall together), and none of that
        candidate's sectors falls. Returns a new (n, 8) bool array (there are
        few such stars).
        """
        n = len(centre)
        out = np.zeros((n, _SECTORS), np.bool_)
        for a in range(0, n, self.capacity):
            b = min(n, a + self.capacity)
            undecided = np.ones(b - a, bool)
            inner = self.rings[0]
            mean, spread = self._sector_stats(inner, a, b, image_pad, bg_pad, centre)
            for outer in self.rings[1:]:
                ready = undecided & (mean.mean(axis=1) < ceiling[a:b])
                if ready.any():
                    sky = self._is_sky(inner, mean, spread, sky_noise[a:b], peak[a:b])
                    far, _ = self._sector_stats(outer, a, b, image_pad, bg_pad, centre)
                    falls = sky | ((mean > 0.0) & (mean < ceiling[a:b, None])
                                   & (far < _FALL * mean))
                    # a star is round: where its ring's mean fell under the ceiling no
                    # sector of it is still near full scale; a body's is (the horn of
                    # a saturated crescent, the limb of a disc), and nothing falls
                    falls &= ~np.any(mean >= _BODY_LIGHT * ceiling[a:b, None], axis=1,
                                     keepdims=True)
                    out[a:b][ready] = falls[ready]
                    undecided &= ~ready
                if not undecided.any():
                    break
                inner = outer
                mean, spread = self._sector_stats(inner, a, b, image_pad, bg_pad, centre)
        return out
