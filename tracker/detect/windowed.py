"""Iterative Gaussian-windowed centroid, flux, SNR and shape for many stars at once.

Why this estimator: for a Gaussian PSF in background-limited noise the
maximum-likelihood position solves sum_i S_i (x_i - x) P(x_i - x) = 0, which
is exactly the fixed point of a centroid weighted by the PSF centred on
the estimate. Iterating that weighted centroid therefore reaches the
Cramer-Rao bound where the faint stars live, without a nonlinear fit, and
is vectorised over all stars of a frame with fixed-size buffers. For
bright, photon-limited stars it stays close to the bound (its weights
are not 1/variance, which costs a few per cent).

Each step moves the estimate by ``gain`` times the offset of the weighted
centroid from the window centre. For a Gaussian spot of sigma s and weight
sigma w that offset is (true - current) s^2 / (s^2 + w^2), so with
gain = 1 + w^2 / s^2 one step lands on a noise-free Gaussian's centre
(SExtractor's XWIN uses the same factor of 2 for w = s). Offsets are clamped
to ``max_shift`` px from the candidate pixel.

Window: the (2r+1)^2 pixels around the candidate pixel in the padded,
background-subtracted image, r = ``radius``. The Gaussian weight is
separable, so each iteration reduces the window to two weighted profiles
(one per axis) and does the rest on them: two passes over the windows per
iteration instead of a dozen.
Results per star (all in ADU of the background-subtracted image):

* ``dx, dy``: offset of the centre from the candidate pixel, px;
* ``flux``: sum over the window;
* ``weighted``: sum(W S) and ``snr`` = sum(W S) / (noise sqrt(sum W^2)),
  the matched-filter SNR at the centroid against background noise only;
* ``size``: weighted second moment Mxx + Myy, px^2, and ``ellipticity``
  sqrt((Mxx - Myy)^2 + 4 Mxy^2) / (Mxx + Myy);
* ``peak``: largest pixel of the central 3x3, ``raw_peak`` the same before
  background subtraction;
* ``npix``: window pixels more than 3 noise above the background.
"""

from __future__ import annotations

import numpy as np

from tracker.detect.fit import PixelGaussianFit
from tracker.detect.layout import PaddedLayout
from tracker.detect.multiplicative import MultiplicativeFit

__all__ = ["WindowedCentroider", "later_within", "second_moments"]

# The fit (tracker.detect.fit) refines stars at least this significant: fainter ones are
# background-limited, where the windowed centroid is the maximum-likelihood centre and
# its pixel-phase bias (< 0.03 px at sigma 0.6) is far inside their noise; but not
# when the frame's edge cuts the window (then every such star is fitted).
_FIT_MIN_SNR = 10.0
# later_within compares every pair of up to this many points at once ([i, j]: j before i)
_DENSE_POINTS = 128
_EARLIER = np.tri(_DENSE_POINTS, k=-1, dtype=bool)


