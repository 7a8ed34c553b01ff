"""The project's detector: robust background, impulse rejection, matched filter, windowed centroid.

Per frame, with every buffer made at construction for one frame shape and
``detect.max_stars``:

1. ``input``: check the frame and copy it into a zero-bordered uint16
   buffer (tracker.detect.frame_input; bad frames give a reason code; other
   dtypes are clipped to 0..full scale and rounded to whole ADU). Integer
   images halve the memory traffic of the full-frame passes up to the
   filter (the detector is memory-bound), and OpenCV's median is faster on
   them.
2. ``background``: per-tile median and low-side noise on a coarse grid,
   3x3-median-filtered and interpolated to full size (tracker.detect.background).
3. ``impulses``: hot pixels, cosmic-ray tracks and salt-and-pepper pixels,
   recognised by being much sharper than the PSF, are replaced by their 3x3
   median and counted (tracker.detect.impulse).
4. ``filter``: Gaussian of the PSF sigma (the matched filter), on a float32
   copy (OpenCV's Gaussian is fastest on float32). The background is not
   subtracted from the whole image: the threshold image carries it
   (background + filtered level left + k times the filtered noise, one
   interpolation of one grid), and the filtered statistics and every
   sparse read subtract it where they look. k is
   ``detect.threshold_sigma``, moved out for skewed noise to the same tail
   probability (Cornish-Fisher, from the filtered background's skewness):
   photon noise of a few counts per pixel otherwise puts clumps of counts
   above a Gaussian-calibrated cut.
5. ``peaks``: local maxima above that threshold; close pairs split where the
   profile dips between them (tracker.detect.peaks).
6. ``centroid``: iterative Gaussian-windowed centroid, flux, SNR and shape
   (tracker.detect.windowed). Spots much narrower than the PSF (cosmic-ray
   clusters that survived step 3) are rejected and counted. Saturated
   stars are re-centred on their unclipped wings. With
   ``detect.centroid_noise: multiplicative`` a maximum-likelihood fit for
   noise proportional to the light (tracker.detect.multiplicative) gives
   every centre instead, from the frame as delivered; the shape tests
   (sharp spots, ELONGATED) are off, a speckled star's pixels being spiky,
   and candidates that end within 2 PSF sigma of a brighter one are
   dropped as its duplicates.

The median of step 3, the float copy and Gaussian of step 4 and the
threshold test of step 5 run in ``detect.threads`` horizontal slabs at once
(tracker.detect.slabs; the result does not depend on the thread count).

``Detections.counters``: impulse_pixels, hot_pixels, cosmic_rays (tracks
found in step 3 plus sharp spots from step 6), sharp_spots, candidates.
Stars are ordered brightest first (by matched-filter peak).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from tracker.config import DetectConfig
from tracker.detect.background import QUANTISATION_NOISE_ADU, BackgroundGrid
from tracker.detect.frame_input import FrameInput, Reason
from tracker.detect.impulse import ImpulseFilter, psf_contrast
from tracker.detect.layout import PaddedLayout
from tracker.detect.multiplicative import MultiplicativeFit
from tracker.detect.peaks import PeakFinder
from tracker.detect.result import Detections, StarFlag
from tracker.detect.slabs import SlabRunner
from tracker.detect.stars import StarTable
from tracker.detect.windowed import WindowedCentroider
from tracker.timing import StageTimer

__all__ = ["DefaultDetector", "effective_sigma"]


def effective_sigma(psf_sigma_px: float) -> float:
    """Sigma of a Gaussian PSF after integration over a square pixel, px."""
    return math.sqrt(psf_sigma_px ** 2 + 1.0 / 12.0)


def _reflected_noise_gain(kernel: np.ndarray, rows: int,
                         cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Noise gain of the filter at the first rows and columns, relative to the interior.

    OpenCV's BORDER_REFLECT folds the kernel onto itself at the border, so
    a pixel there sums some inputs twice and its filtered noise grows by
    sqrt(sum(folded^2) / sum(kernel^2)) per axis. Returns that factor for
    the first ``len(kernel) // 2`` rows and columns (the last ones mirror
    them); frames narrower than the kernel get factors of 1.
    """
    half = len(kernel) // 2
    gains = []
    for length in (rows, cols):
        g = np.ones(half, np.float32)
        if length > 2 * half:
            for i in range(half):
                folded = np.zeros(length)
                for t, k in zip(range(-half, half + 1), kernel, strict=True):
                    j = i + t
                    folded[-j - 1 if j < 0 else j] += k
                g[i] = np.sqrt(np.sum(folded ** 2) / np.sum(kernel ** 2))
        gains.append(g)
    return gains[0], gains[1]


