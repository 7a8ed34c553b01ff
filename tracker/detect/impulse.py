"""Hot pixels, cosmic-ray hits and salt-and-pepper noise: found and replaced.

A pixel is an impulse when it differs from the median of its 3x3
neighbourhood by more than ``k_sigma`` times the local noise AND by more
than the fraction ``contrast`` of its height above the background (for a
pixel darker than its median: of the median's height). A star's light is
spread by the optics, so its brightest pixel stands above the 3x3 median by
only part of its height (0.26 for a centred Gaussian PSF of sigma 1.2 px,
:func:`psf_contrast`); a hot pixel, or a cosmic-ray track one pixel wide,
stands above it by all of its height. The cut-off sits between the two.
Impulses are replaced by their 3x3 median. Once the frame's PSF is known
(:meth:`ImpulseFilter.refine`) a pixel above its median by the limit is an
impulse also when its eight neighbours hold less than half the light a
star of that PSF puts there (:func:`psf_ring`): the contrast alone cannot
tell a hot pixel from a sharp star whose light falls on a pixel's corner.

Impulses are counted. Those of added charge (above their median) are
split: one with no such impulse among its 8 neighbours is a hot pixel (or a
one-pixel hit); a group of touching ones is one cosmic-ray hit, counted at
its first pixel in raster order (one with none to its left or in the row
above; a group shaped like a "U" counts twice). Dark impulses (dead pixels,
pepper) are neither, and never part of a track. Tracks wider than one pixel
survive the 3x3 median and are left to the detector's shape test.

The test runs on the few pixels that differ from their median by more than
``k_sigma`` times the local noise, gathered into fixed buffers of
``capacity`` entries. When there are more (a frame full of salt-and-pepper
noise) it runs on the whole frame instead and counts only ``impulse_pixels``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout
from tracker.detect.slabs import SlabRunner

__all__ = ["ImpulseFilter", "psf_contrast", "psf_ring"]


def psf_contrast(sigma_px: float, worst_phase: bool = False) -> float:
    """(peak - 3x3 median) / peak of a pixel-integrated Gaussian PSF's brightest pixel.

    For a star centred on a pixel, or with ``worst_phase`` the largest over
    its sub-pixel phase (on an edge, a corner, between): a star centred on an
    edge shares its light between two pixels, each standing far above a
    median of fainter wings.
    """
    phases = (((0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.25, 0.0), (0.25, 0.25))
              if worst_phase else ((0.0, 0.0),))
    worst = 0.0
    for px, py in phases:
        wx = np.diff([math.erf((e - px) / (sigma_px * math.sqrt(2.0)))
                      for e in (-2.5, -1.5, -0.5, 0.5, 1.5, 2.5)])
        wy = np.diff([math.erf((e - py) / (sigma_px * math.sqrt(2.0)))
                      for e in (-2.5, -1.5, -0.5, 0.5, 1.5, 2.5)])
        stamp = np.outer(wy, wx)
        r, c = np.unravel_index(np.argmax(stamp), stamp.shape)
        window = stamp[r - 1:r + 2, c - 1:c + 2]
        worst = max(worst, float(1.0 - np.median(window) / stamp[r, c]))
    return worst


def psf_ring(sigma_px: float) -> float:
    """Light in the 8 neighbours of a pixel-integrated Gaussian PSF's brightest pixel, over
    that pixel's: the least over sub-pixel phase (a star centred on a pixel).

    A hot pixel has only noise around it; a star however sharp has its wings
    there (0.86 of its peak at sigma 0.45 px, 1.75 at 0.6 px).
    """
    least = math.inf
    for px, py in ((0.0, 0.0), (0.5, 0.0), (0.5, 0.5), (0.25, 0.0), (0.25, 0.25)):
        edges = (-2.5, -1.5, -0.5, 0.5, 1.5, 2.5)
        wx = np.diff([math.erf((e - px) / (sigma_px * math.sqrt(2.0))) for e in edges])
        wy = np.diff([math.erf((e - py) / (sigma_px * math.sqrt(2.0))) for e in edges])
        stamp = np.outer(wy, wx)
        r, c = np.unravel_index(np.argmax(stamp), stamp.shape)
        peak = stamp[r, c]
        least = min(least, float(stamp[r - 1:r + 2, c - 1:c + 2].sum() - peak) / peak)
    return least


class _TestBuffers:
    """Scratch space for :func:`_impulse_test` on arrays of one shape."""

    def __init__(self, shape: tuple[int, ...]) -> None:
        self.t1 = np.zeros(shape, np.float32)
        self.t2 = np.zeros(shape, np.float32)
        self.b1 = np.zeros(shape, np.bool_)
        self.out = np.zeros(shape, np.bool_)


def _impulse_test(w: np.ndarray, m: np.ndarray, b: np.ndarray, limit: np.ndarray,
                  contrast: float, buf: _TestBuffers, n: int) -> np.ndarray:
    """|w - m| > limit and |w - m| > contrast (max(w, m) - b), on the first n rows.

    Computed in float32 whatever the inputs' dtypes.
    """
    t1, t2, b1, out = buf.t1[:n], buf.t2[:n], buf.b1[:n], buf.out[:n]
    np.subtract(w, m, out=t1, dtype=np.float32)
    np.abs(t1, out=t1)
    np.maximum(w, m, out=t2)
    np.subtract(t2, b, out=t2)
    np.multiply(t2, contrast, out=t2)
    np.greater(t1, t2, out=out)
    np.greater(t1, limit, out=b1)
    np.logical_and(out, b1, out=out)
    return out


def _median3(src: np.ndarray, dst: np.ndarray) -> None:
    cv2.medianBlur(src, 3, dst=dst)


# Neighbour offsets (dy, dx): all eight, the four met before a pixel in raster order first.
_EIGHT = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
_RING = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)   # a pixel's eight neighbours
_REFINE_PASSES = 2
_GROW_STEPS = 2        # rounds of adding the neighbours of replaced pixels
_GROW_LIMIT = 0.5      # ... tested against this fraction of the first pass's limit
_TRACK_REMNANT = 0.2   # a track pixel whose replacement keeps under this of its height: sky
_CUT_ROWS = 32         # rows of the first cut's difference made and compared at a time
_CHARGE_DIFFUSION_PX = 0.45   # a particle's charge spreads by this (Gaussian sigma) ...
_WING_SHARE = 0.5      # ... and a hit's neighbours hold at least this of what that puts there


class ImpulseFilter:
    """Finds and replaces impulses in frames held in padded buffers of ``layout``.

    Frames, their limits and the median are of ``dtype`` (float32 or uint16);
    the median runs in ``threads`` slabs (tracker.detect.slabs).
    """

    def __init__(self, layout: PaddedLayout, contrast: float, capacity: int,
                 dtype: type = np.float32, threads: int = 1,
                 full_scale: float | None = None) -> None:
        self.layout = layout
        self.contrast = float(contrast)
        self.full_scale = full_scale   # the whole-frame pass's lone full-scale pixels
        self.top = np.zeros(layout.full_shape, np.uint8)
        self.near_top = np.zeros(layout.full_shape, np.uint8)
        self.capacity = int(capacity)
        self.median_pad, self.median = layout.buffer(dtype)
        self.mask_pad, self.mask = layout.buffer(np.uint8)
        self.slabs = SlabRunner(layout.rows, layout.cols, 1, threads, dtype)
        # |work - median| of _CUT_ROWS rows at a time, one scratch per slab (by its first
        # row): it stays in the core's cache between its making and its comparison
        self.cut_scratch = {a: np.zeros((_CUT_ROWS, layout.cols), dtype)
                            for a, _ in self.slabs.slabs}
        self.cut_words = layout.word_marks()   # the mask's words holding a candidate
        self.dense = _TestBuffers(layout.full_shape)
        self.sparse = _TestBuffers((self.capacity,))
        self.index = np.zeros(self.capacity, np.intp)
        self.values = np.zeros((4, self.capacity), np.float32)
        self.reads = np.zeros(self.capacity, dtype)
        stride = layout.stride
        self.neighbour_offsets = np.array([dy * stride + dx for dy, dx in _EIGHT], np.intp)
        self.marks = np.zeros(layout.full_shape[0] * stride, np.uint8)
        self.neighbour_index = np.zeros((self.capacity, 8), np.intp)
        self.window_index = np.zeros((self.capacity, 9), np.intp)
        self.window_offsets = np.array([dy * stride + dx for dy in (-1, 0, 1)
                                        for dx in (-1, 0, 1)], np.intp)
        self.window_values = np.zeros((self.capacity, 9), dtype)
        self.replaced = np.zeros(self.capacity, np.bool_)
        self.height = np.zeros(self.capacity, np.float32)   # first read above the background
        self.stale = np.zeros(self.capacity, np.bool_)     # to be judged again (_retest)
        self.sub_index = np.zeros(self.capacity, np.intp)   # _retest_some's candidates
        self.sub_values = np.zeros((4, self.capacity), np.float32)
        self.sub_flags = np.zeros(self.capacity, np.bool_)
        self.charge = np.zeros(self.capacity, np.bool_)   # replaced, and above its median
        self.ring = np.zeros(self.capacity, np.float32)
        self.lone = np.zeros(self.capacity, np.bool_)
        self._dense = False
        self.flags = np.zeros(self.capacity, np.bool_)
        self.tmp_flags = np.zeros(self.capacity, np.bool_)
        # growing and clearing tracks: up to 9 pixels around each candidate
        self.area = np.zeros(9 * self.capacity, np.intp)
        self.area_values = np.zeros((3, 9 * self.capacity), np.float32)
        self.area_reads = np.zeros(9 * self.capacity, dtype)
        self.area_high = np.zeros(9 * self.capacity, np.bool_)
        self.area_marks = np.zeros(9 * self.capacity, np.uint8)
        self.numbers = np.arange(1, 9 * self.capacity + 1, dtype=np.int32)
        self.stamp = np.zeros(layout.full_shape[0] * stride, np.int32)
        self.stamp_reads = np.zeros(9 * self.capacity, np.int32)
        self._n = 0
        self.neighbours = np.zeros((self.capacity, 8), np.uint8)
        # how many of each pixel's eight neighbours lie beyond the frame (_frame_ring): 3 on
        # its outer rows and columns, 5 at its corners, read by one gather, not worked out
        # from each candidate's row and column
        rows = np.arange(layout.full_shape[0]) - layout.pad
        cols = np.arange(layout.stride) - layout.pad
        self.beyond = np.add.outer(((rows == 0) | (rows == layout.rows - 1)).astype(np.uint8),
                                   ((cols == 0) | (cols == layout.cols - 1)).astype(np.uint8))
        np.multiply(self.beyond, 3, out=self.beyond)
        self.beyond[self.beyond == 6] = 5
        # a marked neighbour among the four before each pixel in raster order, among the
        # four after it (and, once or'ed, among all eight), read as whole words of the
        # neighbours' marks (_EIGHT's order puts those before first): a fifth of the time
        # of a max over each row's bytes
        self.neighbour_words = self.neighbours.view(np.uint32)     # (capacity, 2)
        self.any_before = np.zeros(self.capacity, np.bool_)
        self.any_after = np.zeros(self.capacity, np.bool_)
        self.counts = {"impulse_pixels": 0, "hot_pixels": 0, "cosmic_rays": 0}
        self._median_wait = None
        self._listed = 0   # the last cut's candidates
        self._refined = 0  # the last refine's candidates, grown ones included

    def start_median(self, work: np.ndarray) -> None:
        """Begin the 3x3 median of ``work`` (the frame :meth:`cut` will be given, already
        final) on a worker thread, for :meth:`cut` to collect: the caller's other work
        (the background's statistics) overlaps it. Same median as :meth:`cut` makes."""
        self._median_wait = self.slabs.start(_median3, work, self.median)

    def run(self, work_pad: np.ndarray, work: np.ndarray, bg_pad: np.ndarray,
            limit_pad: np.ndarray, limit: np.ndarray) -> dict:
        """Replace impulses in ``work`` (interior view of ``work_pad``) in place; counts.

        ``limit_pad`` (padded like ``work_pad``; ``limit`` its interior view)
        is ``k_sigma`` times the local pixel noise; ``bg_pad`` (float32) the
        background. :meth:`cut`, then :meth:`test`.
        """
        self.cut(work, limit)
        return self.test(work_pad, bg_pad, limit_pad)

    def cut(self, work: np.ndarray, limit: np.ndarray) -> None:
        """List the candidates of :meth:`test`: the pixels of ``work`` (interior view)
        differing from their 3x3 median by more than ``limit`` (its interior view).
        Needs no background: a caller may make the background meanwhile."""
        if self._median_wait is None:
            self.slabs.run(_median3, work, self.median)
        else:
            self._median_wait()
            self._median_wait = None
        self.slabs.rows(lambda a, b: self._first_cut(work[a:b], limit[a:b], a, b))
        self._listed = self.layout.nonzero(self.mask_pad, self.index, marks=self.cut_words)

    def test(self, work_pad: np.ndarray, bg_pad: np.ndarray, limit_pad: np.ndarray,
             split: bool = True) -> dict:
        """Replace the impulses among the last :meth:`cut`'s candidates; counts (arguments
        as :meth:`run`'s). ``split`` false: ``impulse_pixels`` only, for a caller that
        calls :meth:`refine` next, which counts them all again."""
        counts = self.counts
        for key in counts:
            counts[key] = 0
        self._n = self._refined = 0
        self._dense = False
        n = self._listed
        if n == 0:
            return counts
        if n > self.capacity:
            self._dense = True
            imp = _impulse_test(work_pad, self.median_pad, bg_pad, limit_pad, self.contrast,
                                self.dense, work_pad.shape[0])
            if self.full_scale is not None:
                imp |= self._lone_full_scale(work_pad)
            np.copyto(work_pad, self.median_pad, where=imp)
            counts["impulse_pixels"] = int(np.count_nonzero(imp))
            return counts
        self._sparse(n, work_pad, bg_pad, limit_pad, split)
        return counts

    def _lone_full_scale(self, work_pad: np.ndarray) -> np.ndarray:
        """Pixels at full scale none of whose eight neighbours is (a view of a buffer).

        In a frame dense with impulses (the whole-frame pass) such a pixel is a
        grain of salt, also where it falls on a star's core and stands above
        its median by less than the contrast test asks (a core of 150 of 255
        ADU under a grain reads 255: 0.4 of its height above the median). A
        star's own light clips a plateau: its neighbours reach 0.7 of its
        peak under a 1.2 px PSF, so a star clips a lone pixel only while its
        peak is under 1.4 x full scale, and the median then takes a fraction
        of a peak already cut by the clip.
        """
        top = self.dense.b1
        np.greater_equal(work_pad, self.full_scale, out=top)
        np.copyto(self.top, top, casting="unsafe")
        cv2.dilate(self.top, _RING, dst=self.near_top, borderType=cv2.BORDER_CONSTANT,
                   borderValue=0)
        np.logical_and(top, self.near_top == 0, out=top)
        return top

    def spared_maxima(self, work_pad: np.ndarray, bg_pad: np.ndarray) -> np.ndarray | None:
        """Padded flat indices of the last :meth:`run`'s candidates it did not replace that
        are local maxima of ``work_pad`` (not below any of their eight neighbours), or None
        after a whole-frame pass (no list was kept).

        A star's peak stands above its 3x3 median by more than the limit once it is a
        few times the noise, and the contrast test spares it: the bright stars of a
        frame are among these, found without another pass over the frame.
        """
        if self._dense:
            return None
        n = self._n
        if n == 0:
            return self.index[:0]
        # A maximum is not below its 3x3 median, and a candidate differs from it: only
        # those above it (the spared ones keep their value, the replaced ones now equal
        # it) are looked at, about a third of the list, in raster order as listed.
        above = self.flags[:n]
        np.greater(self.values[0, :n], self.values[1, :n], out=above)
        k = int(np.count_nonzero(above))
        idx = self.area[:k]
        np.compress(above, self.index[:n], out=idx)
        flat = work_pad.ravel()
        nb_index = self.neighbour_index[:k]
        np.add(idx[:, None], self.neighbour_offsets[None, :], out=nb_index)
        np.take(flat, nb_index, out=self.window_values[:k, :8], mode="clip")
        np.max(self.window_values[:k, :8], axis=1, out=self.reads[:k])
        np.take(flat, idx, out=self.window_values[:k, 8], mode="clip")
        peak = self.flags[:k]
        np.greater_equal(self.window_values[:k, 8], self.reads[:k], out=peak)
        return np.compress(peak, idx)

    def refine(self, work_pad: np.ndarray, bg_pad: np.ndarray, limit_pad: np.ndarray,
               contrast: float, ring: float = 0.0, mirror_pad: np.ndarray | None = None) -> dict:
        """Test the last :meth:`run`'s candidates again with ``contrast``, and grow; counts.

        ``mirror_pad``: a float32 copy of ``work_pad`` (padded alike) made after
        :meth:`run`; every pixel this pass rewrites is rewritten there too, so
        it stays a copy without another pass over the frame.

        ``ring``: a candidate above its median by the limit whose eight
        neighbours hold less than ``ring`` times its height above the
        background is an impulse too (0: no such test).

        :meth:`run` must use a contrast safe for the sharpest PSF the frame
        might have; once the frame's own PSF is known, a lower contrast (a
        star of that PSF can stand only so far above its 3x3 median) catches
        impulses on star wings and the partners of touching impulses, whose
        median the first pass's replacements have since lowered. Each
        replaced pixel takes the median of its neighbourhood as it now is (a
        track's neighbours were replaced too, so its first median was too
        high). Then the replaced pixels' neighbours join the candidates with
        half the limit (``limit_pad`` is ``k_sigma`` times the noise): the
        wings of a track whose charge diffused over two or three pixels,
        which stand out only once its core is gone. Only the sparse path is
        refined; after a whole-frame pass nothing changes.
        """
        n = self._n
        if n == 0:
            return self.counts
        self.stale[:n] = True           # every candidate is judged with the new cut
        for step in range(_GROW_STEPS + 1):
            if step:
                listed = n
                n = self._grow(n, work_pad, bg_pad, limit_pad)
                self.stale[listed:n] = True
            self._retest(n, work_pad, min(contrast, self.contrast), ring)
        self._count(n, self.index[:n], self.replaced[:n], self.charge[:n])
        if mirror_pad is not None:
            self._mirror(self.index[:n], self.reads[:n], work_pad, mirror_pad)
        self._clear_tracks(n, work_pad, bg_pad, limit_pad, mirror_pad)
        self._refined = n
        return self.counts

    def particle_hits(self, work_pad: np.ndarray, bg_pad: np.ndarray) -> tuple[np.ndarray,
                                                                             np.ndarray]:
        """The pixels the last :meth:`refine` replaced for added charge whose eight
        neighbours still hold a particle's diffused charge (padded flat indices,
        ascending), and how far each first stood above the median that replaced it, ADU
        (:meth:`retest_lone`'s convention).

        A particle's charge diffuses by about 0.45 px: its eight neighbours hold at
        least ``psf_ring(0.45)`` (0.86) of its core's height, a hot pixel's nothing.
        Where the core was replaced as a lone impulse those wings are left, and a spot
        found on them is the hit's remnant, not a star; a pixel whose neighbours now
        hold under ``_WING_SHARE`` of that (half: their noise and the median's share
        of them) had no wings, and a star under it is a star. Empty before
        :meth:`refine` or after a whole-frame pass.
        """
        n = self._refined
        k = int(np.count_nonzero(self.charge[:n]))
        hit = np.compress(self.charge[:n], self.index[:n])
        # first height above the background less the median's: the first value less it
        excess = np.compress(self.charge[:n], self.height[:n]
                             - (self.values[1, :n] - self.values[2, :n]))
        window = self.area[: 8 * k].reshape(k, 8)
        np.add(hit[:, None], self.neighbour_offsets[None, :], out=window)
        wings = (np.take(work_pad.ravel(), window, mode="clip").astype(np.float32).sum(axis=1)
                 - 8.0 * np.take(bg_pad.ravel(), hit, mode="clip"))
        particle = wings >= _WING_SHARE * psf_ring(_CHARGE_DIFFUSION_PX) * excess
        hit, excess = hit[particle], excess[particle]
        order = np.argsort(hit, kind="stable")
        return hit[order], excess[order]

    def retest_lone(self, work_pad: np.ndarray, contrast: float, ring: float,
                    mirror_pad: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Test the last :meth:`run`'s candidates not yet replaced, and with no replaced
        pixel of added charge beside them, again as lone impulses against ``contrast``
        and ``ring`` (:meth:`refine`'s tests, for a PSF measured since); replace those
        of added charge that fail by their 3x3 median (in ``mirror_pad`` too).

        Returns the replaced pixels (padded flat indices, ascending) and how far each
        stood above its median, ADU. Tracks are left as :meth:`refine` left them;
        after a whole-frame pass nothing changes.
        """
        n = self._n
        if n == 0:
            return self.index[:0], self.values[0, :0]
        idx = self.index[:n]
        self._any_marked(n, idx, self.charge[:n])
        w, m, b, lim = (v[:n] for v in self.values)
        window = self.window_values[:n]
        np.add(idx[:, None], self.window_offsets[None, :], out=self.window_index[:n])
        np.take(work_pad.ravel(), self.window_index[:n], out=window, mode="clip")
        around = self.ring[:n]
        np.sum(window, axis=1, out=around, dtype=np.float32)
        np.subtract(around, window[:, 4], out=around)
        np.subtract(around, 8.0 * b, out=around)        # the neighbours' light
        np.copyto(w, window[:, 4])
        window.partition(4, axis=1)
        np.copyto(m, window[:, 4])
        imp = _impulse_test(w, m, b, lim, contrast, self.sparse, n)
        t1, lone = self.sparse.t1[:n], self.lone[:n]
        np.subtract(w, b, out=t1)
        np.multiply(t1, ring, out=t1)
        self._frame_ring(idx, b, around, t1)
        np.less(around, t1, out=lone)                   # its neighbours dark for a star
        np.logical_and(lone, w - m > lim, out=lone)
        np.logical_or(imp, lone, out=imp)
        imp &= (w > m) & ~self.replaced[:n] & ~self.any_after[:n]
        hit = np.compress(imp, idx)
        median_of = np.compress(imp, m)
        np.put(work_pad.ravel(), hit, median_of.astype(work_pad.dtype), mode="clip")
        if mirror_pad is not None:
            np.put(mirror_pad.ravel(), hit, median_of, mode="clip")
        self.replaced[:n] |= imp
        self.charge[:n] |= imp
        return hit, np.compress(imp, w) - median_of

    def _frame_ring(self, idx: np.ndarray, b: np.ndarray, around: np.ndarray,
                    needed: np.ndarray) -> None:
        """The lone test on the frame's outer rows and columns: of a candidate there
        (padded flat indices ``idx``) only the neighbours inside the frame are read.

        ``around`` holds the eight neighbours' light less 8 times the background
        ``b`` and ``needed`` the light a star would put in all eight; the pixels
        beyond the frame read zero and hold no background, and a star's light there
        is not seen: both are set, in place, for the neighbours the frame holds (a
        star centred beyond the edge put half of its light in the border pixel and
        the rest beyond, and read as a lone hot pixel whose eighth neighbours were
        dark).
        """
        beyond = np.take(self.beyond.ravel(), idx, mode="clip")
        at = np.flatnonzero(beyond)
        if len(at) == 0:
            return
        # one edge: 3 of 8 neighbours beyond it; a corner: 5
        beyond = beyond[at].astype(np.float64)
        around[at] += beyond * b[at]
        needed[at] *= (8.0 - beyond) / 8.0

    @staticmethod
    def _mirror(idx: np.ndarray, reads: np.ndarray, work_pad: np.ndarray,
                mirror_pad: np.ndarray) -> None:
        """Copy the pixels ``idx`` of ``work_pad`` into ``mirror_pad`` (``reads``: scratch
        of idx's length and work_pad's dtype)."""
        np.take(work_pad.ravel(), idx, out=reads, mode="clip")
        np.put(mirror_pad.ravel(), idx, reads, mode="clip")

    def _clear_tracks(self, n: int, work_pad: np.ndarray, bg_pad: np.ndarray,
                      limit_pad: np.ndarray, mirror_pad: np.ndarray | None = None) -> None:
        """Set the 3x3 around every track pixel to the background where it stands above it.

        A track pixel is a replaced pixel with a replaced neighbour. Along a
        track two or three pixels wide the 3x3 medians that replaced it are
        themselves lifted by the track, and what is left (a faint ridge) is a
        star to the matched filter; the background has no such memory.
        Pixels more than half the limit above the background, and replaced
        pixels above it (medians of windows the track lifted), become the
        background (rounded); the rest are noise and stay. Only track pixels
        on open sky are cleared (their replacement is within the limit of the
        background, or under ``_TRACK_REMNANT`` of the pixel's first height:
        the median of a bright track's core and wings): on a star's core,
        where the spikes of speckle or a track across the star sit, the
        neighbourhood is the star's light.
        """
        idx = self.index[:n]
        track = self._track_pixels(n)
        # ... on open sky: its replacement (its neighbourhood's median) is within the
        # limit of the background, or under _TRACK_REMNANT of the height the pixel
        # first had (the median of a track's core and its diffused wings); on a
        # star's core (speckle, a track across a star) the neighbourhood is the star,
        # and it stays
        w, m, b, lim = (v[:n] for v in self.values)
        np.take(work_pad.ravel(), idx, out=self.reads[:n], mode="clip")
        np.copyto(w, self.reads[:n])
        np.subtract(w, b, out=w)
        np.less(w, lim, out=self.tmp_flags[:n])
        remnant = self.sparse.t2[:n]
        np.multiply(self.height[:n], _TRACK_REMNANT, out=remnant)
        np.less(w, remnant, out=self.sparse.b1[:n])
        np.logical_or(self.tmp_flags[:n], self.sparse.b1[:n], out=self.tmp_flags[:n])
        np.logical_and(track, self.tmp_flags[:n], out=track)
        k = int(np.count_nonzero(track))
        if k == 0:
            return
        area = self.area[: 9 * k].reshape(k, 9)
        np.add(np.compress(track, idx)[:, None], self.window_offsets[None, :], out=area)
        area = area.ravel()
        values, background, limit = (a[: 9 * k] for a in self.area_values)
        np.take(work_pad.ravel(), area, out=self.area_reads[: 9 * k], mode="clip")
        np.copyto(values, self.area_reads[: 9 * k])
        np.take(bg_pad.ravel(), area, out=background, mode="clip")
        np.take(limit_pad.ravel(), area, out=self.area_reads[: 9 * k], mode="clip")
        np.copyto(limit, self.area_reads[: 9 * k])
        np.subtract(values, background, out=values)
        np.multiply(limit, _GROW_LIMIT, out=limit)
        high = self.area_high[: 9 * k]
        np.greater(values, limit, out=high)
        # ... and the replaced pixels above it: a replacement is the median of a window
        # the track's wings lifted, and a patch of them a few ADU high is a faint star
        # to the matched filter (what noise is left there is the sky's, not raised)
        marks = self.marks
        np.put(marks, idx, self.replaced[:n].view(np.uint8), mode="clip")
        lifted = self.area_marks[: 9 * k]
        np.take(marks, area, out=lifted, mode="clip")
        np.put(marks, idx, 0, mode="clip")
        high |= (lifted > 0) & (values > 0.0)
        np.maximum(background, 0.0, out=background)
        np.rint(background, out=background)
        np.copyto(values, background)
        np.copyto(self.area_reads[: 9 * k], values, casting="unsafe")
        flat = work_pad.ravel()
        np.copyto(values, flat[0])                       # scratch not needed past here
        kept = np.compress(high, area)
        np.put(flat, kept, np.compress(high, self.area_reads[: 9 * k]), mode="clip")
        if mirror_pad is not None:
            self._mirror(kept, self.area_reads[: len(kept)], work_pad, mirror_pad)

    def _neighbour_marks(self, n: int, idx: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(n, 8) view: 1 where each listed pixel's neighbour (``_EIGHT`` order) is marked.

        ``mask`` (n,) marks the listed pixels ``idx``; the marks are cleared again.
        """
        marks = self.marks
        np.put(marks, idx, mask.view(np.uint8), mode="clip")
        nb_index = self.neighbour_index[:n]
        np.add(idx[:, None], self.neighbour_offsets[None, :], out=nb_index)
        nb = self.neighbours[:n]
        np.take(marks, nb_index, out=nb, mode="clip")
        np.put(marks, idx, 0, mode="clip")
        return nb

    def _any_marked(self, n: int, idx: np.ndarray,
                    mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether any of each listed pixel's four neighbours before it in raster order is
        marked, and (views of ``any_before`` and ``any_after``) any of all eight;
        arguments as :meth:`_neighbour_marks`'."""
        self._neighbour_marks(n, idx, mask)
        words = self.neighbour_words[:n]
        before, after = self.any_before[:n], self.any_after[:n]
        np.not_equal(words[:, 0], 0, out=before)
        np.not_equal(words[:, 1], 0, out=after)
        np.logical_or(before, after, out=after)
        return before, after

    def _track_pixels(self, n: int) -> np.ndarray:
        """Mask (a view of ``flags``) of the candidates replaced for added charge (above
        their median) with such a neighbour. A particle adds charge: a dark impulse
        beside a bright one (on a star's steep edge, where the 3x3 median is lifted
        on one side and lowered on the other) is no track."""
        replaced = self.charge[:n]
        self._any_marked(n, self.index[:n], replaced)
        track = self.flags[:n]
        np.logical_and(replaced, self.any_after[:n], out=track)
        return track

    def _retest(self, n: int, work_pad: np.ndarray, contrast: float, ring: float) -> None:
        """Up to ``_REFINE_PASSES`` passes of the tests over the ``stale`` candidates of the
        first ``n``: a candidate is judged again only when a pixel of its 3x3 window
        changed since it was last judged (its tests read nothing else that changes), so
        after the first pass only the few beside a replaced pixel are. The same
        outcome as judging every candidate in every pass. Those touched by the last
        pass's changes stay ``stale`` for the next call."""
        idx = self.index[:n]
        np.put(self.stamp, idx, self.numbers[:n], mode="clip")   # candidate number + 1
        for _ in range(_REFINE_PASSES):
            sel = np.flatnonzero(self.stale[:n])
            if len(sel) == 0:
                break
            self.stale[:n] = False
            changed = self._retest_some(sel, work_pad, contrast, ring)
            if len(changed):
                near = self.area[: 9 * len(changed)].reshape(len(changed), 9)
                np.add(changed[:, None], self.window_offsets[None, :], out=near)
                number = np.take(self.stamp, near.ravel(), mode="clip")
                self.stale[number[number > 0] - 1] = True
        np.put(self.stamp, idx, 0, mode="clip")

    def _retest_some(self, sel: np.ndarray, work_pad: np.ndarray, contrast: float,
                     ring: float) -> np.ndarray:
        """One pass of :meth:`refine`'s tests over the candidates ``sel`` (positions in the
        list); replaced pixels take their window's median. Returns the pixels whose value
        changed (padded flat indices)."""
        k = len(sel)
        idx = self.sub_index[:k]
        np.take(self.index, sel, out=idx)
        w, m, b, lim = (v[:k] for v in self.sub_values)
        np.take(self.values[2], sel, out=b)
        np.take(self.values[3], sel, out=lim)
        flat = work_pad.ravel()
        nb_index = self.window_index[:k]
        np.add(idx[:, None], self.window_offsets[None, :], out=nb_index)
        window = self.window_values[:k]
        np.take(flat, nb_index, out=window, mode="clip")
        around, lone = self.ring[:k], self.lone[:k]
        if ring > 0.0:
            # the neighbours' light above the background (the window less its centre)
            np.sum(window, axis=1, out=around, dtype=np.float32)
            np.subtract(around, window[:, 4], out=around)
            np.subtract(around, 8.0 * b, out=around)
        reads = self.reads[:k]
        np.copyto(reads, window[:, 4])                 # the candidates' own values
        window.partition(4, axis=1)
        np.copyto(m, window[:, 4])
        np.copyto(w, reads)
        replaced = self.sub_flags[:k]
        np.take(self.replaced, sel, out=replaced)
        np.copyto(w, m, where=replaced)
        imp = _impulse_test(w, m, b, lim, contrast, self.sparse, k)
        if ring > 0.0:
            t1, t2 = self.sparse.t1[:k], self.sparse.t2[:k]
            np.subtract(w, b, out=t1)                        # height
            np.multiply(t1, ring, out=t1)
            self._frame_ring(idx, b, around, t1)
            np.less(around, t1, out=lone)
            np.subtract(w, m, out=t2)
            np.greater(t2, lim, out=self.tmp_flags[:k])      # above its median by the limit
            np.logical_and(lone, self.tmp_flags[:k], out=lone)
            np.logical_or(imp, lone, out=imp)
        charge = self.tmp_flags[:k]
        np.greater(w, m, out=charge)                 # (a replaced pixel's w is m)
        np.logical_and(charge, imp, out=charge)
        np.logical_or(np.take(self.charge, sel), charge, out=charge)
        np.put(self.charge, sel, charge)
        np.copyto(w, m, where=imp)
        np.put(flat, idx, w, mode="clip")
        np.logical_or(replaced, imp, out=replaced)
        np.put(self.replaced, sel, replaced)
        np.put(self.values[0], sel, w)
        np.put(self.values[1], sel, m)
        return np.compress(w != reads, idx)

    def _grow(self, n: int, work_pad: np.ndarray, bg_pad: np.ndarray,
              limit_pad: np.ndarray) -> int:
        """Append the unlisted neighbours of track pixels (replaced pixels with a replaced
        neighbour) to the candidates; new count. A lone hot pixel has no wings to grow
        into, and growing from it would take the spiky pixels of faint stars in
        photon-starved frames."""
        idx = self.index[:n]
        replaced = self._track_pixels(n)
        hits = int(np.count_nonzero(replaced))
        room = self.capacity - n
        if hits == 0 or room <= 0:
            return n
        near = self.area[: 8 * hits].reshape(hits, 8)
        np.add(np.compress(replaced, idx)[:, None], self.neighbour_offsets[None, :], out=near)
        near = near.ravel()
        # keep each unlisted pixel once: every entry stamps its own number on its pixel,
        # and the entry whose number survives is the one kept
        stamp = self.stamp
        count = len(near)
        np.put(stamp, idx, -1, mode="clip")
        np.put(stamp, near, self.numbers[:count], mode="clip")
        np.put(stamp, idx, -1, mode="clip")
        own = self.area_reads[:count]
        keep = self.area_high[:count]
        np.take(stamp, near, out=self.stamp_reads[:count], mode="clip")
        np.equal(self.stamp_reads[:count], self.numbers[:count], out=keep)
        new_pixels = np.compress(keep, near)[:room]
        np.put(stamp, near, 0, mode="clip")
        np.put(stamp, idx, 0, mode="clip")
        del own
        k = len(new_pixels)
        if k == 0:
            return n
        new = slice(n, n + k)
        self.index[new] = new_pixels
        np.take(limit_pad.ravel(), new_pixels, out=self.reads[:k], mode="clip")
        np.multiply(self.reads[:k], _GROW_LIMIT, out=self.values[3][new], casting="unsafe")
        np.take(bg_pad.ravel(), new_pixels, out=self.values[2][new], mode="clip")
        np.take(work_pad.ravel(), new_pixels, out=self.reads[:k], mode="clip")
        np.subtract(self.reads[:k], self.values[2][new], out=self.height[new])
        self.replaced[new] = False
        self.charge[new] = False
        return n + k

    def _first_cut(self, work: np.ndarray, limit: np.ndarray, a: int, b: int) -> None:
        """mask = |work - median| > limit on rows [a, b) of the frame (``work`` and
        ``limit`` are those rows), ``_CUT_ROWS`` rows at a time: the difference is
        compared, and the mask's words holding a candidate marked (``cut_words``),
        while still in cache (a third less time than through full-frame buffers, each
        pass reading or writing memory)."""
        scratch = self.cut_scratch[a]
        pad = self.layout.pad
        for top in range(0, b - a, _CUT_ROWS):
            end = min(top + _CUT_ROWS, b - a)
            diff = scratch[:end - top]
            cv2.absdiff(work[top:end], self.median[a + top:a + end], dst=diff)
            cv2.compare(diff, limit[top:end], cv2.CMP_GT, dst=self.mask[a + top:a + end])
            self.layout.mark_words(self.mask_pad, pad + a + top, pad + a + end,
                                   self.cut_words)

    def _sparse(self, n: int, work_pad: np.ndarray, bg_pad: np.ndarray,
                limit_pad: np.ndarray, split: bool) -> None:
        idx = self.index[:n]
        w, m, b, lim = (v[:n] for v in self.values)
        flat = work_pad.ravel()
        reads = self.reads[:n]
        for src, dst in ((flat, w), (self.median_pad.ravel(), m), (limit_pad.ravel(), lim)):
            np.take(src, idx, out=reads, mode="clip")
            np.copyto(dst, reads)
        np.take(bg_pad.ravel(), idx, out=b, mode="clip")
        imp = _impulse_test(w, m, b, lim, self.contrast, self.sparse, n)
        np.subtract(w, b, out=self.height[:n])
        np.greater(w, m, out=self.charge[:n])
        np.logical_and(self.charge[:n], imp, out=self.charge[:n])
        np.copyto(w, m, where=imp)
        np.put(flat, idx, w, mode="clip")
        np.copyto(self.replaced[:n], imp)
        self._n = n
        if split:
            self._count(n, idx, imp, self.charge[:n])
        else:
            self.counts["impulse_pixels"] = int(np.count_nonzero(imp))

    def _count(self, n: int, idx: np.ndarray, imp: np.ndarray, charge: np.ndarray) -> None:
        """Count the impulses; split those of added charge into hot pixels and cosmic-ray
        groups (a dark impulse, a dead pixel or pepper, is neither)."""
        counts = self.counts
        counts["impulse_pixels"] = int(np.count_nonzero(imp))
        counts["hot_pixels"] = counts["cosmic_rays"] = 0
        if not np.any(charge):
            return
        imp = charge
        before, after = self._any_marked(n, idx, imp)
        # isolated impulse: no impulse neighbour at all
        hot = int(np.count_nonzero(imp & ~after))
        starts = int(np.count_nonzero(imp & ~before))
        counts["hot_pixels"] = hot
        counts["cosmic_rays"] = starts - hot
