"""Robust per-tile level and noise on a coarse grid, interpolated to full size.

The frame is cut into a grid of tiles about ``tile_px`` square. In each tile
a fixed lattice of pixels, every ``step_px`` rows and columns, is sorted and
its middle half kept (stars, hot pixels and cosmic rays, which sit in the
top few per cent, and dark impulses, in the bottom few, drop out):

* level = mean of the middle half (the interquartile mean: unbiased for
  symmetric noise and, unlike a median, not stuck to whole ADU steps);
* noise = mean |value - level| over the middle half / 0.3247, the ratio of
  that mean to sigma for a Gaussian (2 (phi(0) - phi(0.6745)) / 0.5).

Integer frames are read on a lattice: a middle half or a percentile of
integers is stuck to whole ADU (rounded Gaussian noise of 0.7 ADU reads
1.26). Their spread is measured on the samples plus a fixed uniform dither
on (-1/2, 1/2), which spreads each over its unit bin (the samples' histogram,
not its lattice), and the 1/12 ADU^2 the independent dither adds is taken
off: what remains is the integers' own noise, rounding included (rounding
is noise the filters see too). The level stays the integers' own.

The noise of an integer frame's tile is measured on its samples less its trend:
the plane through the tile's centre along the slopes its level rises by toward
its neighbours on either side, the smaller where the two agree in sign, else
none (the minmod limiter below). A smooth gradient of glare is no noise, but
about a tile's constant level it spread the samples (5 ADU/px across 32 px
tiles: 46 ADU, beside photon noise of 20), and hot pixels, particles' charge and
noise peaks on glare passed tests of twice the noise that was there. A body's
edge beside a flat tile (a step beside no step) takes no trend off.

Both grids then pass a 3x3 median (a tile swamped by a bright star or a
cluster takes its neighbours' value), and noise is floored at ``floor``.
At the grid's border the median reads a ring of tiles extended along the
ramp the border's tiles rise on, not the border tiles repeated: on a ramp,
a corner tile's repeated neighbourhood holds five values a tile's step or
more below it (rising toward the corner) and its median read one step low,
e.g. 7.5 ADU under glare rising 0.23 ADU/px per axis on 32 px tiles, 10
filtered noises, so the frame's corners reported the noise as stars. Beyond
a border tile g0 (then g1, g2 inward) the ring holds g0 + minmod(g0 - g1,
g1 - g2): the smaller of the two steps where they agree in sign, else none
(the minmod slope limiter): a ramp is extended exactly and is the tile's
own value in the median, while the tiles' noise (two steps of opposite
sign) and a body's edge (a step beside a flat) extend flat, as before, and
so does an axis of three tiles (its two steps reach the far border).
:meth:`BackgroundGrid.upsample` interpolates a grid bilinearly to the full
frame, which follows gradients and glare on scales of a few tiles;
:meth:`BackgroundGrid.at` reads a grid at single pixels (nearest tile);
:meth:`BackgroundGrid.skewness` gives the typical skewness of the tiles.
All buffers are made once.
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout
from tracker.detect.order import median
from tracker.detect.sky_split import sky_class_size, sky_part
from tracker.detect.slabs import SlabRunner
from tracker.normal import erf

__all__ = ["BackgroundGrid", "QUANTISATION_NOISE_ADU"]

QUANTISATION_NOISE_ADU = float(np.sqrt(1.0 / 12.0))
_MEAN_ABS_IN_IQR = 0.3247  # E|z| for a standard normal z restricted to its middle half
_ONE_SIGMA_ABOVE = 0.84134  # fraction of a Gaussian below mean + sigma
_TRIM_FRACTION = 1.0 / 16.0  # trimmed noise: drop this fraction of samples at each end
_DITHER_SEED = 12         # of the fixed dither of integer samples (any seed will do)


def _truncated_normal_std(p: float) -> float:
    """Standard deviation of a unit normal without its lowest and highest fraction ``p``."""
    a = float(-np.sqrt(2.0) * _erfinv(2.0 * p - 1.0))       # Phi^-1(1 - p)
    pdf = float(np.exp(-0.5 * a * a) / np.sqrt(2.0 * np.pi))
    return float(np.sqrt(1.0 - 2.0 * a * pdf / (1.0 - 2.0 * p)))


def _erfinv(y: float) -> float:
    """Inverse error function by Newton's method on tracker.normal.erf (|y| < 1)."""
    x = 0.0
    for _ in range(60):
        x -= (float(erf(np.array(x))) - y) / (2.0 / np.sqrt(np.pi) * np.exp(-x * x))
    return x


