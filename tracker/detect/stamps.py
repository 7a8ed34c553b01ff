"""Lean detection in tracking's windows: one stack of windows, every step vectorised over it.

Tracking knows where its stars will be (tracker.identify.windows plans the
windows, all of one side ``cell``). :class:`StampDetector` works on the
``cells`` windows of a frame as one (cells, cell, cell) stack gathered by
fancy indexing, with no Python loop over windows or stars:

1. ``stack``: the windows copied out of the frame (one gather from a view
   of all its windows).
2. ``background``: each window's sky level and pixel noise from its border
   ring (``RING_PX`` wide): the median, and the RMS of the pixels within 3
   sigma of it (sigma from the interquartile range; the RMS corrected
   for the clip, at least the quantisation noise). The planner centres a
   predicted star in its window, so the ring holds sky.
3. ``filter``: the matched filter (a Gaussian of the pixel-integrated PSF's
   sigma, cut at round(2 sigma) like the full frame's) over the stack,
   background subtracted, by one OpenCV call on the windows laid side by
   side as one wide image (OpenCV filters along rows: twice as fast as on a
   tall stack of window-wide rows), each window followed by a gap of zeros
   one pixel wider than the filter's half-width and the image bordered by
   zeros: no window's filtered pixels or their 3 x 3 maxima read another
   window, and at the frame's edge the filter takes the light beyond it as
   none and is divided by the noise gain of its taps inside the frame
   (tracker.detect.edge.inside_norms): the response
   tracker.detect.edge.inward_starts reads for the full frame, whose
   reflected filter needs it (no mirror merges with a star here), and the
   same false-alarm rate as inside.
4. ``peaks``: local maxima (3 x 3) of the filtered stack above k times each
   window's filtered noise, k the full frame's for the false-alarm budget
   ``detect.false_alarms_per_frame`` (tracker.detect.threshold: the same
   stars as the full frame, fewer false ones in the smaller area), at least
   ``margin`` px from a window's inner borders (there the filter sees
   nothing of the frame beyond the window) and anywhere up to a border that
   is the frame's edge; one per frame pixel (windows overlap), most
   significant first, at most ``max_candidates``.
5. ``impulses``: a stamp of radius 3 sigma around each peak is read from
   the frame (cut at its edge: the pixels beyond it repeat the border's for
   the median, as OpenCV's median does at the full frame's border, and then
   hold no light), and every pixel of it inside the frame tested against its 3 x 3 median with
   the full frame's rule (tracker.detect.impulse): standing off it by more
   than ``detect.impulse_sigma`` pixel noise and by more than the contrast
   no star a tenth sharper than the PSF reaches, it is an impulse and takes
   the median. A peak whose brightest central pixel is one, with less light
   in its eight neighbours than such a star always has, is a hot pixel or
   a one-pixel hit and is dropped (counted ``hot_pixels``).
6. ``centroid``: the fit of the pixel-integrated PSF (tracker.detect.fit)
   to the stamp, two Gauss-Newton steps from the filtered peak's parabolic
   vertex (within 0.003 px RMS of the converged centres; four for a star the
   frame's edge cuts, whose flux and centre across the edge trade off: with
   two, 25 of 128 faint stars centred 1 px beyond the edge ended inside the
   frame, with four 5, at PSF sigma 1.2 px); stars
   closer than the blend radius (``detect.blend_radius_px``, else twice the
   centroid's) to another peak are BLENDED and take the Gaussian-windowed
   centroid instead, as the full frame does (tracker.detect.windowed), two
   steps from the vertex (the neighbour's pull, not the steps, sets its
   error: more steps converge no closer to the truth). Stars the caller
   centres anew (``refitted``: tracking's line-spread fit of a trailed star,
   tracker.detect.trail) keep the vertex, neither fitted nor windowed: that
   centre would be thrown away, and the trail fit finds its own start along
   the trail (its light's first moment), the vertex holding it across to
   half a pixel. On 16 mm 3 deg/s slews (trails of 3-6 px) the trail fit's
   centres from the vertex were within 0.01-0.03 px of those from the point
   fit for 90 % of the stars and their RMS against the truth 0.3-0.6 %
   higher (seeds 13, 21 and 22; held out 31 and 32: -0.1 and +0.8 %); the
   windowed frame's thread CPU 1-5 % lower: the point fit's passes are gone
   only from frames all of whose stars trail that far (a roll leaves the
   stars near the boresight short trails, point-fitted).
   Flux (the stamp's sum), peak, npix and SNR (the Gaussian-weighted sum over its noise, as
   tracker.detect.windowed reports it) and the weighted second moments:
   spots narrower than ``detect.sharp_size_ratio`` of the PSF, or narrow
   and elongated like a particle's track, are rejected (counted
   ``sharp_spots`` and ``cosmic_rays``) when at least ``detect.sharp_min_snr``
   significant; ELONGATED, SATURATED, BLENDED flags as the full frame sets
   them. A star the frame's edge cuts is handled as the full frame handles
   it (tracker.detect.edge): fitted on the stamp's pixels inside the frame,
   its moments judged along the edge (``judge_whole``) before the shape
   tests, flagged EDGE when its stamp reaches beyond the frame
   (``cut_axes``), and dropped when its centre lies beyond the frame
   (``beyond_frame``, counted ``beyond_edge``). A star seen in two
   overlapping windows is reported once.

Not done here, unlike the full frame: deblending by the profile's dip, the
roughness and sky-sector tests, EXTENDED (no frame-wide reference in a few
windows) and the PSF's measurement (the pipeline measures it with the full
detector over a mosaic of the windows on one frame in
``identify.track_lens_every``: tracker.detect.windows).

Fixed memory: the stack, its filtered copy (with the widest PSF's gaps) and
the star table are made at construction for ``cells`` windows of ``cell`` px,
the order of ``max_candidates`` peaks (which comes before which) once; the
per-peak arrays are temporaries of at most ``max_candidates`` rows.

One thread: a frame's few dozen windows are too small to share. Each step
above costs mostly numpy's fixed cost per call, which holds the GIL, so the
windows cut in two halves on two threads (tracker.detect.slabs' pattern)
pay it twice: the halves' thread CPU, one after the other, was 1.3-1.6
times the whole's for every step but the gather, and run at once every
step took longer than the whole on one thread (16 mm 3 deg/s, 40 windows
of 24 px, seed 13, load 1.3: stack 69 -> 107 us wall, background 101 ->
184, filter 112 -> 152, peaks 130 -> 203, impulses 156 -> 258, centroid
657 -> 1077; the trail fit 241 -> 417). The gather alone, whose copy does
scale with the pixels, lost too: its hand-off to a worker costs more than
the half it moves (29 -> 71 us wall, seed 102).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np

from tracker.config import DetectConfig
from tracker.detect.background import QUANTISATION_NOISE_ADU
from tracker.detect.edge import beyond_frame, cut_axes, inside_norms, judge_whole
from tracker.detect.fit import PixelGaussianFit
from tracker.detect.impulse import psf_contrast, psf_ring
from tracker.detect.layout import window_view
from tracker.detect.psf import PsfEstimate
from tracker.detect.result import Detections, StarFlag
from tracker.detect.stars import StarTable
from tracker.detect.threshold import gaussian_peak_threshold
from tracker.detect.windowed import later_within
from tracker.timing import StageTimer

__all__ = ["StampDetector", "RING_PX"]

RING_PX = 2                    # width of the border ring a window's sky is taken from
_IQR_SIGMAS = 1.349            # a Gaussian's interquartile range in sigmas
_CLIP_SIGMAS = 3.0             # the ring's noise: RMS of the pixels within this many sigma
_CLIPPED_VARIANCE = 0.9707     # ... which keeps this share of a Gaussian's variance
_SIGMA_STEP = math.log(1.03)   # PSF sigmas used in steps of 3 % (as the full frame does)
_IMPULSE_PSF_MARGIN = 0.9      # impulses are judged against a PSF this much sharper
_TRACK_WIDTH = 0.6             # a spot this narrow across (PSF = 1) and ...
_TRACK_ELLIPTICITY = 0.3       # ... this elongated is a particle's track
_FIT_STEPS = 2                 # Gauss-Newton steps of the fit from the parabolic vertex:
                               # within 0.003 px RMS of converged (0.02 px at most)
_EDGE_FIT_STEPS = 4            # ... of a star the frame's edge cuts: its flux and centre across
                               # the edge trade off, and the steps converge slower
_BLEND_STEPS = 2               # windowed-centroid steps of a blended star from the vertex: its
                               # error against the truth is its neighbour's pull, not the steps
                               # (RMS 0.249 px with 2, 0.255 with up to 8 over 120 blends)
_MAX_SHIFT_PX = 1.5            # the fit's centre stays this close to the peak pixel
_SAME_STAR_PX = 1.0            # one star's detections in overlapping windows lie closer
_NEIGHBOURS = np.ones((3, 3), np.uint8)
_FLAGS = np.array((StarFlag.SATURATED, StarFlag.ELONGATED, StarFlag.BLENDED, StarFlag.EDGE),
                  np.uint16)
_MAX_SIGMA_PX = 3.5            # the widest optical PSF sigma the buffers are sized for, px


def _effective_sigma(sigma_px: float) -> float:
    """The pixel-integrated PSF's sigma, px (tracker.detect.default.effective_sigma)."""
    return math.sqrt(sigma_px ** 2 + 1.0 / 12.0)


