"""A tile that holds both sky and a body: the sky's level and noise from its sky pixels.

A background tile across a horizon, the Earth's limb or the edge of glare
holds two populations of pixels: the sky's, at the background level with
the sky's noise, and the body's, far brighter and textured. Its statistics
must be the sky's alone, or a star beside the body meets a threshold raised
by the body's light and texture. A fixed slice of the sorted samples (say
their darker third) is the sky's only when the sky fills a known share of
the tile: with a sliver of ground in it the slice sits low in the sky's
distribution (its level too low, its spread too small), with ground over
most of it the slice reaches into the ground.

So the samples are split where two Gaussian classes fit them best: the
minimum-error split of Kittler and Illingworth (1986), the cut i of the
sorted samples minimising w0 ln var0 + w1 ln var1 - 2 (w0 ln w0 + w1 ln w1)
(w the classes' shares, var their variances), -2/m times the log-likelihood
of the two-Gaussian mixture the cut implies. Unlike Otsu's split, which
assumes classes of equal variance and cuts a textured body's broad
distribution in two rather than separate it from the narrow sky, it lets
each class have its own width; and it needs no constant: a body many sky
noises brighter than the sky puts the cut between the two, whatever share
of the tile each fills (on 64 samples of Gaussian sky beside uniform
ground 60-300 noises brighter it finds the sky's exact count for ground
shares of 5-90 %). Each class holds at least two samples (a variance).
The darker class is the sky; its level is the mean of its middle half (the
interquartile mean, as for any tile) and its noise the mean absolute
deviation over that middle half / 0.3247, its value for a Gaussian
(tracker.detect.background's estimators, applied to the sky class alone).

The split is made on the frame as read, where the body's edge is as sharp
as the PSF. The matched-filtered frame spreads the body's light a kernel's
reach into the sky, so its tile holds three populations (sky, the body's
filtered edge, the body), and a flat, saturated body has no spread at all:
a two-class split of the filtered samples pairs the sky with the edge. The
filtered statistics therefore take the sky class as the darkest samples in
the share the split found on the frame (:func:`sky_part`), and, since the
kernel's reach moves the class's brightest samples up into the body's light,
their level from its darker part and their noise from its 10th-30th
percentiles (their distance over 0.757, its value for a Gaussian).
"""

from __future__ import annotations

import numpy as np

__all__ = ["sky_class_size", "sky_part", "sky_statistics"]

_MEAN_ABS_IN_IQR = 0.3247  # E|z| for a standard normal z restricted to its middle half
_DECILES_10_30 = 0.7573    # distance from a Gaussian's 10th to its 30th percentile, in sigma
_TINY = 1e-12              # a class's variance at least this (ADU^2): equal samples


def sky_class_size(sorted_samples: np.ndarray) -> np.ndarray:
    """How many of each row's samples (sorted ascending, (k, m), m >= 4, not all equal) are
    the darker class of the minimum-error split (module docstring); (k,) int, 2 .. m - 2."""
    x = np.asarray(sorted_samples, np.float64)
    m = x.shape[-1]
    sums, squares = np.cumsum(x, axis=-1), np.cumsum(x * x, axis=-1)
    count = np.arange(2, m - 1, dtype=np.float64)         # the darker class's size
    lower = slice(1, m - 2)                                 # its sums, sizes 2 .. m - 2
    s0, q0 = sums[..., lower], squares[..., lower]
    s1, q1 = sums[..., -1:] - s0, squares[..., -1:] - q0
    w0 = count / m
    w1 = 1.0 - w0
    var0 = np.maximum(q0 / count - np.square(s0 / count), _TINY)
    var1 = np.maximum(q1 / (m - count) - np.square(s1 / (m - count)), _TINY)
    cost = (w0 * np.log(var0) + w1 * np.log(var1)
            - 2.0 * (w0 * np.log(w0) + w1 * np.log(w1)))
    return np.argmin(cost, axis=-1) + 2


def sky_statistics(level_samples: np.ndarray, spread_samples: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(level, noise, size) of the sky class of each row: (k,) float32 level and noise
    (units of the input) and the class's size (k,) int.

    ``level_samples`` (k, m), sorted ascending, give the level;
    ``spread_samples`` (k, m), in the same order, the split and the noise (an
    integer frame's samples plus the background grid's dither, whose ties are
    broken: its spread is measured on those, its level on the integers).
    """
    size = sky_class_size(spread_samples)
    m = level_samples.shape[-1]
    quarter = size // 4
    index = np.arange(m)[None, :]
    middle = (index >= quarter[:, None]) & (index < (size - quarter)[:, None])
    count = np.count_nonzero(middle, axis=-1)
    level = np.sum(np.where(middle, level_samples, 0.0), axis=-1) / count
    deviation = np.abs(spread_samples - level[:, None])
    noise = np.sum(np.where(middle, deviation, 0.0), axis=-1) / count / _MEAN_ABS_IN_IQR
    return level.astype(np.float32), noise.astype(np.float32), size


def sky_part(sorted_samples: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(level, noise) of the darkest ``size`` (k,) of each row of ``sorted_samples`` (k, m,
    ascending; filtered samples): level the mean of that class's 6th-37th percentiles,
    noise their 10th-30th percentile distance / 0.757; (k,) float32 each."""
    rows = np.arange(len(size))
    last = np.asarray(size) - 1
    low, high = last // 16, np.maximum(3 * last // 8, last // 16 + 1)
    index = np.arange(sorted_samples.shape[-1])[None, :]
    part = (index >= low[:, None]) & (index < high[:, None])
    level = np.sum(np.where(part, sorted_samples, 0.0), axis=-1) / np.count_nonzero(part, axis=-1)
    spread = (sorted_samples[rows, np.rint(0.3 * last).astype(np.intp)]
              - sorted_samples[rows, np.rint(0.1 * last).astype(np.intp)])
    return level.astype(np.float32), (spread / _DECILES_10_30).astype(np.float32)
