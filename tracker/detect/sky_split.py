"""A tile that holds both sky and a body: the sky's level and noise from its sky pixels.

A background tile across a horizon, the Earth's limb or the edge of glare
holds two populations of pixels: the sky's, at the background level with
the sky's noise, and the body's, far brighter and textured. Its statistics
must be the sky's alone, or a star beside the body meets a threshold raised
by the body's light and texture. A fixed slice of the sorted samples (say
their darker third) is the sky's only when the sky fills at least that
share of the tile: with ground over most of it the slice reaches into the
ground.

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
ground 60-300 noises brighter it finds the sky's exact count in 99.8-100 %
of 500 tiles for ground shares of 5-60 %, and in 97 % at 90 %, 6 sky
samples, where one tile in 500 was cut inside the ground). Each class
holds at least two samples (a variance).
The darker class is the sky. Its statistics are those the detector takes
from any tile holding an edge, applied to the class rather than to the whole
tile: level the mean of its 6th-37th percentiles, noise its 10th-30th
percentile distance over a Gaussian's (0.757 for many samples; for a class
of a few, the expected distance of its order statistics there), low parts of
it because the body's light, blurred by the PSF and, in the matched-filtered
frame, spread a kernel's reach into the sky, raises the class's brightest
samples (:func:`sky_part`). The filtered frame is not split again: its tile
holds three populations (sky, the body's filtered edge, the body), and a
flat, saturated body has no spread at all, so a two-class split of it pairs
the sky with the edge; its sky class is the darkest samples in the share
the split found on the frame as read.

The split serves the tiles whose sky is a minority (the detector's
``sky_split`` tiles: the body fills most of the tile, yet its darkest
samples are sky): a fixed darker part of the tile reaches into the body
there. Where the sky fills most of the tile that part is the
sky's anyway, and on a smooth slope of glare, or textured ground with
shadows, a two-class split has no sky-and-body meaning: it cuts a slope or
the texture and the threshold falls (on 40 lunar frames split in every
edge tile: 15 more false detections, on glare, sky and terrain).
"""

from __future__ import annotations

from functools import lru_cache
from statistics import NormalDist

import numpy as np

__all__ = ["sky_class_size", "sky_part"]

_TINY = 1e-12              # a class's variance at least this (ADU^2): equal samples


def sky_class_size(sorted_samples: np.ndarray) -> np.ndarray:
    """How many of each row's samples (sorted ascending, (k, m)) are the darker class of
    the minimum-error split (module docstring); (k,) int, 2 .. m - 2 (m, all of them,
    when m < 4: too few for two classes of two)."""
    x = np.asarray(sorted_samples, np.float64)
    m = x.shape[-1]
    if m < 4:
        return np.full(x.shape[0], m)
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


def sky_part(level_samples: np.ndarray, spread_samples: np.ndarray,
             size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(level, noise) of the darker part of the darkest ``size`` (k,) samples of each row:
    level the mean of that class's 6th-37th percentiles of ``level_samples``, noise the
    10th-30th percentile distance of ``spread_samples`` over that of a Gaussian's
    order statistics there (:func:`_decile_positions`); (k,) float32 each.

    Both (k, m) sorted ascending in the same order (an integer frame's samples and
    those plus the background grid's dither, whose spread is measured on them).
    """
    size = np.asarray(size)
    rows = np.arange(len(size))
    low = size // 16
    high = np.maximum(3 * size // 8, low + 1)
    index = np.arange(level_samples.shape[-1])[None, :]
    part = (index >= low[:, None]) & (index < high[:, None])
    level = np.sum(np.where(part, level_samples, 0.0), axis=-1) / np.count_nonzero(part, axis=-1)
    low_at, high_at, gaussian = _decile_positions(level_samples.shape[-1])
    spread = (spread_samples[rows, high_at[size]] - spread_samples[rows, low_at[size]])
    return level.astype(np.float32), (spread / gaussian[size]).astype(np.float32)


@lru_cache(maxsize=4)
def _decile_positions(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For classes of n = 0 .. m samples: the positions of their 10th and 30th
    percentiles (rounded; 0 and 0 below two samples) and the expected distance
    between a unit Gaussian's order statistics there, Phi^-1((i + 1/2) / n) (0.757
    for large n, less for a few samples: 0.53 for 19), 1 where it is 0."""
    n = np.arange(m + 1)
    last = np.maximum(n - 1, 0)
    low, high = np.rint(0.1 * last).astype(np.intp), np.rint(0.3 * last).astype(np.intp)
    unit = NormalDist()
    gaussian = np.array([unit.inv_cdf((h + 0.5) / k) - unit.inv_cdf((lo + 0.5) / k)
                         if k > 0 and h > lo else 1.0
                         for k, lo, h in zip(n, low, high, strict=True)])
    return low, high, gaussian