def _kernel_half(sigma: float) -> int:
    """The matched filter's half-width, px: round(2 sigma) of the pixel-integrated PSF's
    ``sigma`` (the full frame's)."""
    return max(1, int(round(2.0 * sigma)))


class StampDetector:
    """Finds stars in ``cells`` windows of ``cell`` px of frames of ``frame_shape``.

    ``cfg``: the detector's settings (the false-alarm budget, impulse and
    shape tests, saturation); ``bit_depth`` sets full scale; ``margin`` the
    PSF's reach, px (module docstring, step 4); ``dtype`` the frames'
    (uint8 or uint16).
    """

    def __init__(self, cfg: DetectConfig, frame_shape: tuple[int, int], cell: int, cells: int,
                 margin: int, bit_depth: int, dtype: type, max_candidates: int = 256) -> None:
        self.cfg = cfg
        self.frame_shape = (int(frame_shape[0]), int(frame_shape[1]))
        self.cell, self.cells = int(cell), int(cells)
        if self.cell > min(self.frame_shape):
            raise ValueError(f"window of {cell} px larger than the frame {frame_shape}")
        self.margin = int(margin)
        self.saturation = (float(2 ** int(bit_depth) - 1) if cfg.saturation_adu is None
                           else float(cfg.saturation_adu))
        self.max_candidates = int(max_candidates)
        n, c = self.cells, self.cell
        self.raw = np.zeros((n, c, c), dtype)
        # the filter's arrays hold the windows side by side with their gaps, (row, window,
        # column); :meth:`_configure` views them for its PSF's gap
        widest = c * n * (c + _kernel_half(_effective_sigma(_MAX_SIGMA_PX)) + 1)
        self._stack_buffer = np.zeros(widest, np.float32)
        self._filt_buffer = np.zeros(widest, np.float32)
        self._dilated_buffer = np.zeros(widest, np.float32)
        self._above_buffer = np.zeros(widest, np.bool_)
        self._peak_buffer = np.zeros(widest, np.bool_)
        self._limit_buffer = np.zeros(widest // c, np.float32)   # a row's thresholds
        ring = np.zeros((c, c), bool)
        ring[:RING_PX], ring[-RING_PX:], ring[:, :RING_PX], ring[:, -RING_PX:] = (True,) * 4
        self.ring = np.flatnonzero(ring.ravel())
        k = len(self.ring)
        self.ring_ranks = [k // 4, (k - 1) // 2, k // 2, (3 * k) // 4]  # quartiles, median
        self.level = np.zeros(n, np.float32)
        # per window, whether its left, top, right, bottom border is the frame's edge
        self.edge = np.zeros((n, 4), bool)
        self.far_origin = np.array([self.frame_shape[1] - c, self.frame_shape[0] - c])
        self.noise = np.zeros(n, np.float32)
        self.table = StarTable(cfg.max_stars)
        self.timer = StageTimer()
        self.sources = np.zeros(0, np.intp)   # the last result's stars' peaks (:meth:`detect`)
        self.counters = {"impulse_pixels": 0, "hot_pixels": 0, "cosmic_rays": 0,
                         "sharp_spots": 0, "beyond_edge": 0, "candidates": 0, "left_out": 0}
        max_radius = int(math.ceil(3.0 * _effective_sigma(_MAX_SIGMA_PX)))
        self.fit = PixelGaussianFit(self.max_candidates, 2 * max_radius + 1, _FIT_STEPS)
        self._step = None

    def _configure(self, sigma_px: float) -> None:
        """Filter, threshold, stamps and impulse constants for an optical PSF sigma (px),
        rebuilt only when it moves to another 3 % step."""
        step = int(round(math.log(sigma_px) / _SIGMA_STEP))
        if step == self._step:
            return
        self._step = step
        sigma_px = math.exp(step * _SIGMA_STEP)
        sigma = _effective_sigma(sigma_px)
        self.sigma, self.expected_size = sigma, sigma ** 2
        half = _kernel_half(sigma)
        kernel = cv2.getGaussianKernel(2 * half + 1, sigma, cv2.CV_64F).ravel()
        n, c = self.cells, self.cell
        width = c + half + 1                  # a window and its gap
        size = c * n * width
        self.stack = self._stack_buffer[:size].reshape(c, n, width)
        self.stack.fill(0.0)                  # the gaps stay zero; windows are written anew
        self.filt = self._filt_buffer[:size].reshape(c, n * width)
        self.dilated = self._dilated_buffer[:size].reshape(c, n * width)
        self.above = self._above_buffer[:size].reshape(c, n * width)
        self.peak = self._peak_buffer[:size].reshape(c, n * width)
        self.limit = self._limit_buffer[:n * width].reshape(n, width)
        self.cross = np.array([0, -1, 1, -n * width, n * width])   # a pixel and its 4
                                                                  # neighbours, flat offsets
        self.kernel = kernel.astype(np.float32)
        self.filter_gain = float(np.sum(kernel ** 2))     # filtered / pixel noise
        # at the frame's edge the filter reads no light beyond it: its response over the
        # noise gain of its taps inside, per axis, from the border pixel inward
        self.half = half
        self.edge_gain = (inside_norms(kernel, np.arange(half))
                          / math.sqrt(self.filter_gain)).astype(np.float32)
        # the full frame's threshold: the windows report the stars it would
        area = self.frame_shape[0] * self.frame_shape[1]
        self.k_sigma = gaussian_peak_threshold(self.cfg.false_alarms_per_frame, area, kernel)
        self.radius = int(math.ceil(3.0 * sigma))
        self.fit.configure(self.radius, sigma_px)
        r = self.radius
        self.stamp_axis = np.arange(-r, r + 1, dtype=np.float64)
        side = 2 * r + 1
        centre = (side * side) // 2
        self.centre9 = centre + np.array([-side - 1, -side, -side + 1, -1, 0, 1,
                                          side - 1, side, side + 1])
        self.contrast = (self.cfg.impulse_contrast if self.cfg.impulse_contrast is not None
                         else 0.5 * (1.0 + psf_contrast(_IMPULSE_PSF_MARGIN * sigma_px,
                                                        worst_phase=True)))
        self.ring_light = 0.5 * psf_ring(_IMPULSE_PSF_MARGIN * sigma_px)

    def detect(self, image: np.ndarray, origins: np.ndarray, psf: PsfEstimate,
               refitted: Callable[[np.ndarray], np.ndarray] | None = None) -> Detections:
        """Stars in the windows whose top-left pixels (x0, y0) are ``origins`` (cells, 2).

        Every window lies inside ``image`` (the planner clips them); ``psf``
        the frame's PSF (the full frames' running estimate); ``refitted``
        (None: none) the mask (n,) of the stars at frame positions (n, 2)
        (x, y) px that the caller centres anew (a trailed star's line-spread
        fit, tracker.detect.trail): those keep their filtered peak's vertex,
        not fitted here (module docstring, step 6). ``refitted`` is called once, on
        every peak kept after the impulse test; ``sources`` then holds, for each star
        of the result, its row among those positions.
        """
        timer = self.timer
        timer.reset()
        for key in self.counters:
            self.counters[key] = 0
        self._configure(psf.sigma_px)
        timer.start("stack")
        self._gather(image, origins)
        timer.start("background")
        self._background()
        timer.start("filter")
        c = self.cell
        np.subtract(self.raw.transpose(1, 0, 2), self.level[None, :, None],
                    out=self.stack[:, :, :c], casting="unsafe")
        cv2.sepFilter2D(self.stack.reshape(self.filt.shape), cv2.CV_32F, self.kernel,
                        self.kernel, dst=self.filt, borderType=cv2.BORDER_CONSTANT)
        np.equal(origins, 0, out=self.edge[:, :2])
        np.equal(origins, self.far_origin, out=self.edge[:, 2:])
        sides = self.edge.any(axis=0)
        if sides.any():
            self._at_frame_edges(sides)
        timer.start("peaks")
        win, py, px = self._peaks(origins)
        timer.start("impulses")
        stamps, inside, keep = self._stamps(image, origins, win, py, px)
        win, py, px, stamps = win[keep], py[keep], px[keep], stamps[keep]
        inside = None if inside is None else inside[keep]
        timer.start("centroid")
        count = self._measure(origins, win, py, px, stamps, inside, refitted)
        timer.stop()
        return self.table.result(count, None, self.counters, timer.ms, psf)

    def _gather(self, image: np.ndarray, origins: np.ndarray) -> None:
        self.raw[...] = window_view(image, self.cell)[origins[:, 1], origins[:, 0]]

    def _background(self) -> None:
        """Each window's level and pixel noise from its border ring (module docstring)."""
        pixels = self.raw.reshape(self.cells, -1)[:, self.ring]
        # the order statistics by sorting the integer rows: a fifth of a partition's work
        # for four ranks
        q1, m0, m1, q3 = np.sort(pixels, axis=1)[:, self.ring_ranks].astype(np.float32).T
        np.multiply(m0 + m1, 0.5, out=self.level)
        ring = pixels.astype(np.float32)
        # quartiles of whole ADU are coarse for a noise of a few ADU: they only set the
        # clip of the RMS that gives the noise (Gaussian noise clipped at _CLIP_SIGMAS
        # keeps _CLIPPED_VARIANCE of its variance)
        clip = np.maximum((q3 - q1) * (_CLIP_SIGMAS / _IQR_SIGMAS), _CLIP_SIGMAS)
        np.subtract(ring, self.level[:, None], out=ring)
        inside = np.abs(ring) <= clip[:, None]
        np.multiply(ring, ring, out=ring)
        ring *= inside
        var = (ring.sum(axis=1) / np.maximum(inside.sum(axis=1), 1)
               / _CLIPPED_VARIANCE)
        np.sqrt(var, out=self.noise)
        np.maximum(self.noise, QUANTISATION_NOISE_ADU, out=self.noise)

    def _at_frame_edges(self, sides: np.ndarray) -> None:
        """The filtered windows' pixels within the filter's half-width of a border that is
        the frame's edge (``sides`` (4,): some window's left, top, right, bottom border is;
        which ones in ``edge``) over the noise gain of the taps inside the frame (module
        docstring, step 3), in place (top and bottom rows first, then the columns)."""
        c, half, gain = self.cell, self.half, self.edge_gain
        filt = self.filt.reshape(c, self.cells, -1)
        for side, rows, cols, by in ((1, slice(0, half), slice(0, c), gain[:, None]),
                                     (3, slice(c - half, c), slice(0, c), gain[::-1, None]),
                                     (0, slice(None), slice(0, half), gain),
                                     (2, slice(None), slice(c - half, c), gain[::-1])):
            if sides[side]:
                for window in self.edge[:, side].nonzero()[0]:
                    filt[rows, window, cols] /= by

    def _peaks(self, origins: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(window, row, column) of the local maxima above threshold, most significant first."""
        n, c = self.cells, self.cell
        width = self.limit.shape[1]
        cv2.dilate(self.filt, _NEIGHBOURS, dst=self.dilated)
        # the tests run over the whole filtered image, gaps included (whole rows: a third
        # of the time of the windows' strided view); a gap's pixels lie beyond every
        # window's last column, which the margins below leave out
        np.greater_equal(self.filt, self.dilated, out=self.peak)
        np.multiply(self.noise, self.k_sigma * self.filter_gain, out=self.limit[:, 0])
        self.limit[:, 1:] = self.limit[:, :1]
        np.greater(self.filt, self.limit.reshape(-1), out=self.above)
        np.logical_and(self.peak, self.above, out=self.peak)
        hits = self.peak.ravel().nonzero()[0]
        py, rest = np.divmod(hits, n * width)
        win, px = np.divmod(rest, width)
        filt = self.filt.reshape(c, n, width)
        # the rows and columns a peak may take in its window: ``margin`` from an inner
        # border (a gap's columns, from c on, beyond any), up to a border that is the
        # frame's edge
        low = np.where(self.edge[:, :2], 0, self.margin)[win]              # (x, y)
        high = np.where(self.edge[:, 2:], c - 1, c - 1 - self.margin)[win]
        inside = ((px >= low[:, 0]) & (px <= high[:, 0])
                  & (py >= low[:, 1]) & (py <= high[:, 1]))
        win, py, px = win[inside], py[inside], px[inside]
        significance = filt[py, win, px] / self.noise[win]
        # most significant first; equal ones by window, row, column
        order = np.lexsort(((win * c + py) * c + px, -significance))
        win, py, px = win[order], py[order], px[order]
        # overlapping windows see one star's peak at one frame pixel: kept once
        at = (origins[win, 1] + py) * self.frame_shape[1] + origins[win, 0] + px
        by_at = at.argsort(kind="stable")
        at = at[by_at]
        new = np.ones(len(at), bool)
        np.not_equal(at[1:], at[:-1], out=new[1:])
        first = by_at[new]
        first.sort()
        first = first[:self.max_candidates]
        self.counters["candidates"] = len(first)
        return win[first], py[first], px[first]

    def _stamps(self, image: np.ndarray, origins: np.ndarray, win: np.ndarray, py: np.ndarray,
                px: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Each peak's stamp (m, side^2) of frame pixels, impulses replaced by their 3 x 3
        median and the pixels beyond the frame by the window's level; the mask (m, side^2)
        of the pixels inside the frame (None: all are); and the mask of peaks kept (module
        docstring, step 5)."""
        m = len(win)
        side = 2 * self.radius + 1
        big = side + 2
        corner = self.radius + 1
        keep = np.ones(m, bool)
        if m == 0:
            return np.zeros((0, side * side)), None, keep
        h, w = self.frame_shape
        top = origins[win, 1] + py - corner
        left = origins[win, 0] + px - corner
        cut = (top < 0) | (left < 0) | (top > h - big) | (left > w - big)
        wide = window_view(image, big)[np.clip(top, 0, h - big),
                                        np.clip(left, 0, w - big)].astype(np.float32)
        inside = None
        if cut.any():
            # the frame's border pixels repeated beyond it (read only by the median)
            rows = top[cut, None] + np.arange(big)
            cols = left[cut, None] + np.arange(big)
            wide[cut] = image[np.clip(rows, 0, h - 1)[:, :, None],
                              np.clip(cols, 0, w - 1)[:, None, :]]
            in_rows = (rows[:, 1:-1] >= 0) & (rows[:, 1:-1] < h)
            in_cols = (cols[:, 1:-1] >= 0) & (cols[:, 1:-1] < w)
            inside = np.ones((m, side * side), bool)
            inside[cut] = (in_rows[:, :, None] & in_cols[:, None, :]).reshape(-1, side * side)
        # the median of each stamp's own pixels: the outer ring (only read by the median)
        # keeps the stamps apart in the image OpenCV filters, the stamps side by side (its
        # float median runs along rows: a tall image of stamp-wide rows costs 15 times more)
        row = np.ascontiguousarray(wide.transpose(1, 0, 2)).reshape(big, m * big)
        median = cv2.medianBlur(row, 3).reshape(big, m, big).transpose(1, 0, 2)
        stamps = wide[:, 1:-1, 1:-1].astype(np.float64)
        median = median[:, 1:-1, 1:-1].reshape(m, -1)
        stamps = stamps.reshape(m, -1)
        level = self.level[win].astype(np.float64)[:, None]
        noise = self.noise[win].astype(np.float64)[:, None]
        rise = np.abs(stamps - median)
        spike = (rise > self.cfg.impulse_sigma * noise) & (
            rise > self.contrast * (np.maximum(stamps, median) - level))
        if inside is not None:
            spike &= inside
            np.copyto(stamps, np.broadcast_to(level, stamps.shape), where=~inside)  # no light
        # a candidate whose brightest central pixel is an impulse with no star's light
        # around it is a hot pixel or a one-pixel hit
        rows = np.arange(m)
        brightest = self.centre9[np.argmax(stamps[:, self.centre9], axis=1)]
        around = brightest[:, None] + (self.centre9 - self.centre9[4])[None, :]
        value = stamps[rows, brightest] - level[:, 0]
        ring = stamps[rows[:, None], around].sum(axis=1) - value - 9.0 * level[:, 0]
        alone = spike[rows, brightest] & (ring < self.ring_light * value)
        keep &= ~alone
        self.counters["hot_pixels"] = int(np.count_nonzero(alone))
        self.counters["impulse_pixels"] = int(np.count_nonzero(spike))
        np.copyto(stamps, median, where=spike)
        return stamps, inside, keep

    def _measure(self, origins: np.ndarray, win: np.ndarray, py: np.ndarray, px: np.ndarray,
                 raw: np.ndarray, inside: np.ndarray | None,
                 refitted: Callable[[np.ndarray], np.ndarray] | None) -> int:
        """Centroid, photometry, shape tests and flags (module docstring, step 6) of the
        stamps ``raw`` (m, side^2), ``inside`` their pixels in the frame (None: all), the
        stars ``refitted`` masks (:meth:`detect`) left at their vertices; the stars kept
        go to the table, most significant first. Returns their count."""
        m = len(win)
        if m == 0:
            self.sources = np.zeros(0, np.intp)
            return 0
        r = self.radius
        side = 2 * r + 1
        noise = self.noise[win].astype(np.float64)
        signal = raw - self.level[win, None].astype(np.float64)
        x, y = self._vertex(win, py, px)
        # peaks closer than the blend radius (the full frame's): a single star's model
        # fitted to a stamp holding two is pulled between them, while a Gaussian weight
        # keeps most of the neighbour out
        col, row = origins[win, 0] + px, origins[win, 1] + py
        at_x, at_y = col.astype(np.float64), row.astype(np.float64)
        blend = 2.0 * r if self.cfg.blend_radius_px is None else float(self.cfg.blend_radius_px)
        # whole pixels: exact in any order
        close = np.square(at_x[:, None] - at_x[None, :])
        close += np.square(at_y[:, None] - at_y[None, :])
        blended = (close <= blend * blend).sum(axis=1) > 1   # itself and another
        # the stars the caller centres anew keep the vertex (their point fit or windowed
        # centroid would be thrown away)
        centred = (~refitted(np.stack((at_x + x, at_y + y), axis=1))
                   if refitted is not None else True)
        # every unblended star's first steps in one fit (a fit's cost is mostly its
        # steps' numpy calls); those the edge cuts continue alone, from their fluxes
        single = (~blended & centred).nonzero()[0]
        flux = self._fit(single, _FIT_STEPS, signal, raw, noise, inside, x, y)
        if inside is not None and len(single):
            cut = ~inside[single].all(axis=1)
            if cut.any():
                self._fit(single[cut], _EDGE_FIT_STEPS - _FIT_STEPS, signal, raw, noise,
                          inside, x, y, flux[cut])
        pair = (blended & centred).nonzero()[0]
        if len(pair):
            x[pair], y[pair] = self._windowed(signal[pair].reshape(-1, side, side), x[pair],
                                              y[pair])
        grid = signal.reshape(m, side, side)
        e = self.stamp_axis - np.array((x, y))[:, :, None]     # (2, m, side): x, y
        e2 = e * e
        g = np.exp((-0.5 / self.expected_size) * e2)
        gx, gy = g
        # the Gaussian weight is separable: profiles weighted along one axis, then moments
        along = self._along_rows(grid, e, g)
        profiles = np.empty((2, m, side))                      # weighted over columns, rows
        np.multiply(along[:, 0], gx, out=profiles[0])
        np.multiply(np.matmul(grid, gx[:, :, None])[:, :, 0], gy, out=profiles[1])
        weighted = profiles[0].sum(axis=1)
        norm = np.sqrt((g * g).sum(axis=2).prod(axis=0))
        snr = weighted / (noise * norm)
        total = np.maximum(weighted, 1e-12)
        mxx, myy = (profiles * e2).sum(axis=2) / total
        mxy = (along[:, 1] * gx * e[0]).sum(axis=1) / total
        size = mxx + myy
        ellipticity = np.hypot(mxx - myy, 2.0 * mxy) / np.maximum(size, 1e-12)
        across_x, across_y = cut_axes(row, col, self.frame_shape, r)
        judge_whole({"mxx": mxx, "myy": myy, "mxy": mxy, "size": size,
                     "ellipticity": ellipticity}, across_x, across_y)
        width = 0.5 * size * (1.0 - ellipticity) / (0.5 * self.expected_size)
        judged = snr >= self.cfg.sharp_min_snr
        spot = (weighted > 0) & (size > 0) & (ellipticity <= 1.0)
        track = (width < _TRACK_WIDTH) & (ellipticity > _TRACK_ELLIPTICITY)
        sharp = judged & (~spot | (width < self.cfg.sharp_size_ratio) | track)
        self.counters["sharp_spots"] = int(np.count_nonzero(sharp))
        self.counters["cosmic_rays"] = self.counters["sharp_spots"]
        fx, fy = at_x + x, at_y + y
        # a star centred beyond the frame shows less than half its light: no centre
        off = beyond_frame(fx, fy, self.frame_shape)
        self.counters["beyond_edge"] = int(np.count_nonzero(off))
        keep = (~(sharp | off)).nonzero()[0]
        keep = keep[np.argsort(-snr[keep], kind="stable")]
        # one star's detections in two windows: the later within _SAME_STAR_PX of an
        # earlier one left out
        keep = keep[~later_within(fx[keep], fy[keep], _SAME_STAR_PX)]
        self.counters["left_out"] = max(0, len(keep) - self.table.capacity)
        keep = keep[:self.table.capacity]
        self.sources = keep
        count = len(keep)
        s = self.table.stars
        s["x"][:count], s["y"][:count] = fx[keep], fy[keep]
        kept = signal[keep]
        s["flux"][:count] = kept.sum(axis=1)
        s["peak"][:count] = kept[:, self.centre9].max(axis=1)
        s["snr"][:count] = snr[keep]
        s["npix"][:count] = (kept > 3.0 * noise[keep, None]).sum(axis=1)
        # the flags' bits (_FLAGS) of every star, summed over the kept ones' in one product
        bits = np.empty((len(_FLAGS), m), bool)
        np.greater_equal(raw[:, self.centre9].max(axis=1), self.saturation, out=bits[0])
        np.greater(ellipticity, self.cfg.elongation_max, out=bits[1])
        bits[1] &= judged
        bits[2] = blended
        np.logical_or(across_x, across_y, out=bits[3])
        s["flags"][:count] = _FLAGS @ bits[:, keep]
        return count

    def _fit(self, which: np.ndarray, steps: int, signal: np.ndarray, raw: np.ndarray,
             noise: np.ndarray, inside: np.ndarray | None, x: np.ndarray,
             y: np.ndarray, flux0: np.ndarray | None = None) -> np.ndarray:
        """The PSF's fit (``steps`` Gauss-Newton steps) to the stamps ``which`` of
        ``signal`` and ``raw`` (m, side^2), on their pixels ``inside`` the frame (None:
        all); their centres ``x``, ``y`` (m,), px from the peak pixels, refined in place,
        from the fluxes ``flux0`` (None: the stamps' sums). Returns their fitted fluxes
        (a copy)."""
        if len(which) == 0:
            return np.zeros(0)
        self.fit.iterations = steps
        if len(which) == len(x):             # every stamp: no copies
            return self.fit.run(len(x), signal, raw, x, y, noise, self.saturation,
                                _MAX_SHIFT_PX, inside, flux0).copy()
        fx, fy = x[which], y[which]
        flux = self.fit.run(len(which), signal[which], raw[which], fx, fy, noise[which],
                            self.saturation, _MAX_SHIFT_PX,
                            None if inside is None else inside[which], flux0)
        x[which], y[which] = fx, fy
        return flux.copy()

    def _windowed(self, grid: np.ndarray, x: np.ndarray,
                  y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gaussian-windowed centroids (tracker.detect.windowed: weight of the PSF's sigma,
        gain 2; ``_BLEND_STEPS`` steps) of stamps ``grid`` (m, side, side) from (x, y) px
        off their centres."""
        inv = -0.5 / self.expected_size
        pos = np.array((x, y))                                   # (2, m)
        for _ in range(_BLEND_STEPS):
            e = self.stamp_axis - pos[:, :, None]                # (2, m, side): x, y
            g = np.exp(inv * e * e)
            cols = self._along_rows(grid, e, g)                  # (m, 2, side)
            sums = np.matmul(cols, g[0][:, :, None])[:, :, 0].T  # (total, sum g e_y)
            step = np.array(((cols[:, 0] * g[0] * e[0]).sum(axis=1), sums[1]))
            step *= 2.0 / np.where(sums[0] > 0, sums[0], np.inf)   # no light: no step
            pos = np.minimum(np.maximum(pos + step, -_MAX_SHIFT_PX), _MAX_SHIFT_PX)
        return pos[0], pos[1]

    @staticmethod
    def _along_rows(grid: np.ndarray, e: np.ndarray, g: np.ndarray) -> np.ndarray:
        """(m, 2, side): the stamps ``grid`` (m, side, side) summed over rows weighted by
        g_y and by g_y e_y (``e``, ``g`` (2, m, side): offsets and Gaussian weights along
        x and y), one batched matrix product (np.einsum parses its subscripts anew each
        call: 4 times the product's cost on a frame's stamps)."""
        by_row = np.empty((g.shape[1], 2, g.shape[2]))
        by_row[:, 0] = g[1]
        np.multiply(g[1], e[1], out=by_row[:, 1])
        return np.matmul(by_row, grid)

    def _vertex(self, win: np.ndarray, py: np.ndarray,
                px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The filtered peak's parabolic vertex per axis, px from the peak pixel (|.| <= 0.5;
        0 across a window's top or bottom row, where the filter has no neighbour): the peak
        and its four neighbours read in one gather, both axes at once."""
        at = (py * self.cells + win) * (self.filt.shape[1] // self.cells) + px
        near = self.filt.ravel().take(at[:, None] + self.cross,
                                      mode="clip").astype(np.float64)  # (m, 5)
        lo, hi = near[:, 1::2], near[:, 2::2]        # (left, up), (right, down)
        curve = lo - 2.0 * near[:, :1] + hi
        bent = curve < 0
        offset = np.where(bent, 0.5 * (lo - hi) / np.where(bent, curve, -1.0), 0.0)
        np.maximum(offset, -0.5, out=offset)
        np.minimum(offset, 0.5, out=offset)
        offset[(py == 0) | (py == self.cell - 1), 1] = 0.0
        return offset[:, 0], offset[:, 1]
