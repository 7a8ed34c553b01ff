"""Candidate stars: local maxima of the matched-filtered image above a noise threshold.

The impulse-cleaned frame is convolved with a Gaussian of the PSF's sigma
(the matched filter for a Gaussian PSF in background noise: it maximises a
point source's SNR). A pixel is a candidate when its filtered value exceeds
``threshold`` (an image of the background plus ``k`` times the filtered
noise, per pixel) and is a local maximum: strictly
above the four neighbours met before it in raster order and not below the
four after it, so a flat top (a saturated star) gives one candidate, not a
plateau of them.

Candidates are ranked by their filtered value above the background (read
at the candidate pixel). Close pairs: each candidate is compared with the
brightest brighter candidate within ``radius`` px. It is kept as a separate star only if the
filtered image dips between the two, at 1/4, 1/2 and 3/4 of the way, by
at least ``dip_sigma`` times the filtered noise below the fainter peak;
otherwise it is a bump on the brighter star's profile and is dropped.
Kept candidates with another kept candidate within ``radius`` are marked
blended.

The local-maximum test reads each pixel's two row neighbours first: a
smooth filtered image has about one row maximum per row of a star's
image, so only those few read the six pixels of the rows above and below.

Only pixels above the threshold are visited (gathered into buffers of
``pixel_capacity`` entries): each slab of the comparison marks the words of
its mask holding a pixel above while they are still in the core's cache, so
the gathering needs no further pass over the whole mask. When more pixels
than that exceed it (a frame washed by light), the threshold is doubled
until they fit and the frame is marked crowded (the threshold's height
above the background is doubled by the caller's ``raise_threshold``).
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout
from tracker.detect.slabs import SlabRunner

__all__ = ["PeakFinder"]

# the rows above and below a pixel (the three before it in raster order, then the three
# after); its own row's two neighbours are read first, at offsets -1 and +1
_ACROSS = ((-1, -1), (-1, 0), (-1, 1), (1, -1), (1, 0), (1, 1))
_BEFORE = 3
_LINE_STEPS = (0.25, 0.5, 0.75)
_MAX_DOUBLINGS = 12


class PeakFinder:
    """Local maxima of a filtered image held in padded buffers of ``layout``.

    The threshold test runs on the row slabs of ``slabs``
    (tracker.detect.slabs), if given. The image and its threshold are of
    ``dtype`` (float32, or uint16 for a search of the unfiltered frame).
    """

    def __init__(self, layout: PaddedLayout, radius: int, dip_sigma: float,
                 pixel_capacity: int, capacity: int, slabs: SlabRunner | None = None,
                 dtype: type = np.float32) -> None:
        self.slabs = slabs or SlabRunner(layout.rows, layout.cols, 0, 1, np.float32)
        self.layout = layout
        self.stride = layout.stride
        self.dip_sigma = float(dip_sigma)
        self.pixel_capacity = int(pixel_capacity)
        self.capacity = int(capacity)
        self.mask_pad, self.mask = layout.buffer(np.uint8)
        self.words = layout.word_marks()   # the mask's words holding a pixel above
        self.pixels = np.zeros(self.pixel_capacity, np.intp)
        self.pixel_values = np.zeros(self.pixel_capacity, dtype)
        self.positions = np.arange(self.pixel_capacity, dtype=np.intp)
        self.side_index = np.zeros(self.pixel_capacity, np.intp)
        self.side = np.zeros(self.pixel_capacity, dtype)
        self.row_max = np.zeros(self.pixel_capacity, np.intp)   # positions among pixels
        self.neighbour_index = np.zeros((self.pixel_capacity, len(_ACROSS)), np.intp)
        self.neighbours = np.zeros((self.pixel_capacity, len(_ACROSS)), dtype)
        self.before = np.zeros(self.pixel_capacity, dtype)
        self.after = np.zeros(self.pixel_capacity, dtype)
        self.is_max = np.zeros(self.pixel_capacity, np.bool_)
        self.tmp = np.zeros(self.pixel_capacity, np.bool_)
        self.below = np.zeros(self.pixel_capacity, np.bool_)
        self.offsets_across = np.array([dy * self.stride + dx for dy, dx in _ACROSS], np.intp)
        self.cand = np.zeros(self.capacity, np.intp)
        self.cand_values = np.zeros(self.capacity, np.float32)
        self.cand_noise = np.zeros(self.capacity, np.float32)
        self.cand_bg = np.zeros(self.capacity, np.float32)
        self.cand_rows = np.zeros(self.capacity, np.intp)
        self.cand_cols = np.zeros(self.capacity, np.intp)
        self.by_flat = np.zeros(self.capacity, np.intp)    # candidates in raster order
        self.sorted_flat = np.zeros(self.capacity, np.intp)
        self.nearest = np.zeros(self.capacity, np.intp)
        self.has = np.zeros(self.capacity, np.bool_)
        self.line_index = np.zeros((self.capacity, len(_LINE_STEPS)), np.intp)
        self.line_values = np.zeros((self.capacity, len(_LINE_STEPS)), dtype)
        self.saddle = np.zeros(self.capacity, np.float32)
        self.keep = np.zeros(self.capacity, np.bool_)
        self.blended = np.zeros(self.capacity, np.bool_)
        self.crowded = False
        self._n_pixels = 0
        self.configure(radius)

    def configure(self, radius: int) -> None:
        """Pairs: candidates closer than ``radius`` px (less than the layout's padding)."""
        if int(radius) >= self.layout.pad:
            raise ValueError(f"pair radius {radius} px reaches beyond the padding "
                             f"({self.layout.pad} px)")
        self.radius = int(radius)

    def find(self, filt_pad: np.ndarray, filt: np.ndarray, threshold: np.ndarray,
             bg_pad: np.ndarray, raise_threshold, noise_at, finish=None) -> int:
        """Candidates into ``cand[:n]`` (padded flat indices, brightest first); returns n.

        ``filt`` is the interior view of ``filt_pad``, the filtered image with
        its background, which ``bg_pad`` holds; ``threshold``
        (frame shape, float32) the detection level, background
        included; ``raise_threshold(factor)`` refills it with its height above
        the background multiplied by ``factor`` (used when crowded);
        ``noise_at(flat, out)`` gives the filtered noise at padded flat
        indices. ``cand_values[:n]`` are filtered values above the
        background. ``finish(first, end)``, if given, completes the
        threshold's frame rows [first, end) before they are compared: each
        slab of the comparison calls it on its own rows, in its own thread,
        after every (re)filling of the threshold. Sets ``blended[:n]`` and
        ``crowded``.
        """
        self.crowded = False
        n = self._above(filt, threshold, raise_threshold, finish)
        n = self._local_maxima(n, filt_pad)
        n = self._rank(n, bg_pad, noise_at)
        return self._deblend(n, filt_pad)

    def _compare(self, filt: np.ndarray, threshold: np.ndarray, finish=None) -> None:
        self.slabs.rows(lambda a, b: self._compare_rows(filt, threshold, a, b, finish))

    def _compare_rows(self, filt: np.ndarray, threshold: np.ndarray, a: int, b: int,
                      finish) -> None:
        """mask = filt > threshold on frame rows [a, b) (a slab; ``finish`` as
        :meth:`find`'s), and the words of its mask holding a pixel above marked in
        ``words`` while they are in the core's cache."""
        if finish is not None:
            finish(a, b)
        cv2.compare(filt[a:b], threshold[a:b], cv2.CMP_GT, dst=self.mask[a:b])
        pad = self.layout.pad
        self.layout.mark_words(self.mask_pad, pad + a, pad + b, self.words)

    def _above(self, filt: np.ndarray, threshold: np.ndarray, raise_threshold,
               finish=None) -> int:
        self._compare(filt, threshold, finish)
        n = self.layout.nonzero(self.mask_pad, self.pixels, marks=self.words)
        doublings = 0
        while n > self.pixel_capacity and doublings < _MAX_DOUBLINGS:
            self.crowded = True
            doublings += 1
            raise_threshold(2.0 ** doublings)
            self._compare(filt, threshold, finish)
            n = self.layout.nonzero(self.mask_pad, self.pixels, marks=self.words)
        if n > self.pixel_capacity:
            n = 0
        self._n_pixels = n
        return n

    def _local_maxima(self, n: int, filt_pad: np.ndarray) -> int:
        """Mark in ``is_max[:n]`` the pixels above their four neighbours before them in
        raster order and not below the four after; returns how many. The row's two
        first, then the rows above and below for the maxima along the row alone."""
        if n == 0:
            return 0
        flat = filt_pad.ravel()
        idx = self.pixels[:n]
        v = self.pixel_values[:n]
        np.take(flat, idx, out=v, mode="clip")
        is_max, tmp = self.is_max[:n], self.tmp[:n]
        side_index, side = self.side_index[:n], self.side[:n]
        np.subtract(idx, 1, out=side_index)
        np.take(flat, side_index, out=side, mode="clip")
        np.greater(v, side, out=is_max)
        np.add(idx, 1, out=side_index)
        np.take(flat, side_index, out=side, mode="clip")
        np.greater_equal(v, side, out=tmp)
        np.logical_and(is_max, tmp, out=is_max)
        m = int(np.count_nonzero(is_max))
        if m == 0:
            return 0
        along = self.row_max[:m]
        np.compress(is_max, self.positions[:n], out=along)
        at, values = self.side_index[:m], self.side[:m]     # free once the row is read
        np.take(idx, along, out=at, mode="clip")
        np.take(v, along, out=values, mode="clip")
        nb_index = self.neighbour_index[:m]
        np.add(at[:, None], self.offsets_across[None, :], out=nb_index)
        nb = self.neighbours[:m]
        np.take(flat, nb_index, out=nb, mode="clip")
        before, after = self.before[:m], self.after[:m]
        np.max(nb[:, :_BEFORE], axis=1, out=before)
        np.max(nb[:, _BEFORE:], axis=1, out=after)
        found, below = self.tmp[:m], self.below[:m]
        np.greater(values, before, out=found)
        np.greater_equal(values, after, out=below)
        np.logical_and(found, below, out=found)
        np.put(is_max, along, found)
        return int(np.count_nonzero(found))

    def _rank(self, m: int, bg_pad: np.ndarray, noise_at) -> int:
        """Maxima sorted by filtered value above the background, brightest first.

        At most ``capacity`` of them.
        """
        if m == 0:
            return 0
        n_px = self._n_pixels
        maxima = np.compress(self.is_max[:n_px], self.pixels[:n_px])
        values = np.subtract(np.compress(self.is_max[:n_px], self.pixel_values[:n_px]),
                             np.take(bg_pad.ravel(), maxima, mode="clip"), dtype=np.float32)
        order = np.argsort(-values, kind="stable")[: self.capacity]
        if m > self.capacity:
            self.crowded = True
        n = len(order)
        np.take(maxima, order, out=self.cand[:n])
        np.take(values, order, out=self.cand_values[:n])
        np.take(bg_pad.ravel(), self.cand[:n], out=self.cand_bg[:n], mode="clip")
        noise_at(self.cand[:n], self.cand_noise[:n])
        return n

    def _pairs(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Every ordered pair (i, j), i != j, of ``cand[:n]`` within ``radius`` px.

        Candidates in raster order; for each candidate and each row offset dy
        within the radius, the run of candidates on that row within
        sqrt(radius^2 - dy^2) columns is found by bisection (the padding is
        wider than the radius, so a run never reaches into another row): work
        in proportion to the candidates times the rows of the circle, plus the
        pairs found, not to the circle's area. Temporaries are of that size.
        """
        cand, r = self.cand[:n], self.radius
        by_flat, sorted_flat = self.by_flat[:n], self.sorted_flat[:n]
        by_flat[:] = np.argsort(cand, kind="stable")
        np.take(cand, by_flat, out=sorted_flat)
        dy = np.arange(-r, r + 1)
        reach = np.floor(np.sqrt(r * r - dy * dy)).astype(np.intp)
        centre = cand[:, None] + (dy * self.stride)[None, :]
        start = np.searchsorted(sorted_flat, centre - reach, side="left").ravel()
        counts = np.searchsorted(sorted_flat, centre + reach, side="right").ravel() - start
        first = np.cumsum(counts) - counts
        j = by_flat[np.arange(int(counts.sum())) + np.repeat(start - first, counts)]
        i = np.repeat(np.arange(n), counts.reshape(n, -1).sum(axis=1))
        other = i != j
        return i[other], j[other]

    def _deblend(self, n: int, filt_pad: np.ndarray) -> int:
        """Drop bumps on brighter stars; mark close pairs blended; compact; returns count.

        Candidates are ranked brightest first, so of a candidate's pairs those
        with a lower index are the brighter, and the lowest is the brightest.
        """
        if n == 0:
            return 0
        cand = self.cand[:n]
        i, j = self._pairs(n)
        brighter = j < i
        nearest, has = self.nearest[:n], self.has[:n]
        nearest.fill(n)
        np.minimum.at(nearest, i[brighter], j[brighter])
        np.less(nearest, n, out=has)
        np.copyto(nearest, np.arange(n), where=~has)   # a line to itself: kept anyway
        rows, cols = self.cand_rows[:n], self.cand_cols[:n]
        np.divmod(cand, self.stride, out=(rows, cols))
        dy, dx = rows[nearest] - rows, cols[nearest] - cols
        line_index = self.line_index[:n]
        for k, t in enumerate(_LINE_STEPS):
            line_index[:, k] = (cand + np.rint(t * dy) * self.stride
                                + np.rint(t * dx)).astype(np.intp)
        line = self.line_values[:n]
        np.take(filt_pad.ravel(), line_index, out=line, mode="clip")
        saddle = self.saddle[:n]
        np.min(line, axis=1, out=saddle)
        np.subtract(saddle, self.cand_bg[:n], out=saddle)  # the background at the candidate
        values, noise = self.cand_values[:n], self.cand_noise[:n]
        np.minimum(saddle, values, out=saddle)
        keep = self.keep[:n]
        np.greater_equal(values - saddle, self.dip_sigma * noise, out=keep)
        np.logical_or(keep, ~has, out=keep)
        # blended: another kept candidate within the radius
        blended = self.blended[:n]
        np.greater(np.bincount(i, weights=keep[j], minlength=n), 0, out=blended)
        k = int(np.count_nonzero(keep))
        for arr in (self.cand, self.cand_values, self.cand_noise, self.blended):
            arr[:k] = np.compress(keep, arr[:n])
        return k
