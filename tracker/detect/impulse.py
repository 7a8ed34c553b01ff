"""Hot pixels, cosmic-ray hits and salt-and-pepper noise: found and replaced.

A pixel is an impulse when it differs from the median of its 3x3
neighbourhood by more than ``k_sigma`` times the local noise AND by more
than the fraction ``contrast`` of its height above the background (for a
pixel darker than its median: of the median's height). A star's light is
spread by the optics, so its brightest pixel stands above the 3x3 median by
only part of its height (0.26 for a centred Gaussian PSF of sigma 1.2 px,
:func:`psf_contrast`); a hot pixel, or a cosmic-ray track one pixel wide,
stands above it by all of its height. The cut-off sits between the two.
Impulses are replaced by their 3x3 median.

Impulses are counted: a pixel with no impulse among its 8 neighbours is a
hot pixel (or a one-pixel hit); a group of touching impulse pixels is one
cosmic-ray hit, counted at its first pixel in raster order (one with no
impulse to its left or in the row above; a group shaped like a "U" counts
twice). Tracks wider than one pixel survive the 3x3 median and are left to
the detector's shape test.

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

__all__ = ["ImpulseFilter", "psf_contrast"]


def psf_contrast(sigma_px: float) -> float:
    """(peak - 3x3 median) / peak of a pixel-integrated Gaussian PSF centred on a pixel."""
    cdf = [math.erf(e / (sigma_px * math.sqrt(2.0))) for e in (-1.5, -0.5, 0.5, 1.5)]
    w = np.diff(cdf)
    stamp = np.outer(w, w)
    return float(1.0 - np.median(stamp) / stamp[1, 1])


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


# Neighbour offsets (dy, dx): all eight, and the four met before a pixel in raster order.
_EIGHT = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))
_BEFORE = 4


class ImpulseFilter:
    """Finds and replaces impulses in frames held in padded buffers of ``layout``.

    Frames, their limits and the median are of ``dtype`` (float32 or uint16);
    the median runs in ``threads`` slabs (tracker.detect.slabs).
    """

    def __init__(self, layout: PaddedLayout, contrast: float, capacity: int,
                 dtype: type = np.float32, threads: int = 1) -> None:
        self.layout = layout
        self.contrast = float(contrast)
        self.capacity = int(capacity)
        self.median_pad, self.median = layout.buffer(dtype)
        self.diff_pad, self.diff = layout.buffer(dtype)
        self.mask_pad, self.mask = layout.buffer(np.uint8)
        self.slabs = SlabRunner(layout.rows, layout.cols, 1, threads, dtype)
        self.dense = _TestBuffers(layout.full_shape)
        self.sparse = _TestBuffers((self.capacity,))
        self.index = np.zeros(self.capacity, np.intp)
        self.values = np.zeros((4, self.capacity), np.float32)
        self.reads = np.zeros(self.capacity, dtype)
        stride = layout.stride
        self.neighbour_offsets = np.array([dy * stride + dx for dy, dx in _EIGHT], np.intp)
        self.marks = np.zeros(layout.full_shape[0] * stride, np.uint8)
        self.neighbour_index = np.zeros((self.capacity, 8), np.intp)
        self.neighbours = np.zeros((self.capacity, 8), np.uint8)
        self.any_before = np.zeros(self.capacity, np.uint8)
        self.any_after = np.zeros(self.capacity, np.uint8)
        self.counts = {"impulse_pixels": 0, "hot_pixels": 0, "cosmic_rays": 0}

    def run(self, work_pad: np.ndarray, work: np.ndarray, bg_pad: np.ndarray,
            limit_pad: np.ndarray, limit: np.ndarray) -> dict:
        """Replace impulses in ``work`` (interior view of ``work_pad``) in place; counts.

        ``limit_pad`` (padded like ``work_pad``; ``limit`` its interior view)
        is ``k_sigma`` times the local pixel noise; ``bg_pad`` (float32) the
        background.
        """
        counts = self.counts
        for key in counts:
            counts[key] = 0
        self.slabs.run(_median3, work, self.median)
        self.slabs.rows(lambda a, b: self._first_cut(work[a:b], limit[a:b], a, b))
        n = self.layout.nonzero(self.mask_pad, self.index)
        if n == 0:
            return counts
        if n > self.capacity:
            imp = _impulse_test(work_pad, self.median_pad, bg_pad, limit_pad, self.contrast,
                                self.dense, work_pad.shape[0])
            np.copyto(work_pad, self.median_pad, where=imp)
            counts["impulse_pixels"] = int(np.count_nonzero(imp))
            return counts
        self._sparse(n, work_pad, bg_pad, limit_pad)
        return counts

    def _first_cut(self, work: np.ndarray, limit: np.ndarray, a: int, b: int) -> None:
        """mask = |work - median| > limit on rows [a, b) of the frame."""
        cv2.absdiff(work, self.median[a:b], dst=self.diff[a:b])
        cv2.compare(self.diff[a:b], limit, cv2.CMP_GT, dst=self.mask[a:b])

    def _sparse(self, n: int, work_pad: np.ndarray, bg_pad: np.ndarray,
                limit_pad: np.ndarray) -> None:
        idx = self.index[:n]
        w, m, b, lim = (v[:n] for v in self.values)
        flat = work_pad.ravel()
        reads = self.reads[:n]
        for src, dst in ((flat, w), (self.median_pad.ravel(), m), (limit_pad.ravel(), lim)):
            np.take(src, idx, out=reads, mode="clip")
            np.copyto(dst, reads)
        np.take(bg_pad.ravel(), idx, out=b, mode="clip")
        imp = _impulse_test(w, m, b, lim, self.contrast, self.sparse, n)
        np.copyto(w, m, where=imp)
        np.put(flat, idx, w, mode="clip")
        self._count(n, idx, imp)

    def _count(self, n: int, idx: np.ndarray, imp: np.ndarray) -> None:
        """Split the impulses into hot pixels and cosmic-ray groups."""
        counts = self.counts
        total = int(np.count_nonzero(imp))
        counts["impulse_pixels"] = total
        if total == 0:
            return
        marks = self.marks
        np.put(marks, idx, imp.view(np.uint8), mode="clip")
        nb_index = self.neighbour_index[:n]
        np.add(idx[:, None], self.neighbour_offsets[None, :], out=nb_index)
        nb = self.neighbours[:n]
        np.take(marks, nb_index, out=nb, mode="clip")
        before, after = self.any_before[:n], self.any_after[:n]
        np.max(nb[:, :_BEFORE], axis=1, out=before)
        np.max(nb[:, _BEFORE:], axis=1, out=after)
        # isolated impulse: no impulse neighbour at all
        np.bitwise_or(before, after, out=after)
        hot = int(np.count_nonzero(imp & (after == 0)))
        starts = int(np.count_nonzero(imp & (before == 0)))
        counts["hot_pixels"] = hot
        counts["cosmic_rays"] = starts - hot
        marks[idx] = 0