class WindowedCentroider:
    """Gaussian-windowed centroids in a padded image with rows of ``stride`` pixels.

    The image is of ``dtype`` (float32 or uint16), its background float32.
    Windows of up to ``max_radius`` are supported; :meth:`configure` sets
    the radius and the weight's sigma (the frame's PSF) and may be called
    between frames. Stars are measured ``chunk`` at a time, so the working
    buffers hold ``chunk`` windows whatever ``capacity`` (the most stars
    per frame) is. With ``fit`` (tracker.detect.fit) the centres of each
    chunk's significant, unblended stars are then refined by a fit of the
    pixel-integrated PSF (the shape figures stay those of the windowed
    centre). Given the ``layout`` of the padded image, a star whose window
    reaches beyond the frame is fitted on the window's pixels inside it, its
    centre free to lie up to ``max_shift`` px beyond the edge.
    """

    def __init__(self, stride: int, max_radius: int, gain: float, iterations: int,
                 tolerance: float, max_shift: float, capacity: int, dtype: type = np.float32,
                 chunk: int = 256, fit: PixelGaussianFit | None = None,
                 layout: PaddedLayout | None = None) -> None:
        self.stride = int(stride)
        self.layout = layout
        self.max_radius = int(max_radius)
        self.base_gain = float(gain)
        self.iterations = int(iterations)
        self.tolerance = float(tolerance)
        self.max_shift = float(max_shift)
        self.chunk = int(chunk)
        self.fit = fit
        c, k = self.chunk, (2 * self.max_radius + 1) ** 2
        side = 2 * self.max_radius + 1
        self._index = np.zeros(c * k, np.intp)
        self._win = np.zeros(c * k, dtype)
        self._bgwin = np.zeros(c * k, np.float32)
        self._f64 = {name: np.zeros(c * k, np.float64)
                     for name in ("s", "ex", "ey", "w", "ws", "t")}
        self._axis_work = np.zeros(6 * c * side, np.float64)
        # one row per quantity; x0 and y0, sum_x and sum_y, and step_x and step_y adjacent,
        # so that one call works on both axes
        names = ("x0", "y0", "sum_x", "sum_y", "step_x", "step_y", "sum_ws", "flux",
                 "weighted", "sum_w2", "mxx", "myy", "mxy", "size", "ellipticity", "snr", "peak",
                 "raw_peak", "npix", "rough")
        self._per_star = np.zeros((len(names), int(capacity)), np.float64)
        self.v = dict(zip(names, self._per_star, strict=True))
        self.radius = -1
        self.weight_sigma = 0.0

    def configure(self, radius: int, weight_sigma: float) -> None:
        """Windows of (2 radius + 1)^2 pixels weighted by a Gaussian of ``weight_sigma`` px."""
        radius = int(radius)
        if radius > self.max_radius:
            raise ValueError(f"window radius {radius} exceeds the centroider's {self.max_radius}")
        if radius != self.radius:
            dy, dx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
            self.offsets = (dy * self.stride + dx).ravel().astype(np.intp)
            self.dx = dx.ravel().astype(np.float64)
            self.dy = dy.ravel().astype(np.float64)
            self.side = 2 * radius + 1
            self.axis = np.arange(-radius, radius + 1, dtype=np.float64)
            centre = (np.abs(dx) <= 1) & (np.abs(dy) <= 1)
            self.centre = np.flatnonzero(centre.ravel())
            self.radius = radius
        self.weight_sigma = float(weight_sigma)
        self.inv_two_w2 = 1.0 / (2.0 * self.weight_sigma ** 2)
        self.gain = self.base_gain

    def _chunk_views(self, m: int) -> dict:
        k = len(self.offsets)
        views = {name: buf[: m * k].reshape(m, k) for name, buf in self._f64.items()}
        views["index"] = self._index[: m * k].reshape(m, k)
        views["win"] = self._win[: m * k].reshape(m, k)
        views["bgwin"] = self._bgwin[: m * k].reshape(m, k)
        views["axis"] = self._axis_work[: 6 * m * self.side].reshape(3, 2, m, self.side)
        return views

    def measure(self, n: int, image_pad: np.ndarray, bg_pad: np.ndarray, cand: np.ndarray,
                noise: np.ndarray, level: np.ndarray,
                saturation: float | np.ndarray = np.inf,
                blended: np.ndarray | None = None) -> dict:
        """Measure the ``n`` stars at padded flat indices ``cand[:n]``; views of length n.

        ``image_pad`` holds the frame and ``bg_pad`` its background, both padded
        the same way; ``level`` (n,) a further background offset per star and
        ``noise`` (n,) the background noise at each star, ADU. With a fit,
        pixels at or above ``saturation`` (ADU; one level, or one per star (n,))
        are left out of it, and stars
        marked in ``blended`` (n,) keep their windowed centres: a single
        star's model fitted to a window holding two is pulled between them,
        while the Gaussian weight keeps most of the neighbour out.
        """
        v = {name: arr[:n] for name, arr in self.v.items()}
        for a in range(0, n, self.chunk):
            b = min(n, a + self.chunk)
            part = {name: arr[a:b] for name, arr in v.items()}
            self._measure_chunk(b - a, image_pad, bg_pad, cand[a:b], noise[a:b], level[a:b],
                                saturation[a:b] if np.ndim(saturation) else saturation,
                                None if blended is None else blended[a:b], part,
                                self._per_star[:, a:b])
        return v

    def _measure_chunk(self, m: int, image_pad, bg_pad, cand, noise, level, saturation,
                       blended, v: dict, rows: np.ndarray) -> None:
        """One chunk of :meth:`measure`: ``v`` views of the chunk's stars, ``rows`` the same
        as (quantity, star) rows of the per-star table (x0, y0 first)."""
        c = self._chunk_views(m)
        idx, win, bgwin, s = c["index"], c["win"], c["bgwin"], c["s"]
        np.add(cand[:, None], self.offsets[None, :], out=idx)
        np.take(image_pad.ravel(), idx, out=win, mode="clip")
        np.take(bg_pad.ravel(), idx, out=bgwin, mode="clip")
        np.subtract(win, bgwin, out=s)
        np.subtract(s, level[:, None], out=s)
        x0, y0 = v["x0"], v["y0"]
        xy, sums, step = rows[0:2], rows[2:4], rows[4:6]   # (x0, y0), (sum_x, sum_y), ...
        xy.fill(0.0)
        for _ in range(self.iterations):
            self._profiles(m, c, xy, sums, v["sum_ws"])
            self._shift(sums, v["sum_ws"], xy)
            np.abs(sums, out=step)
            if step.max() < self.tolerance:
                break
        self._weights(c, x0, y0)
        self._photometry(m, c, v, noise)
        if self.fit is not None:
            fit = v["snr"] >= _FIT_MIN_SNR
            inside = self._inside(cand)
            if inside is not None:
                # a cut star's windowed centre is pulled inward at any SNR (the window
                # reads no light beyond the edge): the fit's, on the pixels inside, is not
                fit |= ~inside.all(axis=1)
            if blended is not None:
                fit &= ~blended
            rows = np.flatnonzero(fit)
            if len(rows):
                x, y = x0[rows], y0[rows]
                self.fit.run(len(rows), s[rows], win[rows], x, y, noise[rows],
                             saturation[rows] if np.ndim(saturation) else saturation,
                             self.max_shift, None if inside is None else inside[rows])
                x0[rows], y0[rows] = x, y

    def _inside(self, cand: np.ndarray) -> np.ndarray | None:
        """(m, window pixels) true for the pixels of the windows around the padded flat
        indices ``cand`` (m,) that lie in the frame; None when every one does (or
        there is no layout)."""
        if self.layout is None:
            return None
        rows, cols = self.layout.frame_position(cand)
        r = self.radius
        near = ((rows < r) | (cols < r) | (rows >= self.layout.rows - r)
                | (cols >= self.layout.cols - r))
        if not near.any():
            return None
        inside = np.ones((len(cand), len(self.offsets)), bool)
        at = np.flatnonzero(near)
        row = rows[at, None] + self.dy[None, :]
        col = cols[at, None] + self.dx[None, :]
        inside[at] = ((row >= 0) & (row < self.layout.rows)
                      & (col >= 0) & (col < self.layout.cols))
        return inside

    def refine_multiplicative(self, n: int, fit: MultiplicativeFit, cand: np.ndarray,
                              delivered_pad: np.ndarray, bg_pad: np.ndarray, level: np.ndarray,
                              merge_px: float) -> np.ndarray:
        """Re-centre the first ``n`` stars by ``fit``'s likelihood for speckle-like noise.

        The windowed centroid is made for additive noise; under noise
        proportional to the light (tracker.detect.multiplicative) the
        brightest, noisiest pixels pull it. The fit reads the windows around
        ``cand[:n]`` in ``delivered_pad``, the frame before impulse
        rejection, padded like the measured image, over the background
        ``bg_pad`` plus ``level`` (as ``measure`` took them). The peak of a
        faint speckled star can sit a pixel or two from its centre, so a
        centre more than half a pixel from its window's is fitted again in a
        window around it, and centres up to ``radius - 1`` px from the
        candidate pixel are kept. A fit that fails or lands farther keeps
        the windowed centre. Updates ``x0``/``y0`` in place. Two candidates
        on one speckled star end on one centre: returns the mask of stars
        whose centre is within ``merge_px`` of an earlier (brighter) star's.
        """
        if n == 0:
            return np.zeros(0, bool)
        index = cand[:n, None] + self.offsets[None, :]
        x, y, ok = self._fit_windows(fit, index, delivered_pad, bg_pad, level[:n])
        far = np.flatnonzero(ok & ((np.abs(x) > 0.5) | (np.abs(y) > 0.5)))
        if len(far):
            sx, sy = np.rint(x[far]), np.rint(y[far])
            moved = index[far] + (sy * self.stride + sx).astype(np.intp)[:, None]
            x2, y2, ok2 = self._fit_windows(fit, moved, delivered_pad, bg_pad, level[far])
            x[far], y[far], ok[far] = sx + x2, sy + y2, ok2
        reach = self.side // 2 - 1
        ok &= (np.abs(x) <= reach) & (np.abs(y) <= reach)
        self.v["x0"][:n][ok] = x[ok]
        self.v["y0"][:n][ok] = y[ok]
        centre = cand[:n]
        return later_within(centre % self.stride + self.v["x0"][:n],
                             centre // self.stride + self.v["y0"][:n], merge_px)

    @staticmethod
    def _fit_windows(fit: MultiplicativeFit, index: np.ndarray, delivered_pad: np.ndarray,
                     bg_pad: np.ndarray, level: np.ndarray):
        """``fit`` on the windows at padded flat indices ``index`` (n, pixels)."""
        delivered = np.take(delivered_pad.ravel(), index, mode="clip")
        background = np.take(bg_pad.ravel(), index, mode="clip") + level[:, None]
        return fit.fit(delivered, background, (delivered - background).sum(axis=1))

    def _weights(self, c: dict, x0: np.ndarray, y0: np.ndarray) -> None:
        """w = exp(-((dx - x0)^2 + (dy - y0)^2) / (2 w^2)); ws = w * s."""
        ex, ey, w, t = c["ex"], c["ey"], c["w"], c["t"]
        np.subtract(self.dx[None, :], x0[:, None], out=ex)
        np.subtract(self.dy[None, :], y0[:, None], out=ey)
        np.multiply(ex, ex, out=w)
        np.multiply(ey, ey, out=t)
        np.add(w, t, out=w)
        np.multiply(w, -self.inv_two_w2, out=w)
        np.exp(w, out=w)
        np.multiply(w, c["s"], out=c["ws"])

    def _profiles(self, m: int, c: dict, xy: np.ndarray, sums: np.ndarray,
                  sum_ws: np.ndarray) -> None:
        """sum_ws = sum(W S) and sums = (sum(W S ex), sum(W S ey)) (2, m) for W centred on
        xy = (x0, y0) (2, m); both axes' offsets, weights and profiles in one call each."""
        e, w, p = c["axis"]                     # (ex, ey), (wx, wy), (px, py): (2, m, side)
        np.subtract(self.axis[None, None, :], xy[:, :, None], out=e)
        np.multiply(e, e, out=w)
        np.multiply(w, -self.inv_two_w2, out=w)
        np.exp(w, out=w)
        s = c["s"].reshape(m, self.side, self.side)  # (star, row = dy, column = dx)
        np.einsum("nij,ni->nj", s, w[1], out=p[0])  # column profile, weighted along y
        np.einsum("nij,nj->ni", s, w[0], out=p[1])  # row profile, weighted along x
        np.multiply(p, w, out=p)
        np.sum(p[0], axis=1, out=sum_ws)
        np.einsum("kij,kij->ki", p, e, out=sums)

    def _shift(self, step: np.ndarray, sum_ws: np.ndarray, pos: np.ndarray) -> None:
        """pos += gain * step / sum_ws, clamped (step, pos: (2, m), both axes); step
        (sum(W S e) on entry) holds the move."""
        # a window whose weighted sum is not positive (noise) keeps its position
        np.divide(step, sum_ws, out=step, where=sum_ws > 0)
        step[:, sum_ws <= 0] = 0.0
        np.multiply(step, self.gain, out=step)
        np.add(pos, step, out=step)
        np.clip(step, -self.max_shift, self.max_shift, out=step)
        np.subtract(step, pos, out=step)
        np.add(pos, step, out=pos)

    def _photometry(self, m: int, c: dict, v: dict, noise: np.ndarray) -> None:
        s, w, ws, t = c["s"], c["w"], c["ws"], c["t"]
        ex, ey = c["ex"], c["ey"]
        np.sum(s, axis=1, out=v["flux"])
        np.sum(ws, axis=1, out=v["weighted"])
        np.einsum("ij,ij->i", w, w, out=v["sum_w2"])
        np.sqrt(v["sum_w2"], out=v["snr"])
        np.multiply(v["snr"], noise, out=v["snr"])
        np.divide(v["weighted"], v["snr"], out=v["snr"])
        second_moments(ws, ex, ey, t, v["weighted"], v)
        np.add(v["mxx"], v["myy"], out=v["size"])
        e = np.hypot(v["mxx"] - v["myy"], 2.0 * v["mxy"])
        np.divide(e, np.maximum(v["size"], 1e-12), out=v["ellipticity"])
        np.max(s[:, self.centre], axis=1, out=v["peak"])
        np.max(c["win"][:, self.centre], axis=1, out=v["raw_peak"])
        np.greater(s, 3.0 * noise[:, None], out=t)
        np.sum(t, axis=1, out=v["npix"])
        self._roughness(m, c, v, noise)

    def _roughness(self, m: int, c: dict, v: dict, noise: np.ndarray) -> None:
        """rough = sum (Laplacian S)^2 / sum S^2 over the window, noise taken out.

        The optics pass nothing finer than the PSF, so no image of the sky
        (a star, a trail, a nebula) is rougher than a point source; a
        cosmic-ray cluster or a hot-pixel pair, made on the sensor, is. The
        4-neighbour Laplacian of white noise has 20 times its variance, which
        is subtracted from the sum (and the noise's own from the denominator).
        """
        side = self.side
        grid = c["s"].reshape(m, side, side)
        lap = c["t"].reshape(m, side, side)[:, : side - 2, : side - 2]
        np.multiply(grid[:, 1:-1, 1:-1], 4.0, out=lap)
        lap -= grid[:, :-2, 1:-1]
        lap -= grid[:, 2:, 1:-1]
        lap -= grid[:, 1:-1, :-2]
        lap -= grid[:, 1:-1, 2:]
        np.multiply(lap, lap, out=lap)
        inner = (side - 2) ** 2
        var = np.square(noise)
        rough = lap.sum(axis=(1, 2)) - 20.0 * inner * var
        np.multiply(c["s"], c["s"], out=c["ex"])
        energy = c["ex"].sum(axis=1) - side * side * var
        np.divide(rough, np.maximum(energy, 1e-12), out=v["rough"])


def second_moments(ws: np.ndarray, ex: np.ndarray, ey: np.ndarray, scratch: np.ndarray,
                   total: np.ndarray, out: dict) -> None:
    """out["mxx"], ["myy"], ["mxy"] = sum(ws e e') / total per row, e = ex or ey.

    ``ws``: weighted signal (n, k); ``ex``, ``ey``: offsets from the centre
    (n, k); ``scratch``: an (n, k) buffer; ``total`` (n,): the normaliser
    (floored at 1e-12).
    """
    np.multiply(ws, ex, out=scratch)
    np.einsum("ij,ij->i", scratch, ex, out=out["mxx"])
    np.einsum("ij,ij->i", scratch, ey, out=out["mxy"])
    np.multiply(ws, ey, out=scratch)
    np.einsum("ij,ij->i", scratch, ey, out=out["myy"])
    denom = np.maximum(total, 1e-12)
    for key in ("mxx", "myy", "mxy"):
        np.divide(out[key], denom, out=out[key])


def later_within(x: np.ndarray, y: np.ndarray, radius: float) -> np.ndarray:
    """Mask of points within ``radius`` of an earlier point in the arrays' order.

    Up to ``_DENSE_POINTS`` points (a tracked frame's few dozen stars) every pair is
    compared in one (n, n) array: a third of the numpy calls of the sorted search.
    More, sorted by x, each point is compared only with those within ``radius`` in x.
    """
    n = len(x)
    if n <= _DENSE_POINTS:
        close = np.hypot(x[:, None] - x, y[:, None] - y) <= radius
        close &= _EARLIER[:n, :n]
        return close.any(axis=1)
    later = np.zeros(n, bool)
    order = np.argsort(x, kind="stable")
    xs, ys = x[order], y[order]
    stop = np.searchsorted(xs, xs + radius, side="right")
    counts = stop - np.arange(n) - 1                     # neighbours to the right in x
    first = np.repeat(np.arange(n), counts)
    second = first + 1 + np.arange(len(first)) - np.repeat(np.cumsum(counts) - counts, counts)
    close = np.hypot(xs[second] - xs[first], ys[second] - ys[first]) <= radius
    a, b = order[first[close]], order[second[close]]
    later[np.maximum(a, b)] = True
    return later
