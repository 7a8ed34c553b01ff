"""The brightest spots of a frame binned 4 x 4: where the PSF meter looks when peaks are low.

A wide PSF spreads a star's light so thin that its peak pixel may stand
only a few noise sigmas above the sky while the matched filter sees it at
SNR 20 (a 3 px PSF's peak holds 1/57 of its light). The PSF meter
(tracker.detect.psf) then finds too few bright peaks to measure the PSF,
and without the PSF the matched filter cannot be chosen. Binning the frame
4 x 4 (the mean of each block, one OpenCV pass over the frame into an
image a sixteenth its size) adds up most of such a star's light against
a quarter of the pixel noise: 3-4 times the peak's SNR for a 2-3 px PSF,
without knowing the PSF. The bins that are the brightest within two bins
(8 px) around, at least ``min_snr`` binned noise sigmas above the
background, brightest first, are the candidates (one per star: a wide
star's top spans bins whose rounded means may tie, or whose noise makes two
bumps, and each would measure it again; ties go to the first in raster
order); each one's
light-weighted centre over its 3 x 3 bins gives the frame pixel the meter
starts from, and the brightest pixel of its block is kept for the tests
that tell a hot pixel from a star.

The background and pixel noise are the background stage's grids
(tracker.detect.background), interpolated to the binned image; a bin's
noise is the pixel noise over 4 (white noise) with the rounding of the
binned integers (1/12 ADU^2) added. The binning runs in the row slabs of
a tracker.detect.slabs runner if given (each slab the blocks that begin in
its rows: the same means as one call). Every buffer is made at construction.
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout
from tracker.detect.slabs import SlabRunner

__all__ = ["BinnedPeaks", "BIN_PX"]

BIN_PX = 4
_REACH = 2                 # a candidate is the brightest bin this many bins around
# the bins before a bin in raster order within that reach, and those after it
_BEFORE = np.zeros((2 * _REACH + 1, 2 * _REACH + 1), np.uint8)
_BEFORE[:_REACH] = 1
_BEFORE[_REACH, :_REACH] = 1
_AFTER = (1 - _BEFORE).astype(np.uint8)
_AFTER[_REACH, _REACH] = 0
_ROUNDING_VARIANCE = 1.0 / 12.0   # ADU^2: the binned means are rounded to whole ADU


class BinnedPeaks:
    """Candidates of frames held in padded uint16 buffers of ``layout``; up to ``capacity``."""

    def __init__(self, layout: PaddedLayout, capacity: int,
                 slabs: SlabRunner | None = None) -> None:
        self.layout = layout
        self.slabs = slabs or SlabRunner(layout.rows, layout.cols, 0, 1, np.uint16)
        self.shape = (max(1, layout.rows // BIN_PX), max(1, layout.cols // BIN_PX))
        self.binned = np.zeros(self.shape, np.uint16)
        self.values = np.zeros(self.shape, np.float32)
        self.before = np.zeros(self.shape, np.uint16)   # the binned means' maxima around
        self.after = np.zeros(self.shape, np.uint16)
        self.level = np.zeros(self.shape, np.float32)
        self.noise = np.zeros(self.shape, np.float32)
        self.threshold = np.zeros(self.shape, np.float32)
        self.above = np.zeros(self.shape, np.bool_)
        self.capacity = int(capacity)
        self.start = np.zeros(self.capacity, np.intp)       # padded flat: the meter's start
        self.brightest = np.zeros(self.capacity, np.intp)   # padded flat: its block's peak
        dy, dx = np.mgrid[-1:2, -1:2]
        self.bin_dy, self.bin_dx = dy.ravel(), dx.ravel()
        dy, dx = np.mgrid[0:BIN_PX, 0:BIN_PX]
        self.block_offsets = (dy.ravel() * layout.stride + dx.ravel()).astype(np.intp)

    def _bin(self, work: np.ndarray, first: int, end: int) -> None:
        """The binned means (``binned``, and ``values`` in float32) of the blocks whose
        first row lies in the frame's rows [first, end)."""
        rows, cols = self.shape
        lo, hi = -(-first // BIN_PX), min(-(-end // BIN_PX), rows)
        if lo < hi:
            cv2.resize(work[lo * BIN_PX:hi * BIN_PX, :cols * BIN_PX], (cols, hi - lo),
                       dst=self.binned[lo:hi], interpolation=cv2.INTER_AREA)
            np.copyto(self.values[lo:hi], self.binned[lo:hi])

    def find(self, work_pad: np.ndarray, work: np.ndarray, level: np.ndarray,
             noise: np.ndarray, min_snr: float) -> int:
        """Candidates of the frame in ``work`` (uint16, the interior view of ``work_pad``)
        into ``start[:n]`` and ``brightest[:n]``, brightest first; returns n.

        ``level`` and ``noise``: the background stage's grids (ADU per pixel).
        """
        rows, cols = self.shape
        if work.shape[0] < BIN_PX or work.shape[1] < BIN_PX:
            return 0
        self.slabs.rows(lambda first, end: self._bin(work, first, end))
        cv2.resize(level, (cols, rows), dst=self.level, interpolation=cv2.INTER_LINEAR)
        cv2.resize(noise, (cols, rows), dst=self.noise, interpolation=cv2.INTER_LINEAR)
        np.multiply(self.noise, self.noise, out=self.noise)
        np.multiply(self.noise, 1.0 / BIN_PX ** 2, out=self.noise)
        np.add(self.noise, _ROUNDING_VARIANCE, out=self.noise)
        np.sqrt(self.noise, out=self.noise)
        np.multiply(self.noise, min_snr, out=self.threshold)
        np.add(self.threshold, self.level, out=self.threshold)
        cv2.dilate(self.binned, _BEFORE, dst=self.before)
        cv2.dilate(self.binned, _AFTER, dst=self.after)
        np.greater(self.binned, self.before, out=self.above)
        self.above &= self.binned >= self.after
        self.above &= self.values > self.threshold
        idx = np.flatnonzero(self.above)
        if len(idx) == 0:
            return 0
        values = self.values.ravel()
        level = self.level.ravel()
        snr = (values[idx] - level[idx]) / self.noise.ravel()[idx]
        idx = idx[np.argsort(-snr, kind="stable")[:self.capacity]]
        n = len(idx)
        by, bx = np.divmod(idx, cols)
        # the light-weighted centre over the 3 x 3 bins (clipped at the image's edge)
        ny = np.clip(by[:, None] + self.bin_dy[None, :], 0, rows - 1)
        nx = np.clip(bx[:, None] + self.bin_dx[None, :], 0, cols - 1)
        near = ny * cols + nx
        light = np.maximum(values[near] - level[near], 0.0)
        total = np.maximum(light.sum(axis=1), 1e-12)
        cy = (light * (ny - by[:, None])).sum(axis=1) / total
        cx = (light * (nx - bx[:, None])).sum(axis=1) / total
        half = 0.5 * (BIN_PX - 1)
        row = np.clip(np.rint(BIN_PX * (by + cy) + half), 0, self.layout.rows - 1)
        col = np.clip(np.rint(BIN_PX * (bx + cx) + half), 0, self.layout.cols - 1)
        self.start[:n] = self.layout.flat_index(row.astype(np.intp), col.astype(np.intp))
        corner = self.layout.flat_index(BIN_PX * by, BIN_PX * bx)
        block = corner[:, None] + self.block_offsets[None, :]
        reads = np.take(work_pad.ravel(), block, mode="clip")
        self.brightest[:n] = block[np.arange(n), np.argmax(reads, axis=1)]
        return n