def _mean(a: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Mean of ``a`` along its last axis into ``out``. einsum's sum takes a quarter of
    np.add.reduce's time on the short tile axis (its order differs: float32 sums of
    the same values agree to a few units in their last place, and exactly for whole
    numbers summing to under 2^24, such as a middle half of uint16 reads)."""
    np.einsum("...k->...", a, out=out)
    return np.true_divide(out, a.shape[-1], out=out)


def _tile_lattice(length: int, tiles: int, step: int) -> np.ndarray:
    """(tiles, m) sample coordinates along one axis: m evenly spaced points per tile."""
    size = length / tiles
    per = max(1, int(np.floor(size / step)))
    pos = (np.arange(tiles)[:, None] + (np.arange(per)[None, :] + 0.5) / per) * size
    return np.clip(np.floor(pos).astype(np.intp), 0, length - 1)


def _tile_of(length: int, tiles: int, pad: int, padded_length: int) -> np.ndarray:
    """Tile number of every padded coordinate along one axis (border: nearest tile)."""
    coord = np.arange(padded_length) - pad
    return np.clip(np.floor((coord + 0.5) * tiles / length).astype(np.intp), 0, tiles - 1)


class BackgroundGrid:
    """Tile statistics of frames held in padded buffers of ``layout``."""

    def __init__(self, layout: PaddedLayout, tile_px: int, step_px: int,
                 capacity: int) -> None:
        rows, cols = layout.rows, layout.cols
        self.layout = layout
        self.grid_shape = (max(1, round(rows / tile_px)), max(1, round(cols / tile_px)))
        ny, nx = self.grid_shape
        ys = _tile_lattice(rows, ny, step_px) + layout.pad
        xs = _tile_lattice(cols, nx, step_px) + layout.pad
        index = ys[:, None, :, None] * layout.stride + xs[None, :, None, :]
        self.index = np.ascontiguousarray(index.reshape(ny, nx, -1))
        m = self.index.shape[-1]
        self.samples = np.zeros(self.index.shape, np.float32)
        self.minus_samples = np.zeros(self.index.shape, np.float32)
        self.int_samples = np.zeros(self.index.shape, np.uint16)  # reads of uint16 frames
        self.middle = self.samples[..., m // 4: m - m // 4]
        # integer frames: a fixed uniform dither on (-1/2, 1/2) spreads each sample over
        # its unit bin (the same every frame: the same frame gives the same statistics);
        # stratified: each tile's m values are (k + 1/2) / m - 1/2 in a shuffled order
        even = ((np.arange(m) + 0.5) / m - 0.5).astype(np.float32)
        # (contiguous: Generator.permuted's strides made each frame's addition six times
        # slower)
        self.dither = np.ascontiguousarray(np.random.default_rng(_DITHER_SEED).permuted(
            np.broadcast_to(even, self.index.shape), axis=-1))
        self.rounded = np.zeros(self.index.shape, np.float32)
        # each sample's offset from its tile's mean sample position, px (the plane a
        # tile's trend is taken off along), and the samples less it, sorted
        offset_y = ys - ys.mean(axis=1, keepdims=True)
        offset_x = xs - xs.mean(axis=1, keepdims=True)
        self.offset_y = np.ascontiguousarray(np.broadcast_to(
            offset_y[:, None, :, None], (ny, nx, ys.shape[1], xs.shape[1])).reshape(ny, nx, m),
            dtype=np.float32)
        self.offset_x = np.ascontiguousarray(np.broadcast_to(
            offset_x[None, :, None, :], (ny, nx, ys.shape[1], xs.shape[1])).reshape(ny, nx, m),
            dtype=np.float32)
        self.spacing = (rows / ny, cols / nx)       # between tile centres, px
        self.detrended = np.zeros(self.index.shape, np.float32)
        self.trend = np.zeros(self.index.shape, np.float32)
        self.slope = np.zeros((2,) + self.grid_shape, np.float32)
        self.deviation = np.zeros(self.middle.shape, np.float32)
        self.raw = np.zeros(self.grid_shape, np.float32)
        self.level_raw = np.zeros(self.grid_shape, np.float32)
        self.sky_size = np.zeros(self.grid_shape, np.intp)   # sky samples of dark_side tiles
        self.upper = np.zeros(self.grid_shape, np.float32)
        self.trimmed = np.zeros(self.grid_shape, np.float32)
        self.smoothed = np.zeros(self.grid_shape, np.float32)
        self.extended = np.zeros((ny + 2, nx + 2), np.float32)   # _smooth's ring ...
        self.extended_median = np.zeros((ny + 2, nx + 2), np.float32)   # ... its median
        self.steps = np.zeros((2, max(ny, nx) + 2), np.float32)   # ... and the border's
        self._upper = int(round(_ONE_SIGMA_ABOVE * (m - 1)))
        self._trim = max(1, int(round(_TRIM_FRACTION * m)))
        self._trimmed_std = _truncated_normal_std(self._trim / m)
        self.trim_dev = np.zeros((ny, nx, max(m - 2 * self._trim, 0)), np.float32)
        self.trim_pow = np.zeros(self.trim_dev.shape, np.float32)
        self.moment2 = np.zeros(self.grid_shape, np.float32)
        self.moment3 = np.zeros(self.grid_shape, np.float32)
        self._third_due = False
        self.spread3 = np.zeros(self.grid_shape, np.float32)  # m2^1.5
        self.star_free = np.zeros(self.grid_shape, np.bool_)
        self.above = np.zeros(self.grid_shape, np.int32)   # samples above the level
        self.is_above = np.zeros(self.index.shape, np.bool_)   # samples above their level
        self.pooled = np.zeros(self.grid_shape, np.float32)
        self.above_near = np.zeros(self.grid_shape, np.int32)   # above(), 3x3 summed
        # lattice samples in each tile's 3x3 neighbourhood (fewer at the grid's border)
        self.samples_near = cv2.boxFilter(np.full(self.grid_shape, float(m), np.float32), -1,
                                          (3, 3), normalize=False,
                                          borderType=cv2.BORDER_CONSTANT).astype(np.int32)

        # each tile row's first frame row, and one past its last
        self.row_edges = np.searchsorted(_tile_of(rows, ny, 0, rows), np.arange(ny + 1))
        self.col_tile = _tile_of(cols, nx, 0, cols)      # each frame column's tile
        tile_rows = _tile_of(rows, ny, layout.pad, layout.full_shape[0])
        tile_cols = _tile_of(cols, nx, layout.pad, layout.stride)
        self.tile_index = (tile_rows[:, None] * nx + tile_cols[None, :]).astype(np.int32).ravel()
        self.tile_scratch = np.zeros(int(capacity), np.int32)
        # a row of tiles' frame rows (cap_over_in_tiles)
        self.band = np.zeros((int(np.max(np.diff(self.row_edges))), cols), np.float32)

    def above_nearby(self) -> np.ndarray:
        """Lattice samples above their tile's level in each tile's 3x3 neighbourhood, after
        the last :meth:`stats` of an integer frame (grid shape, int32; of
        ``samples_near``). On a sky flat to within its rounding they bound how often
        its pixels read above it (tracker.detect.threshold.constant_sky_rate); a star's
        light on the lattice only raises the bound."""
        np.copyto(self.pooled, self.above, casting="unsafe")
        cv2.boxFilter(self.pooled, -1, (3, 3), dst=self.pooled, normalize=False,
                      borderType=cv2.BORDER_CONSTANT)
        np.copyto(self.above_near, self.pooled, casting="unsafe")
        return self.above_near

    def stats(self, padded: np.ndarray, level: np.ndarray, noise: np.ndarray,
              floor: float, upper: bool = False, minus: bool = False,
              dark_side: np.ndarray | None = None,
              sky_split: np.ndarray | None = None, resample: bool = True,
              slabs: SlabRunner | None = None) -> None:
        """Per-tile level and noise (grid shape, units of ``padded``) into the given arrays.

        ``padded`` is float32 or uint16. With ``minus`` the statistics are
        those of ``padded`` less the image the last :meth:`sample_minus` call
        read, computed on the sampled pixels only. Tiles marked in
        ``dark_side`` (bool, grid shape) take both from the darker part of
        their sky pixels (tracker.detect.sky_split.sky_part: level the mean of
        their 6th-37th percentiles, noise the 10th-30th percentile distance
        over 0.757): a tile across a horizon or the edge of glare then has the
        sky's level and noise, not a blend of sky and ground. Its sky pixels
        are all its samples, but in the tiles also marked in ``sky_split``,
        whose sky is a minority: there the darker class of a split of the
        samples (tracker.detect.sky_split.sky_class_size). With ``minus``
        each tile keeps the share of sky the last call without it found.

        With ``upper`` the noise is also at least the distance from the level
        up to the 84.13th percentile, and at least the standard deviation of
        the samples without their lowest and highest sixteenth (divided by 0.754, its
        value for Gaussian samples): noise with a long bright tail, or a
        background clipped at zero so that most pixels read exactly 0 (photon
        noise of a few counts), then gets the larger, honest figure, where the
        middle-half estimate would see no spread at all. For Gaussian noise
        all three agree.

        ``resample`` false: ``padded`` is the image of the last call, which was
        made without ``minus`` (a second call for its ``dark_side``): its
        sorted samples are taken as they are, not read and sorted again.

        ``slabs`` (tracker.detect.slabs), if given, reads and sorts the tiles'
        samples in its row slabs (each slab the rows of tiles its frame rows
        begin; the same values as one call), for a caller whose workers are idle.
        """
        m = self.samples.shape[-1]
        lattice = padded.dtype == self.int_samples.dtype and not minus
        if resample:
            self._sample(padded, minus, lattice, slabs)
        # the level from the integers as read (in the same order: the dither is under
        # half a step), not the histogram's (a tile of zeros with a few ones would
        # read 0.02)
        values = self.rounded if lattice else self.samples
        _mean(values[..., m // 4: m - m // 4], self.level_raw)
        if lattice:
            np.greater(values, self.level_raw[..., None], out=self.is_above)
            np.einsum("...k->...", self.is_above.view(np.uint8), out=self.above,
                      dtype=np.int32, casting="unsafe")
        split = dark_side is not None and np.any(dark_side)
        if split:
            if not minus:
                self.sky_size[dark_side] = m
                if sky_split is not None and np.any(sky_split):
                    self.sky_size[sky_split] = sky_class_size(self.samples[sky_split])
            self.level_raw[dark_side], sky_noise = sky_part(
                values[dark_side], self.samples[dark_side], self.sky_size[dark_side])
        self._smooth(self.level_raw, level)
        # about the level: the trend's plane has no mean over the tile's samples
        spread = self._detrend() if lattice else self.samples
        centre = self.level_raw
        np.subtract(spread[..., m // 4: m - m // 4], centre[..., None], out=self.deviation)
        np.abs(self.deviation, out=self.deviation)
        _mean(self.deviation, self.raw)
        np.multiply(self.raw, 1.0 / _MEAN_ABS_IN_IQR, out=self.raw)
        estimates = [self.raw]
        if upper:
            np.subtract(spread[..., self._upper], centre, out=self.upper)
            trimmed = spread[..., self._trim:m - self._trim]
            _mean(trimmed, self.moment2)
            np.subtract(trimmed, self.moment2[..., None], out=self.trim_dev)
            np.multiply(self.trim_dev, self.trim_dev, out=self.trim_pow)
            _mean(self.trim_pow, self.moment2)
            self._third_due = True    # skewness() takes the third moment from these
            if lattice:
                np.subtract(self.moment2, 1.0 / 12.0, out=self.moment2)
                np.maximum(self.moment2, 0.0, out=self.moment2)
            np.sqrt(self.moment2, out=self.trimmed)
            np.multiply(self.trimmed, 1.0 / self._trimmed_std, out=self.trimmed)
            estimates += [self.upper, self.trimmed]
        if split:
            for estimate in estimates:
                estimate[dark_side] = sky_noise
        if lattice:
            # the dithered samples are the integers plus an independent uniform of
            # variance 1/12: the integers' own spread is what remains (the trimmed
            # variance has had it taken off already)
            for estimate in estimates[:2]:
                np.multiply(estimate, estimate, out=estimate)
                np.subtract(estimate, 1.0 / 12.0, out=estimate)
                np.maximum(estimate, 0.0, out=estimate)
                np.sqrt(estimate, out=estimate)
        # each estimate smoothed on its own, then the largest: the largest of
        # three noisy estimates of one tile would be biased upwards (6 % for
        # Gaussian noise), that of their 3x3 medians much less

        self._smooth(self.raw, noise)
        for estimate in estimates[1:]:
            np.maximum(self.raw, estimate, out=self.raw)   # per tile, for skewness()
            self._smooth(estimate, self.smoothed)
            np.maximum(noise, self.smoothed, out=noise)
        np.maximum(noise, floor, out=noise)

    def _detrend(self) -> np.ndarray:
        """The last integer frame's dithered samples less each tile's trend (module
        docstring), sorted per tile (``detrended``, returned). The slopes, ADU/px, are
        the steps of ``level_raw`` between tile centres; a border tile's other side is
        the next step inward (a ramp extended, as the border's ring in :meth:`_smooth`),
        and an axis of fewer than three tiles takes none."""
        ny, nx = self.grid_shape
        for axis, (count, step) in enumerate(((ny, self.spacing[0]), (nx, self.spacing[1]))):
            slope = self.slope[axis]
            if count < 3:
                slope.fill(0.0)
                continue
            steps = np.diff(self.level_raw, axis=axis) / np.float32(step)
            # a border tile's other side: the next step inward (its ramp extended)
            before = np.concatenate([steps.take([1], axis=axis), steps], axis=axis)
            after = np.concatenate([steps, steps.take([-2], axis=axis)], axis=axis)
            np.minimum(np.maximum(before, 0.0), np.maximum(after, 0.0), out=slope)
            slope += np.maximum(np.minimum(before, 0.0), np.minimum(after, 0.0))
            # a rise of under an ADU across the tile is below the integers' resolution
            slope[np.abs(slope) * np.float32(step) < 1.0] = 0.0
        np.add(self.int_samples, self.dither, out=self.detrended)
        np.multiply(self.offset_y, self.slope[0][..., None], out=self.trend)
        np.subtract(self.detrended, self.trend, out=self.detrended)
        np.multiply(self.offset_x, self.slope[1][..., None], out=self.trend)
        np.subtract(self.detrended, self.trend, out=self.detrended)
        self.detrended.sort(axis=-1)
        return self.detrended

    def _sample(self, padded: np.ndarray, minus: bool, lattice: bool,
                slabs: SlabRunner | None) -> None:
        """Read ``padded`` at the tiles' lattice into ``samples``, sorted per tile (less
        the last :meth:`sample_minus` image with ``minus``; an integer lattice read
        plus the dither, its integers also in ``rounded``), in ``slabs`` if given."""
        if slabs is None:
            self._sample_tiles(padded, minus, lattice, 0, self.grid_shape[0])
            return
        ny, rows = self.grid_shape[0], self.layout.rows
        slabs.rows(lambda a, b: self._sample_tiles(padded, minus, lattice,
                                                        a * ny // rows, b * ny // rows))

    def _sample_tiles(self, padded: np.ndarray, minus: bool, lattice: bool, first: int,
                      end: int) -> None:
        """:meth:`_sample` on the rows of tiles [first, end)."""
        tiles = np.s_[first:end]
        samples, ints = self.samples[tiles], self.int_samples[tiles]
        if padded.dtype == self.int_samples.dtype:
            np.take(padded.ravel(), self.index[tiles], out=ints, mode="clip")
            if lattice:    # the integers (exact in float32) plus the dither, in one pass
                np.add(ints, self.dither[tiles], out=samples)
            else:
                np.copyto(samples, ints)
        else:
            np.take(padded.ravel(), self.index[tiles], out=samples, mode="clip")
        if minus:
            np.subtract(samples, self.minus_samples[tiles], out=samples)
        samples.sort(axis=-1)
        if lattice:
            np.rint(samples, out=self.rounded[tiles])

    def sample_minus(self, minus: np.ndarray) -> None:
        """Read ``minus`` (float32, padded like the frames) at the sampled pixels, for
        the :meth:`stats` calls with ``minus`` until the next call (one gather of an
        image fixed for a frame, which a worker thread can make ahead)."""
        np.take(minus.ravel(), self.index, out=self.minus_samples, mode="clip")

    def skewness(self, star_free_sigma: float = 5.0, min_fraction: float = 0.5) -> float:
        """Median skewness of the star-free tiles of the last :meth:`stats` call (``upper``).

        A tile is star-free when its highest sample is less than
        ``star_free_sigma`` times its noise above its level. Each such tile's
        samples without their lowest and highest (as for the trimmed noise)
        give m3 / m2^1.5 (0 for a tile with no spread). About 0 for Gaussian
        noise; positive for photon noise of a few counts per pixel. 0 when
        fewer than ``min_fraction`` of the tiles are star-free (a field so
        crowded that star wings would pass for skew).
        """
        if self._third_due:   # once per stats() call, and only for a caller that asks
            np.multiply(self.trim_pow, self.trim_dev, out=self.trim_pow)
            _mean(self.trim_pow, self.moment3)
            self._third_due = False
        np.subtract(self.samples[..., -1], self.level_raw, out=self.spread3)
        np.multiply(self.raw, star_free_sigma, out=self.upper)
        np.less(self.spread3, self.upper, out=self.star_free)
        if np.count_nonzero(self.star_free) < min_fraction * self.star_free.size:
            return 0.0
        np.maximum(self.moment2, 1e-12, out=self.moment2)  # no spread: m3 = 0 too
        np.sqrt(self.moment2, out=self.spread3)
        np.multiply(self.spread3, self.moment2, out=self.spread3)
        np.divide(self.moment3, self.spread3, out=self.spread3)
        return median(self.spread3[self.star_free])

    def _smooth(self, src: np.ndarray, dst: np.ndarray) -> None:
        """3x3 median of a grid into ``dst``, the border's neighbourhoods extended along
        its ramp (module docstring); grids under 3 tiles a side are copied."""
        if min(self.grid_shape) < 3:
            np.copyto(dst, src)
            return
        e = self.extended
        inner = e[1:-1, 1:-1]
        np.copyto(inner, src)
        np.copyto(e[0, 1:-1], inner[0])
        np.copyto(e[-1, 1:-1], inner[-1])
        np.copyto(e[:, 0], e[:, 1])
        np.copyto(e[:, -1], e[:, -2])
        ny, nx = self.grid_shape
        rows = (e[0, 1:-1], inner[0], inner[1], inner[2]), (e[-1, 1:-1], inner[-1], inner[-2],
                                                           inner[-3])
        cols = (e[:, 0], e[:, 1], e[:, 2], e[:, 3]), (e[:, -1], e[:, -2], e[:, -3], e[:, -4])
        # the columns' after the rows' (corners too); a ramp read two steps inward, on
        # tiles short of the far border (three tiles a side: repeated, as before)
        for ring, g0, g1, g2 in (rows if ny > 3 else ()) + (cols if nx > 3 else ()):
            outer, inward = self.steps[0, :len(ring)], self.steps[1, :len(ring)]
            np.subtract(g0, g1, out=outer)
            np.subtract(g1, g2, out=inward)
            np.minimum(inward, 0.0, out=ring)         # minmod(outer, inward): outer held
            np.maximum(inward, 0.0, out=inward)       # between 0 and inward
            np.clip(outer, ring, inward, out=outer)
            np.add(g0, outer, out=ring)
        cv2.medianBlur(e, 3, dst=self.extended_median)
        np.copyto(dst, self.extended_median[1:-1, 1:-1])

    def upsample(self, grid: np.ndarray, dst: np.ndarray) -> np.ndarray:
        """Bilinear interpolation of a grid to the frame (``dst``: interior view)."""
        return cv2.resize(grid, (self.layout.cols, self.layout.rows), dst=dst,
                          interpolation=cv2.INTER_LINEAR)

    def cap_in_tiles(self, grid: np.ndarray, dst: np.ndarray, tiles: np.ndarray) -> None:
        """Hold an upsampled ``dst`` (interior view) at or under ``grid``'s own value in
        the tiles marked in ``tiles`` (bool, grid shape): there the interpolation
        towards a brighter neighbour (a body beyond a sharp edge) is not followed."""
        for ty in np.flatnonzero(tiles.any(axis=1)):
            caps = np.where(tiles[ty], grid[ty], np.inf).astype(dst.dtype)[self.col_tile]
            part = dst[self.row_edges[ty]:self.row_edges[ty + 1]]
            np.minimum(part, caps, out=part)

    def cap_over_in_tiles(self, grid: np.ndarray, dst: np.ndarray, base: np.ndarray,
                          tiles: np.ndarray) -> None:
        """Hold ``dst`` (interior view) at or under ``base`` (an image of its shape) plus
        ``grid``'s own value in the tiles marked in ``tiles`` (bool, grid shape): there
        the interpolation of ``dst`` - ``base`` towards a neighbour's larger value is not
        followed."""
        for ty in np.flatnonzero(tiles.any(axis=1)):
            rows = slice(self.row_edges[ty], self.row_edges[ty + 1])
            band = self.band[:rows.stop - rows.start]
            caps = np.where(tiles[ty], grid[ty], np.inf).astype(dst.dtype)[self.col_tile]
            np.add(base[rows], caps, out=band)
            np.minimum(dst[rows], band, out=dst[rows])

    def at(self, grid: np.ndarray, flat: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Values of ``grid`` at padded flat indices (nearest tile), into ``out``.

        At most ``capacity`` (a constructor argument) indices at a time.
        """
        np.take(self.tile_index, flat, out=self.tile_scratch[: len(flat)], mode="clip")
        return np.take(grid.ravel(), self.tile_scratch[: len(flat)], out=out, mode="clip")
