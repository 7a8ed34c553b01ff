"""The detection threshold from a false-alarm budget: how many noise peaks a frame may report.

A candidate is a local maximum of the matched-filtered frame above the
background by k times the filtered noise. Noise alone makes local maxima
everywhere; the threshold is set so that on average at most
``false_per_frame`` of them (``detect.false_alarms_per_frame``, 0.1 by
default) clear it in a frame of this size, whatever the PSF:

1. For Gaussian noise the expected number of local maxima above u
   standard deviations of a smooth random field over an area A is, at
   the levels that matter (u > 3), its expected Euler characteristic

       E(u) = A lambda2 / (2 pi)^(3/2) u exp(-u^2 / 2)

   (Adler 1981; Worsley et al. 1996), where lambda2 is the variance of the
   field's derivative along an axis over the field's variance. For white
   noise through the separable kernel k, the lag-one correlation along an
   axis is rho1 = sum k_i k_(i+1) / sum k_i^2 and lambda2 = 2 (1 - rho1)
   (the pixel-grid version of 1 / (2 s^2) for a Gaussian of sigma s).
   E(u) = budget is solved for u by bisection: about 5.3 for a 1600 x 1300
   frame and a PSF of 1.2 px.
2. Noise that is not Gaussian (photon noise of a few counts, 8-bit noise
   clipped at black) has a longer upper tail. The filtered background's
   skewness g (tracker.detect.background) moves u to the same tail
   probability by the Cornish-Fisher expansion, k = u + g (u^2 - 1) / 6
   (g < 0 is taken as 0: a short tail is no reason to find fewer stars).

The filtered noise itself is measured per tile of the frame (never
assumed), so the budget holds for the frame's actual noise, glare and
vignetting included.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.normal import log_tail

__all__ = ["gaussian_peak_threshold", "skewed_threshold", "NoiseTail", "constant_sky_rate"]

_MAX_CORRELATION = 0.2   # neighbouring pixels more alike than this are not white noise
_BULK_SIGMAS = 4.0       # the bulk of the noise: within this many sigma of its mean
_LOPSIDED_BULK = 0.5     # ... is modelled here only when its skewness is beyond this
_UNSEEN = -math.log(0.05)  # events a Poisson count shows none of with probability 0.05
_T_TOLERANCE = 1e-12     # the saddlepoint t is found to this fraction of itself ...
_LOG_P_TOLERANCE = 1e-13  # ... or log P(Y > y) to this of its target
_MAX_STEPS = 200         # regula falsi steps at most (ten or so are taken)
_T_LOWEST = 1e-3         # the least saddlepoint t evaluated


def constant_sky_rate(count, samples):
    """The largest fraction of a sky's pixels that may read above its level when
    ``count`` of ``samples`` of its pixels do: the rate at which a Poisson count would
    be ``count`` or fewer with probability about 0.05 (the count plus 3, the bound for
    none seen, over the samples; a slight excess for counts above zero).
    Works on arrays of counts and samples alike.
    """
    return (np.asarray(count, np.float64) + _UNSEEN) / np.maximum(samples, 1)


def _axis_lambda2(kernel_1d: np.ndarray) -> float:
    """2 (1 - rho1) of white noise filtered by ``kernel_1d`` along its axis."""
    k = np.asarray(kernel_1d, np.float64)
    power = float(np.sum(k * k))
    rho1 = float(np.sum(k[1:] * k[:-1])) / power if len(k) > 1 else 0.0
    return 2.0 * (1.0 - rho1)


def gaussian_peak_threshold(false_per_frame: float, area_px: float,
                            kernel_1d: np.ndarray) -> float:
    """u (in filtered-noise sigmas): E[maxima of Gaussian noise above u] = ``false_per_frame``.

    ``area_px``: pixels searched; ``kernel_1d``: the separable filter's
    kernel along one axis. The count falls monotonically for u > 1, where
    the bisection looks.
    """
    lambda2 = _axis_lambda2(kernel_1d)
    scale = area_px * lambda2 / (2.0 * math.pi) ** 1.5
    target = max(float(false_per_frame), 1e-300)

    def expected(u: float) -> float:
        return scale * u * math.exp(-0.5 * u * u)

    lo, hi = 1.0, 40.0
    if expected(lo) <= target:
        return lo
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if expected(mid) > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def skewed_threshold(u: float, skewness: float) -> float:
    """Cornish-Fisher: the threshold of Gaussian tail ``u`` for noise of ``skewness`` (>= 0)."""
    g = max(0.0, float(skewness))
    return u + g * (u * u - 1.0) / 6.0


class NoiseTail:
    """The filtered noise's upper tail from the frame's own pixel distribution (saddlepoint).

    Cornish-Fisher from a measured skewness is only a first correction: 8-bit
    noise clipped at black, or photon noise of a fraction of a count per
    pixel, has a tail the matched filter does not make Gaussian enough. This
    class finds the level y (in standard deviations of the filtered noise)
    that the filtered noise exceeds with the probability a Gaussian has
    beyond u, from the distribution of the frame's own background pixels:

    1. the impulse-cleaned frame is sampled on the background grid's
       lattice (tracker.detect.background), each sample standardised by its
       tile's level and noise; tiles holding a sample beyond
       ``star_sigma`` (a star's core) are left out, and the rest pooled in a
       histogram of ``bins`` bins, which is then standardised to mean 0 and
       variance 1 (the pixel distribution X);
    2. for white noise through the kernel, the filtered value is
       Y = sum_j a_j X_j with a_j the kernel's weights over their root sum
       of squares, so its cumulant generating function is
       K_Y(t) = sum_j K_X(a_j t), K_X(s) = log sum_b p_b exp(s x_b);
    3. the Lugannani-Rice saddlepoint formula
       P(Y > y) = 1 - Phi(w) + phi(w) (1/v - 1/w), w = sign(t) sqrt(2 (t y - K_Y(t))),
       v = t sqrt(K_Y''(t)), y = K_Y'(t), accurate to a few per cent of the
       probability far into the tail for such sums, is solved for t by
       regula falsi on log P.

    Every array is made at construction (for the grid) or in
    :meth:`configure` (for the kernel).
    """

    def __init__(self, index: np.ndarray, bins: int = 240, star_sigma: float = 12.0,
                 min_fraction: float = 0.3) -> None:
        self.index = index                         # (ny, nx, m) padded flat indices
        self.index_right = index + 1               # each sample's right neighbour
        self.noise = np.zeros(index.shape[:2], np.float32)
        self.star_sigma = float(star_sigma)
        self.min_fraction = float(min_fraction)
        self.bins = int(bins)
        self.width = 2.0 * self.star_sigma / self.bins
        self.centres = -self.star_sigma + (np.arange(self.bins) + 0.5) * self.width
        self.raw = np.zeros(index.shape, np.uint16)
        self.z = np.zeros(index.shape, np.float32)
        self.right = np.zeros(index.shape, np.float32)     # each sample's right neighbour
        self.product = np.zeros(index.shape, np.float32)
        self.tile_sum = np.zeros(index.shape[:2], np.float64)
        self.bin_of = np.zeros(index.shape, np.intp)
        self.tile_max = np.zeros(index.shape[:2], np.float32)
        self.tile_min = np.zeros(index.shape[:2], np.float32)
        self.excluded = np.zeros(index.shape[:2], np.bool_)
        self.weights = np.zeros(1)
        self.counts = np.zeros(1)

    def configure(self, kernel_1d: np.ndarray) -> None:
        """The separable filter's kernel along one axis."""
        k = np.asarray(kernel_1d, np.float64)
        k2 = np.outer(k, k).ravel()
        k2 = k2 / np.sqrt(np.sum(k2 * k2))
        values, counts = np.unique(np.round(k2, 12), return_counts=True)
        keep = values > 1e-9
        self.weights, self.counts = values[keep], counts[keep].astype(np.float64)

    def sample(self, frame_pad: np.ndarray, level: np.ndarray, noise: np.ndarray) -> None:
        """Take the impulse-cleaned frame's lattice samples (uint16, padded), standardised
        by ``level`` and ``noise`` (per tile, ADU).

        The filter sees the frame after impulse rejection, whose spikes (hot
        pixels, salt and pepper) are gone; clumps of two or three high counts
        stay in both, and in sparse photon noise (a fraction of a count per
        pixel) they make the tail somewhat heavier than independent pixels of
        this histogram would (about 0.3 rather than 0.1 noise peaks per
        512 x 512 frame at 0.15 counts per pixel).
        """
        self.noise = noise
        scale = np.maximum(noise, 1e-6)[..., None]
        for index, out in ((self.index, self.z), (self.index_right, self.right)):
            np.take(frame_pad.ravel(), index, out=self.raw, mode="clip")
            np.subtract(self.raw, level[..., None], out=out)
            np.divide(out, scale, out=out)

    def threshold(self, u: float, noise_f: np.ndarray, filter_gain: float) -> float | None:
        """k: P(filtered noise > k noise_f) = Q(u), or None for the caller's Cornish-Fisher.

        None when too few tiles are free of stars, when neighbouring pixels
        are correlated, or when the bulk of the noise (within 4 sigma) is
        nearly symmetric: then the far tail of the histogram is mostly the
        light of faint stars (a sharp PSF puts several sigma into single
        pixels), not noise, and the skewness correction from trimmed samples
        is the safer figure.

        Uses the last :meth:`sample`; ``noise_f``: the filtered image's
        per-tile noise as the detector
        measured it, and ``filter_gain`` its white-noise gain (filtered over
        pixel standard deviation; for a separable kernel, the 1-D kernel's
        sum of squares). The
        quantile y found in true standard deviations of the filtered noise is
        returned in units of ``noise_f``: y times the tiles' median ratio of
        the filtered standard deviation white noise of the histogram's spread
        would have to ``noise_f`` (robust estimators misjudge the spread of
        skewed noise, in either direction), that ratio kept above 0.8 (noise
        correlated between pixels has a larger filtered spread than white
        noise, which is no reason to lower the threshold).
        """
        np.max(self.z, axis=-1, out=self.tile_max)
        np.min(self.z, axis=-1, out=self.tile_min)
        np.greater(self.tile_max, self.star_sigma, out=self.excluded)
        self.excluded |= self.tile_min < -self.star_sigma
        if np.count_nonzero(~self.excluded) < self.min_fraction * self.excluded.size:
            return None
        if self._neighbour_correlation() > _MAX_CORRELATION:
            return None
        # bin index, with every sample of an excluded tile sent to the overflow bin
        np.add(self.z, self.star_sigma, out=self.z)
        np.multiply(self.z, 1.0 / self.width, out=self.z)
        np.clip(self.z, 0, self.bins - 1, out=self.z)
        np.copyto(self.bin_of, self.z, casting="unsafe")
        self.bin_of[self.excluded] = self.bins
        hist = np.bincount(self.bin_of.ravel(), minlength=self.bins + 1)[: self.bins]
        p = hist / max(float(hist.sum()), 1.0)
        mean = float(np.sum(p * self.centres))
        std = float(np.sqrt(np.sum(p * (self.centres - mean) ** 2)))
        if not std > 0:
            return None
        x = (self.centres - mean) / std
        if abs(_bulk_skewness(x, p)) < _LOPSIDED_BULK:
            return None         # near-Gaussian noise: faint stars' light would pass for its tail
        live = p > 0
        y = _saddlepoint_quantile(x[live], np.log(p[live]), self.weights, self.counts,
                                  float(log_tail(np.array(u))))
        if y is None:
            return None
        np.multiply(self.noise, std * filter_gain, out=self.tile_max)
        np.divide(self.tile_max, np.maximum(noise_f, 1e-12), out=self.tile_max)
        ratio = float(np.median(self.tile_max[~self.excluded]))
        return y * max(0.8, ratio)


    def constant_sky(self, u: float, rate: float, gain: float) -> float:
        """The filtered level above a sky's (ADU) that its noise exceeds with a Gaussian's
        probability beyond ``u``, when it is flat to within its rounding and its pixels
        read one ADU above their level at ``rate`` (:func:`constant_sky_rate`), never
        below it; ``gain``: the filter's white-noise gain (filtered over pixel noise).

        A sky whose lattice samples nearly all read its level has no noise a robust
        spread can see, and white rounding noise of 1/12 ADU^2 (the floor) would have
        put a third of them off it: its rounding is a constant the level holds. What
        noise it may have is this sparse one, of mean ``rate`` and variance
        rate (1 - rate) ADU^2; the saddlepoint of its filtered sum (:meth:`threshold`,
        the kernel's weights from :meth:`configure`) at 0.5 % of the pixels lies
        between three such pixels side by side and four, where the floor asked for
        five.
        """
        f = min(max(float(rate), 1e-9), 0.5)
        spread = math.sqrt(f * (1.0 - f))
        x = (np.array([0.0, 1.0]) - f) / spread
        log_p = np.log([1.0 - f, f])
        y = _saddlepoint_quantile(x, log_p, self.weights, self.counts,
                                  float(log_tail(np.array(u))))
        if y is None:
            return math.inf
        return f + y * spread * gain

    def _neighbour_correlation(self) -> float:
        """Correlation of horizontally adjacent background pixels in the kept tiles.

        Noise whose pixels are not independent (smooth light rounded to a few
        ADU, star wings, JPEG blocks) is not what the saddlepoint models.
        Sums per tile, then over the kept tiles (no copies of the samples).
        """
        keep = ~self.excluded
        count = float(np.count_nonzero(keep)) * self.z.shape[-1]
        sums = {}
        for name, a, b in (("a", self.z, None), ("b", self.right, None), ("aa", self.z, self.z),
                           ("bb", self.right, self.right), ("ab", self.z, self.right)):
            src = a
            if b is not None:
                np.multiply(a, b, out=self.product)
                src = self.product
            np.sum(src, axis=-1, out=self.tile_sum)
            sums[name] = float(np.sum(self.tile_sum, where=keep))
        mean_a, mean_b = sums["a"] / count, sums["b"] / count
        cov = sums["ab"] / count - mean_a * mean_b
        var_a = sums["aa"] / count - mean_a ** 2
        var_b = sums["bb"] / count - mean_b ** 2
        return cov / math.sqrt(var_a * var_b) if var_a > 0 and var_b > 0 else 1.0


def _bulk_skewness(x: np.ndarray, p: np.ndarray) -> float:
    """Skewness of the distribution (values x, probabilities p) within 4 sigma of its mean.

    Noise that is not Gaussian (photon counts of a fraction of a count, 8-bit
    noise clipped at black) is lopsided already there; Gaussian noise is not,
    whatever faint stars add to its far tail.
    """
    inner = np.abs(x) <= _BULK_SIGMAS
    q = p[inner] / max(float(p[inner].sum()), 1e-300)
    m = float(np.sum(q * x[inner]))
    d = x[inner] - m
    var = float(np.sum(q * d * d))
    return float(np.sum(q * d ** 3)) / var ** 1.5 if var > 0 else 0.0


def _cumulants(t: float, x: np.ndarray, log_p: np.ndarray, a: np.ndarray,
               m: np.ndarray) -> tuple[float, float, float]:
    """K_Y(t), K_Y'(t), K_Y''(t) for Y = sum_j a_j X_j (multiplicities m_j)."""
    s = t * a                                        # (J,)
    e = s[:, None] * x[None, :] + log_p[None, :]     # (J, B) log terms
    top = e.max(axis=1, keepdims=True)
    w = np.exp(e - top)
    m0 = w.sum(axis=1)
    m1 = (w * x).sum(axis=1) / m0
    m2 = (w * x * x).sum(axis=1) / m0
    k0 = np.log(m0) + top[:, 0]
    return (float(np.sum(m * k0)), float(np.sum(m * a * m1)),
            float(np.sum(m * a * a * (m2 - m1 * m1))))


def _log_lr_tail(t: float, x, log_p, a, m) -> tuple[float, float]:
    """(y, log P(Y > y)) at the saddlepoint t > 0 (Lugannani-Rice)."""
    k, k1, k2 = _cumulants(t, x, log_p, a, m)
    w = math.sqrt(max(2.0 * (t * k1 - k), 1e-300))
    v = t * math.sqrt(max(k2, 1e-300))
    log_q = float(log_tail(np.array(w)))
    # 1 - Phi(w) + phi(w) (1/v - 1/w) = Q(w) (1 + phi(w)/Q(w) (1/v - 1/w))
    ratio = math.exp(-0.5 * w * w - 0.5 * math.log(2.0 * math.pi) - log_q)
    factor = 1.0 + ratio * (1.0 / v - 1.0 / w)
    return k1, log_q + math.log(max(factor, 1e-300))


def _saddlepoint_quantile(x, log_p, a, m, log_target: float) -> float | None:
    """y with log P(Y > y) = ``log_target``: the saddlepoint t by regula falsi on log P.

    log P falls as t grows; the root is bracketed by doubling t from 1 (or
    halving it, down to ``_T_LOWEST``), then narrowed by the Illinois
    variant of regula falsi (the end that stays put has its value halved, so
    both ends close in, superlinearly) until the bracket is ``_T_TOLERANCE``
    of t wide or log P is within ``_LOG_P_TOLERANCE`` of the target: some ten
    evaluations of the cumulants where bisection to the same width took
    forty. Returns y at the evaluated t nearest the target.
    """
    hi = 1.0
    y_hi, g_hi = _log_lr_tail(hi, x, log_p, a, m)
    g_hi -= log_target
    while g_hi > 0:
        hi *= 2.0
        if hi > 1e4:
            return None
        y_lo, g_lo = y_hi, g_hi      # log P is still above the target there
        y_hi, g_hi = _log_lr_tail(hi, x, log_p, a, m)
        g_hi -= log_target
    lo = 0.5 * hi
    if hi == 1.0:
        # the lower end by halving (Lugannani-Rice is unstable as t -> 0: no value is
        # read below _T_LOWEST, where the root is taken to be)
        y_lo, g_lo = _log_lr_tail(lo, x, log_p, a, m)
        g_lo -= log_target
        while not g_lo > 0:
            hi, y_hi, g_hi = lo, y_lo, g_lo
            lo *= 0.5
            if lo < _T_LOWEST:
                return y_hi
            y_lo, g_lo = _log_lr_tail(lo, x, log_p, a, m)
            g_lo -= log_target
    best_y, best_g = (y_hi, g_hi) if -g_hi < g_lo else (y_lo, g_lo)
    side = 0
    for _ in range(_MAX_STEPS):
        if hi - lo <= _T_TOLERANCE * hi or abs(best_g) <= _LOG_P_TOLERANCE:
            break
        t = hi - g_hi * (hi - lo) / (g_hi - g_lo)
        if not lo < t < hi:
            t = 0.5 * (lo + hi)
        y, g = _log_lr_tail(t, x, log_p, a, m)
        g -= log_target
        if abs(g) < abs(best_g):
            best_y, best_g = y, g
        if g > 0:
            lo, g_lo = t, g
            if side > 0:
                g_hi *= 0.5
            side = 1
        else:
            hi, g_hi = t, g
            if side < 0:
                g_lo *= 0.5
            side = -1
    return best_y