class DefaultDetector:
    """Fixed-memory star detector; see the module docstring for the stages."""

    def __init__(self, cfg: DetectConfig, shape: tuple[int, int], bit_depth: int) -> None:
        self.cfg = cfg
        sigma = effective_sigma(cfg.psf_sigma_px)
        self.sigma = sigma
        self.radius = int(math.ceil(3.0 * sigma))
        blend = 2 * self.radius if cfg.blend_radius_px is None else int(cfg.blend_radius_px)
        layout = PaddedLayout(shape, max(self.radius, blend) + 1)
        self.layout = layout
        self.input = FrameInput(shape, bit_depth, min_size=3, layout=layout, dtype=np.uint16)
        self.saturation = (self.input.full_scale if cfg.saturation_adu is None
                           else float(cfg.saturation_adu))
        self.table = StarTable(cfg.max_stars)
        self.timer = StageTimer()
        self.grid = BackgroundGrid(layout, cfg.background_tile_px, cfg.background_step_px,
                                   cfg.max_candidates)
        grid_shape = self.grid.grid_shape
        self.level = np.zeros(grid_shape, np.float32)        # raw background, ADU
        self.noise = np.zeros(grid_shape, np.float32)        # raw pixel noise, ADU
        self.residual = np.zeros(grid_shape, np.float32)     # filtered level left, ADU
        self.noise_f = np.zeros(grid_shape, np.float32)      # filtered noise, ADU
        self.float_grid = np.zeros(grid_shape, np.float32)
        self.int_grid = np.zeros(grid_shape, np.uint16)
        self.bg_pad, self.bg = layout.buffer(np.float32)
        # impulse_sigma times the pixel noise in whole ADU, like the differences it bounds
        self.limit_pad, self.impulse_limit = layout.buffer(np.uint16)
        self.work_float = np.zeros(self.input.shape, np.float32)  # the filter's input
        self.filt_pad, self.filt = layout.buffer(np.float32)
        self.threshold = np.zeros(self.input.shape, np.float32)  # background included, ADU
        contrast = (cfg.impulse_contrast if cfg.impulse_contrast is not None
                    else 0.5 * (1.0 + psf_contrast(cfg.psf_sigma_px)))
        self.impulses = ImpulseFilter(layout, contrast, cfg.max_impulses, np.uint16,
                                      cfg.threads)
        # Half-width round(2 sigma): the cut-off kernel keeps >= 99 % of the matched
        # filter's SNR (its square holds >= 99.5 % of the PSF's squared mass per axis)
        # and costs two thirds of a 2.5-sigma one (5x5 instead of 7x7 at sigma 1.2).
        k = 2 * int(round(2.0 * sigma)) + 1
        self.ksize = (k, k)
        kernel = cv2.getGaussianKernel(k, sigma, cv2.CV_64F).ravel()
        self.filter_gain = float(np.sum(kernel ** 2))  # filtered / pixel noise, white noise
        self.threshold_k = float(cfg.threshold_sigma)
        self.filter_slabs = SlabRunner(layout.rows, layout.cols, k // 2, cfg.threads,
                                       np.float32)
        self.edge_gain = _reflected_noise_gain(kernel, layout.rows, layout.cols)
        self.peaks = PeakFinder(layout, blend, cfg.deblend_dip_sigma, cfg.max_pixels_above,
                                cfg.max_candidates, slabs=self.filter_slabs)
        self.centroider = WindowedCentroider(
            layout.stride, self.radius, sigma, gain=2.0, iterations=cfg.centroid_iterations,
            tolerance=cfg.centroid_tolerance_px, max_shift=1.5, capacity=cfg.max_candidates,
            dtype=np.uint16)
        # multiplicative noise: the likelihood fit reads the frame as delivered, since
        # the impulse filter takes the spikes of speckle for hot pixels
        self.speckle_fit = None
        if cfg.centroid_noise == "multiplicative":
            self.speckle_fit = MultiplicativeFit(self.radius, cfg.psf_sigma_px,
                                                 self.input.full_scale)
            self.delivered_pad = np.zeros_like(self.input.padded)
        self.expected_size = sigma ** 2  # weighted Mxx + Myy of a Gaussian star, px^2
        self.cand_noise = np.zeros(cfg.max_candidates, np.float32)
        self.cand_level = np.zeros(cfg.max_candidates, np.float32)
        self.counters = {"impulse_pixels": 0, "hot_pixels": 0, "cosmic_rays": 0,
                         "sharp_spots": 0, "candidates": 0}

    def _noise_f_at(self, flat: np.ndarray, out: np.ndarray) -> np.ndarray:
        return self.grid.at(self.noise_f, flat, out)

    def detect(self, image: np.ndarray) -> Detections:
        """Stars in ``image`` (pixel convention: tracker.detect.result)."""
        timer = self.timer
        timer.reset()
        for key in self.counters:
            self.counters[key] = 0
        timer.start("input")
        reason = self.input.load(image)
        if reason is not None:
            timer.stop()
            return self.table.result(0, reason, self.counters, timer.ms)
        if self.speckle_fit is not None:
            np.copyto(self.delivered_pad, self.input.padded)
        timer.start("background")
        grid = self.grid
        grid.stats(self.input.padded, self.level, self.noise, QUANTISATION_NOISE_ADU,
                   upper=True)
        grid.upsample(self.level, self.bg)
        np.multiply(self.noise, self.cfg.impulse_sigma, out=self.float_grid)
        np.clip(self.float_grid, 0.0, 65535.0, out=self.float_grid)
        np.rint(self.float_grid, out=self.float_grid)
        np.copyto(self.int_grid, self.float_grid, casting="unsafe")
        grid.upsample(self.int_grid, self.impulse_limit)
        timer.start("impulses")
        self.counters.update(self.impulses.run(self.input.padded, self.input.work, self.bg_pad,
                                               self.limit_pad, self.impulse_limit))
        timer.start("filter")
        self.filter_slabs.rows(self._to_float)
        self.filter_slabs.run(self._matched_filter, self.work_float, self.filt)
        grid.stats(self.filt_pad, self.residual, self.noise_f,
                   QUANTISATION_NOISE_ADU * self.filter_gain, upper=True, minus=self.bg_pad)
        self._skew_threshold(grid.skewness())
        self._make_threshold(1.0)
        timer.start("peaks")
        n = self.peaks.find(self.filt_pad, self.filt, self.threshold, self.bg_pad,
                            self._make_threshold, self._noise_f_at)
        self.counters["candidates"] = n
        timer.start("centroid")
        count = self._measure(n)
        timer.stop()
        reason = Reason.CROWDED if self.peaks.crowded else None
        return self.table.result(count, reason, self.counters, timer.ms)

    def _to_float(self, a: int, b: int) -> None:
        np.copyto(self.work_float[a:b], self.input.work[a:b])

    def _matched_filter(self, src: np.ndarray, dst: np.ndarray) -> None:
        cv2.GaussianBlur(src, self.ksize, self.sigma, dst=dst, borderType=cv2.BORDER_REFLECT)

    def _skew_threshold(self, skewness: float) -> None:
        """threshold_k: threshold_sigma moved to the same tail probability for skewed noise.

        Cornish-Fisher: the z quantile of a distribution of skewness g sits
        near z + g (z^2 - 1) / 6 standard deviations. Photon noise of a few
        counts per pixel is skewed even after the matched filter (and a
        Gaussian 6-sigma cut lets its clumps through); Gaussian noise (g about
        0) keeps threshold_sigma. ``skewness``: of the filtered background.
        """
        z = float(self.cfg.threshold_sigma)
        g = max(0.0, skewness)
        self.threshold_k = z + g * (z * z - 1.0) / 6.0

    def _make_threshold(self, factor: float) -> None:
        """Threshold image: background + level left + factor * threshold_k * noise."""
        np.multiply(self.noise_f, factor * self.threshold_k, out=self.float_grid)
        np.add(self.float_grid, self.residual, out=self.float_grid)
        np.add(self.float_grid, self.level, out=self.float_grid)
        self.grid.upsample(self.float_grid, self.threshold)
        self._raise_edges()

    def _raise_edges(self) -> None:
        """Scale the threshold's height above the background near the borders.

        There the reflected filter has more noise (``_reflected_noise_gain``).
        """
        top, left = self.edge_gain
        r = len(top)
        t, b = self.threshold, self.bg
        for sl, gain in (((slice(0, r), slice(None)), top[:, None]),
                         ((slice(-r, None), slice(None)), top[::-1, None]),
                         ((slice(None), slice(0, r)), left[None, :]),
                         ((slice(None), slice(-r, None)), left[None, ::-1])):
            strip = t[sl]
            np.subtract(strip, b[sl], out=strip)
            np.multiply(strip, gain, out=strip)
            np.add(strip, b[sl], out=strip)

    def _measure(self, n: int) -> int:
        """Centroid the candidates, reject sharp spots, fill the star table."""
        if n == 0:
            return 0
        cand = self.peaks.cand[:n]
        noise, level = self.cand_noise[:n], self.cand_level[:n]
        self.grid.at(self.noise, cand, noise)
        self.grid.at(self.residual, cand, level)
        v = self.centroider.measure(n, self.input.padded, self.bg_pad, cand, noise, level)
        if self.speckle_fit is not None:  # its likelihood handles saturated stars too
            merged = self.centroider.refine_multiplicative(
                n, self.speckle_fit, self.delivered_pad, self.bg_pad, level, 2.0 * self.sigma)
        else:
            self.centroider.refine_clipped(n, self.saturation, self.sigma, noise)
            merged = False
        # Shape tests against the PSF, for spots bright enough to measure; under
        # multiplicative noise a star's own pixels are spiky, so none applies.
        judged = (v["snr"] >= self.cfg.sharp_min_snr) & (self.speckle_fit is None)
        # Second moment across the spot's narrowest axis: a PSF's is half its size,
        # and a star streaked by motion keeps it, while a cosmic-ray hit or track
        # is a pixel or so wide. Moments of no positive spot (what impulse
        # rejection leaves of a track) count as narrow.
        narrowest = 0.5 * v["size"] * (1.0 - v["ellipticity"])
        spot = (v["weighted"] > 0) & (v["size"] > 0) & (v["ellipticity"] <= 1.0)
        sharp = judged & (
            ~spot | (narrowest < self.cfg.sharp_size_ratio * 0.5 * self.expected_size))
        n_sharp = int(np.count_nonzero(sharp))
        self.counters["sharp_spots"] = n_sharp
        self.counters["cosmic_rays"] += n_sharp
        keep = np.flatnonzero(~(sharp | merged))[: self.table.capacity]
        count = len(keep)
        rows, cols = self.layout.frame_position(cand[keep])
        s = self.table.stars
        s["x"][:count] = cols + v["x0"][keep]
        s["y"][:count] = rows + v["y0"][keep]
        s["flux"][:count] = v["flux"][keep]
        s["peak"][:count] = v["peak"][keep]
        s["snr"][:count] = v["snr"][keep]
        s["npix"][:count] = v["npix"][keep]
        flags = np.zeros(count, np.uint16)
        h, w = self.input.shape
        r = self.radius
        flags[(cols < r) | (rows < r) | (cols > w - 1 - r) | (rows > h - 1 - r)] |= StarFlag.EDGE
        flags[v["raw_peak"][keep] >= self.saturation] |= StarFlag.SATURATED
        flags[(v["ellipticity"][keep] > self.cfg.elongation_max)
              & judged[keep]] |= StarFlag.ELONGATED
        flags[self.peaks.blended[:n][keep]] |= StarFlag.BLENDED
        self._flag_extended(s[:count], flags)
        s["flags"][:count] = flags
        return count

    def _flag_extended(self, stars: np.ndarray, flags: np.ndarray) -> None:
        """EXTENDED: effective area flux/peak above ``extended_ratio`` x the frame's median.

        A point source's flux/peak is fixed by the PSF (2 pi sigma^2 for a
        Gaussian) whatever its brightness; a nebula, comet or lit branch
        spreads its flux wider. The frame's own median is the reference, so
        an unknown or field-varying PSF needs no configuration. Saturated
        stars (flat tops) are neither judged nor part of the median; fewer
        than five unsaturated sources give no reference.
        """
        unsat = (flags & StarFlag.SATURATED) == 0
        if np.count_nonzero(unsat) < 5:
            return
        area = stars["flux"] / np.maximum(stars["peak"], 1e-12)
        broad = unsat & (area > self.cfg.extended_ratio * np.median(area[unsat]))
        flags[broad] |= StarFlag.EXTENDED
