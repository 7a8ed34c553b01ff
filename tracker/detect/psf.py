"""The PSF measured from the frame: width and ellipticity from bright, isolated, unsaturated stars.

Optics drift with focus and temperature, and a user rarely knows their
PSF, so the detector measures it on every frame and uses it for the
matched filter, the centroid window and the centroid fit;
``detect.psf_sigma_px`` is only where it starts.

Per frame (:class:`PsfMeter`):

1. the brightest local maxima of the impulse-cleaned, unfiltered frame
   (at most ``capacity``, each ``detect.psf_min_peak_sigma`` pixel noise
   above the background; tracker.detect.peaks) are the candidates;
2. adaptive second moments of each (Bernstein and Jarvis 2002): a
   Gaussian weight of sigma w centred on the star, w^2 set to the weighted
   Mxx + Myy and the centre moved until both settle. For a Gaussian spot of
   covariance C and a round weight of sigma w the weighted moments are
   M = (C^-1 + I / w^2)^-1, so C = (M^-1 - I / w^2)^-1 exactly; at the
   fixed point w matches the spot, which makes C the best-fitting
   (least-squares) elliptical Gaussian of any PSF. The pixel's own width
   (1/12 px^2 per axis) is then taken off: C_optics = C - I / 12;
3. a candidate is kept if it is unsaturated, away from the frame's edge,
   isolated (the mean light in a ring at 3.5-4.5 w is under 2 % of its
   peak, beyond three standard errors of that mean, so no neighbour, edge
   of a bright body or glare slope pulls its moments) and round enough
   (ellipticity < 0.5; cosmic-ray tracks are not);
4. the frame's sigma is the mode of the kept stars' sigmas (the median of
   the stars in the densest 10 %-wide bin of log sigma, then the median of
   the stars within 15 % of that), so a minority of cosmic-ray blobs,
   double stars and bumps on bright bodies does not move it; its
   ellipticity and angle are the median tensor of those stars. Fewer than
   ``min_stars`` agreeing stars give no measurement. The optics blur every
   star of a frame alike, and nothing blurs a particle's charge, which
   diffuses in the silicon to about the sharpest PSF handled (under 1.5 x
   0.45 px). So where the mode is that sharp and at least two spots are 1.5
   times wider, the mode is a particle event's round hits (on the lunar
   surface they outnumber the bright stars): the wider spots measure the
   PSF, and beside such a sharp population 3 agreeing stars (or
   ``min_stars`` if fewer) suffice; if the wider ones do not agree, the
   frame has no measurement. With no wider spots beside it, at least
   ``min_stars``, and most, of that sharp mode must share one shape (a
   PSF's stars all do; of tracks pointing every way a few lie near their
   median by chance) within what each one's noise allows: an ellipticity
   vector within sqrt(0.15^2 + (4 sigma_e)^2) of their median one, sigma_e = 2 / SNR per component
   (Bernstein and Jarvis 2002), scaled by the pixel width taken off; else
   the frame has no measurement (if enough do, all the mode's spots count:
   an undersampled star's shape also depends on where in its pixel it
   lies, up to e 0.4 at sigma 0.5 px). A short particle track is as sharp
   as the sharpest PSF, bright (SNR 30-300) and points its own way; where a
   wide PSF's stars were too faint at the peak to be candidates, the tracks
   alone would have measured it. Faint stars (SNR 10-40) scatter in shape
   as widely and count. The hits are left out of the estimate's robust
   spread. (The windows are sized from the brightest dozen, and where those
   were such hits, candidates that grew 1.5 times wider than them, beyond
   their windows, are measured again in windows wide enough.)

Across frames (:class:`PsfTracker`): the estimate in use is a running
mean of the measurements that agree with it (within 3 standard errors;
at most ``memory`` frames' worth), so a steady PSF is known ever more
precisely; a measurement that disagrees (focus moved, a new scene)
replaces it at once. A frame with no measurement keeps the estimate once
two frames have agreed on it; before that (one frame's measurement, which
in a folder of frames from different cameras says nothing of the next)
it is searched with the configured start.

sigma here is the optics' Gaussian-equivalent sigma (pixel integration
removed), the same quantity as ``detect.psf_sigma_px``; its FWHM is
2 sqrt(2 ln 2) sigma.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker.detect.order import median

__all__ = ["PsfEstimate", "PsfMeter", "PsfTracker", "SIGMA_MIN_PX", "SIGMA_MAX_PX",
           "FWHM_PER_SIGMA", "CHARGE_SIGMA_PX", "OPTICS_WIDER", "pixel_tensor_to_optics",
           "combine_stars"]

SIGMA_MIN_PX = 0.45     # narrower PSFs are undersampled beyond what the fit models
SIGMA_MAX_PX = 3.5      # the largest windows the detector's buffers hold
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
PIXEL_VARIANCE = 1.0 / 12.0
_ITERATIONS = 3
_SCOUTS = 12            # brightest stars that first say how wide the PSF is
_SCOUT_ITERATIONS = 3
_RING_MARGIN = 1.25     # windows reach this far beyond the ring of the typical star
# The weight is never narrower than this: weighted moments of an undersampled spot
# under a weight about one pixel wide rest on a single pixel and tell nothing; the
# deconvolution C = (M^-1 - I / w^2)^-1 holds for any weight.
_MIN_WEIGHT_PX = 0.8
_RING = (3.5, 4.5)      # isolation ring, in units of the weight sigma
_RING_FRACTION = 0.02
_MAX_ELLIPTICITY = 0.5
_BIN = math.log(1.10)
_AGREE = math.log(1.15)
OPTICS_WIDER = 1.5          # spots this much wider than the mode (at least two) ...
_OPTICS_GAP = math.log(OPTICS_WIDER)
# a particle's charge, diffused in the silicon, is at most this wide (optical sigma, px):
# as sharp as the sharpest PSF handled, give or take the same factor
CHARGE_SIGMA_PX = OPTICS_WIDER * SIGMA_MIN_PX
# ... and the PSF meter's adaptive weight for it (never under _MIN_WEIGHT_PX)
_CHARGE_WEIGHT_PX = max(_MIN_WEIGHT_PX, math.sqrt(CHARGE_SIGMA_PX ** 2 + PIXEL_VARIANCE))
_WIDER_STARS = 3             # ... measure the PSF if this many agree (or min_stars)
# a sharp mode's spots share one shape: an ellipticity vector within this of their median
# one beyond their noise (the optics' variation across a field) ...
_SHAPE_FLOOR = 0.15
_SHAPE_SIGMAS = 4.0          # ... plus this many standard errors of their own


@dataclass(frozen=True)
class PsfEstimate:
    """A PSF: optical sigma (px), ellipticity, angle of the long axis (rad), and its basis.

    ``stars``: how many stars this frame's measurement came from (0: none,
    the previous estimate or the configured value was used);
    ``sigma_error_px``: standard error of ``sigma_px``.
    """

    sigma_px: float
    ellipticity: float = 0.0
    angle_rad: float = 0.0
    stars: int = 0
    sigma_error_px: float = math.inf

    @property
    def fwhm_px(self) -> float:
        return FWHM_PER_SIGMA * self.sigma_px


def pixel_tensor_to_optics(cxx, cyy, cxy):
    """(sigma, ellipticity, angle) of covariances measured on pixels, pixel width removed.

    Inputs are arrays (or scalars) of the pixel-integrated spot's covariance,
    px^2; sigma^2 is the mean of the optical covariance's eigenvalues.
    NaN where the optical covariance is not positive.
    """
    a = np.asarray(cxx, np.float64) - PIXEL_VARIANCE
    b = np.asarray(cyy, np.float64) - PIXEL_VARIANCE
    c = np.asarray(cxy, np.float64)
    half_trace = 0.5 * (a + b)
    spread = np.hypot(0.5 * (a - b), c)
    ok = (half_trace > spread) & (half_trace > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma = np.where(ok, np.sqrt(np.where(ok, half_trace, 1.0)), np.nan)
        ellipticity = np.where(ok, spread / np.where(ok, half_trace, 1.0), np.nan)
    angle = 0.5 * np.arctan2(2.0 * c, a - b)
    return sigma, ellipticity, angle


class PsfMeter:
    """Adaptive moments of up to ``capacity`` stars in windows of up to ``radius`` px.

    Windows are read from padded buffers with rows of ``stride`` pixels
    (tracker.detect.layout); every buffer is made here.
    """

    def __init__(self, stride: int, radius: int, capacity: int, min_stars: int) -> None:
        self.stride = int(stride)
        self.radius = int(radius)
        self.capacity = int(capacity)
        self.min_stars = int(min_stars)
        self._windows: dict[int, tuple] = {}
        k = (2 * self.radius + 1) ** 2
        c = self.capacity
        self._flat = {name: np.zeros(c * k, np.float64) for name in ("s", "ex", "ey", "t")}
        side = 2 * self.radius + 1
        self._axis = np.zeros(c * side * 3, np.float64)    # per-column weight factors
        self._rows = np.zeros(c * side * 3, np.float64)    # the window times them
        self._index = np.zeros(c * k, np.intp)
        self._raw = np.zeros(c * k, np.uint16)
        self._bgwin = np.zeros(c * k, np.float32)
        self.last_cand, self.last_n, self.last_good = np.zeros(0, np.intp), 0, np.zeros(0, bool)
        self.last_snr = np.zeros(0)   # the last measure's weighted-flux SNR of its n spots
        # one row per quantity; x and y, and mxx and myy, adjacent so that both axes
        # are worked on in one call
        names = ("x", "y", "mxx", "myy", "w2", "s0", "mxy", "cxx", "cyy", "cxy", "ring",
                 "peak", "raw_peak", "scale", "move_x", "move_y")
        self._per_star = np.zeros((len(names), c), np.float64)
        self.per_star = dict(zip(names, self._per_star, strict=True))
        self._move = names.index("move_x")   # move_x, move_y: scratch for (x, y) steps
        self._e = np.zeros(2 * c * side, np.float64)      # column and row offsets
        self._g = np.zeros(2 * c * side, np.float64)      # their Gaussian weights
        self._gy_e = np.zeros(2 * c * side, np.float64)   # gy ey, gy ey^2
        self._axes = {r: np.arange(-r, r + 1, dtype=np.float64) for r in range(self.radius + 1)}

    def _window(self, radius: int) -> tuple:
        """(offsets, r) of a window of ``radius``: padded flat offsets and the distance
        of each pixel from the centre, px; made once per radius."""
        if radius not in self._windows:
            dy, dx = np.mgrid[-radius:radius + 1, -radius:radius + 1]
            dx, dy = dx.ravel().astype(np.float64), dy.ravel().astype(np.float64)
            offsets = (dy * self.stride + dx).astype(np.intp)
            self._windows[radius] = (offsets, np.hypot(dx, dy))
        return self._windows[radius]

    def measure(self, n: int, image_pad: np.ndarray, bg_pad: np.ndarray, cand: np.ndarray,
                noise: np.ndarray, saturation: float, sigma_start: float,
                edge_px: np.ndarray, min_stars: int | None = None) -> PsfEstimate | None:
        """The PSF of the ``n`` candidates at padded flat indices ``cand`` (brightest first).

        ``image_pad`` (uint16) and ``bg_pad`` (float32): the frame and its
        background, padded alike; ``noise`` (n,): the pixel noise at each,
        ADU; ``edge_px`` (n,): each one's distance to the frame's nearest
        edge, px (a star whose isolation ring the edge cuts is not used).
        Returns None when fewer than ``min_stars`` (default: the
        constructor's) stars agree.

        First the brightest few, in the largest windows, say roughly how
        wide the PSF is, whatever ``sigma_start`` (px) was; then every
        candidate is measured in windows just wide enough for the isolation
        ring.
        """
        need = self.min_stars if min_stars is None else int(min_stars)
        n = min(int(n), self.capacity)
        self.last_n = 0
        if n < need:
            return None
        p = {name: arr[:n] for name, arr in self.per_star.items()}
        p["w2"].fill(max(sigma_start ** 2 + PIXEL_VARIANCE, _MIN_WEIGHT_PX ** 2))
        first = min(n, _SCOUTS)
        self._iterate(first, self.radius, image_pad, bg_pad, cand, p, _SCOUT_ITERATIONS,
                      final=False)
        w_typical = math.sqrt(median(p["w2"][:first]))
        p["w2"].fill(w_typical ** 2)
        radius = min(self.radius, int(math.ceil(_RING[1] * w_typical * _RING_MARGIN)) + 1)
        view = self._iterate(n, radius, image_pad, bg_pad, cand, p, _ITERATIONS)
        # where a particle event's sharp hits were the scouts, stars of a wider PSF
        # outgrow the windows (their isolation rings beyond the edge): the windows are
        # widened for them, and combine_stars tells the two populations apart
        w_now = np.sqrt(p["w2"])
        wide = w_now >= OPTICS_WIDER * w_typical
        if (w_typical <= _CHARGE_WEIGHT_PX and radius < self.radius
                and np.count_nonzero(wide & (_RING[1] * w_now > radius)) >= 2):
            w_wide = median(w_now[wide])
            radius = min(self.radius, int(math.ceil(_RING[1] * w_wide * _RING_MARGIN)) + 1)
            view = self._iterate(n, radius, image_pad, bg_pad, cand, p, _ITERATIONS)
        sigma, ellipticity, _ = pixel_tensor_to_optics(p["cxx"], p["cyy"], p["cxy"])
        self.last_cand, self.last_n = cand, n
        good = self._isolated(n, radius, view, p, noise[:n], saturation)
        good &= edge_px[:n] >= _RING[1] * np.sqrt(p["w2"]) + 1.0
        # a spot narrower than any PSF the detector handles is a particle's, not a star's
        good &= ((ellipticity < _MAX_ELLIPTICITY) & (sigma >= SIGMA_MIN_PX)
                 & (sigma <= SIGMA_MAX_PX))
        self.last_good = good
        # the weighted flux's SNR: the Gaussian weight's sum of squares is pi w^2
        snr = p["s0"] / (noise[:n] * np.sqrt(math.pi * p["w2"]))
        self.last_snr = snr
        return combine_stars(sigma[good], ellipticity[good], p["cxx"][good], p["cyy"][good],
                             p["cxy"][good], snr[good], need)

    def last_stars(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The last :meth:`measure`'s usable stars: padded flat index, optical sigma (px),
        ellipticity, and the centre offset (dx, dy) from that pixel, px (n, 2)."""
        if self.last_n == 0:
            empty = np.zeros(0)
            return np.zeros(0, np.intp), empty, empty, np.zeros((0, 2))
        n, good = self.last_n, self.last_good
        p = {name: arr[:n] for name, arr in self.per_star.items()}
        sigma, ellipticity, _ = pixel_tensor_to_optics(p["cxx"], p["cyy"], p["cxy"])
        return (self.last_cand[:n][good].copy(), sigma[good], ellipticity[good],
                np.column_stack([p["x"][good], p["y"][good]]))

    def _views(self, n: int, k: int) -> dict:
        out = {name: buf[: n * k].reshape(n, k) for name, buf in self._flat.items()}
        out["index"] = self._index[: n * k].reshape(n, k)
        out["raw"] = self._raw[: n * k].reshape(n, k)
        out["bgwin"] = self._bgwin[: n * k].reshape(n, k)
        return out

    def _iterate(self, n: int, radius: int, image_pad, bg_pad, cand, p: dict,
                 iterations: int, final: bool = True) -> dict:
        """Adaptive moments of the first ``n`` stars in windows of ``radius``; returns the
        window views (their ``s`` holds the background-subtracted light).

        ``final`` False: only the weights (w2) and centres are wanted (the scouts',
        whose moments and covariances the next pass writes afresh), not the
        moments under the last weight."""
        offsets, _ = self._window(radius)
        v = self._views(n, len(offsets))
        np.add(cand[:n, None], offsets[None, :], out=v["index"])
        np.take(image_pad.ravel(), v["index"], out=v["raw"], mode="clip")
        np.take(bg_pad.ravel(), v["index"], out=v["bgwin"], mode="clip")
        np.subtract(v["raw"], v["bgwin"], out=v["s"])
        q = {name: arr[:n] for name, arr in p.items()}
        q["x"].fill(0.0)
        q["y"].fill(0.0)
        xy, moments, move = (self._per_star[rows, :n] for rows in (
            slice(0, 2), slice(2, 4), slice(self._move, self._move + 2)))
        w2 = q["w2"]
        with np.errstate(invalid="ignore", divide="ignore"):   # for _deconvolve_weight
            self._adapt(q, v, radius, iterations, xy, moments, move, w2)
            if final:
                self._weighted(q, v, radius, second=True)
                _deconvolve_weight(q)
        return v

    def _adapt(self, q: dict, v: dict, radius: int, iterations: int, xy: np.ndarray,
               moments: np.ndarray, move: np.ndarray, w2: np.ndarray) -> None:
        """The adaptive iterations of :meth:`_iterate`: centre, then weight, ``iterations``
        times (``xy``, ``moments``, ``move``: (2, n) views of the per-star table)."""
        for _ in range(iterations):
            self._weighted(q, v, radius)
            # move to the weighted centroid (gain 2: exact when the weight matches the
            # spot); mxx, myy hold sum(W S ex) / S0, sum(W S ey) / S0
            np.multiply(moments, 2.0, out=move)
            np.add(xy, move, out=xy)
            np.maximum(xy, -1.5, out=xy)
            np.minimum(xy, 1.5, out=xy)
            self._weighted(q, v, radius, second=True)
            _deconvolve_weight(q)
            np.add(q["cxx"], q["cyy"], out=w2)
            np.multiply(w2, 0.5, out=w2)
            np.copyto(w2, _MIN_WEIGHT_PX ** 2, where=np.isnan(w2))
            np.maximum(w2, _MIN_WEIGHT_PX ** 2, out=w2)
            np.minimum(w2, (1.2 * SIGMA_MAX_PX) ** 2, out=w2)

    def _isolated(self, n: int, radius: int, v: dict, p: dict, noise: np.ndarray,
                  saturation: float) -> np.ndarray:
        """Unsaturated stars whose ring at 3.5-4.5 w holds < 2 % of their peak (beyond three
        standard errors of its mean), inside the window."""
        _, r = self._window(radius)
        t, ring = v["t"], v["ex"]
        w_now = np.sqrt(p["w2"])
        np.divide(r[None, :], w_now[:, None], out=t)             # r / w
        np.greater_equal(t, _RING[0], out=ring)
        np.less_equal(t, _RING[1], out=v["ey"])
        np.multiply(ring, v["ey"], out=ring)                     # 1 in the ring
        np.sum(ring, axis=1, out=p["ring"])
        np.multiply(ring, v["s"], out=ring)
        ring_light = ring.sum(axis=1) / np.maximum(p["ring"], 1.0)
        np.max(v["s"], axis=1, out=p["peak"])
        np.max(v["raw"], axis=1, out=p["raw_peak"])
        return ((_RING[1] * w_now <= radius) & (p["raw_peak"] < saturation)
                & (ring_light < _RING_FRACTION * p["peak"]
                   + 3.0 * noise / np.sqrt(np.maximum(p["ring"], 1.0))))

    def _weighted(self, p: dict, v: dict, radius: int, second: bool = False) -> None:
        """First (``second`` False) or second weighted moments about (x, y) into mxx, myy, mxy.

        First moments are stored as mxx = sum(W S ex) / S0 and myy likewise.
        The Gaussian weight is separable, W = gy(row) gx(col), so each sum is
        gy-weighted over rows of S times one of gx, gx ex, gx ex^2 (one
        batched matrix product over the windows' pixels); the two axes'
        offsets and weights are computed together.
        """
        n, side = len(p["x"]), 2 * radius + 1
        e = self._e[: 2 * n * side].reshape(2, n, side)     # (ex, ey): column, row offsets
        np.subtract(self._axes[radius], self._per_star[0:2, :n, None], out=e)
        g = self._g[: 2 * n * side].reshape(2, n, side)     # (gx, gy)
        scale = p["scale"]
        np.divide(-0.5, p["w2"], out=scale)
        np.multiply(e, e, out=g)
        np.multiply(g, scale[:, None], out=g)
        np.exp(g, out=g)
        (ex, ey), (gx, gy) = e, g
        # the first moments need no sum(W S ex^2): two columns, not three
        k = 3 if second else 2
        shape = (n, side, k)
        cols = self._axis[: n * side * k].reshape(shape)
        rows = self._rows[: n * side * k].reshape(shape)
        np.copyto(cols[..., 0], gx)
        np.multiply(gx, ex, out=cols[..., 1])
        if second:
            np.multiply(cols[..., 1], ex, out=cols[..., 2])
        np.matmul(v["s"].reshape(n, side, side), cols, out=rows)  # S (gx, gx ex[, gx ex^2])
        gy_e = self._gy_e[: 2 * n * side].reshape(2, n, side)  # (gy ey, gy ey^2)
        np.multiply(gy, ey, out=gy_e[0])
        by_gy = np.einsum("ij,ijk->ik", gy, rows)   # S0, sum(W S ex)[, sum(W S ex^2)]
        p["s0"][:] = by_gy[:, 0]
        denom = np.maximum(p["s0"], 1e-12)
        moments = self._per_star[2:4, :n]            # (mxx, myy)
        if not second:
            moments[0] = by_gy[:, 1]
            np.einsum("ij,ij->i", gy_e[0], rows[..., 0], out=p["myy"])
            np.divide(moments, denom, out=moments)
            return
        np.multiply(gy_e[0], ey, out=gy_e[1])
        moments[0] = by_gy[:, 2]
        np.einsum("ij,ij->i", gy_e[0], rows[..., 1], out=p["mxy"])
        np.einsum("ij,ij->i", gy_e[1], rows[..., 0], out=p["myy"])
        np.divide(moments, denom, out=moments)
        np.divide(p["mxy"], denom, out=p["mxy"])


def _deconvolve_weight(p: dict) -> None:
    """cxx, cyy, cxy = (M^-1 - I / w^2)^-1: the spot's covariance from its weighted moments.

    NaN where that is not a covariance (noise, or a spot broader than the
    model allows). The caller silences numpy's warnings for the divisions.
    """
    mxx, myy, mxy = p["mxx"], p["myy"], p["mxy"]
    det_m = mxx * myy - mxy * mxy
    inv_w2 = 1.0 / p["w2"]
    a = myy / det_m - inv_w2
    b = mxx / det_m - inv_w2
    c = -mxy / det_m
    det_c = a * b - c * c
    bad = ~((det_m > 0) & (det_c > 0) & (a > 0))
    np.divide(b, det_c, out=p["cxx"])
    np.divide(a, det_c, out=p["cyy"])
    np.divide(-c, det_c, out=p["cxy"])
    for key in ("cxx", "cyy", "cxy"):
        np.copyto(p[key], np.nan, where=bad)


def _densest(log_s: np.ndarray) -> float:
    """The mode of ``log_s``: the median of the values in its densest bin of width _BIN
    (sliding in steps of a quarter bin; ties: the last). The bin's own centre is up to
    half a bin from its values, and then leaves out a star at the cluster's far edge."""
    starts = np.arange(log_s.min() - _BIN, log_s.max() + _BIN / 4, _BIN / 4)
    counts = np.count_nonzero((log_s[None, :] >= starts[:, None])
                              & (log_s[None, :] < starts[:, None] + _BIN), axis=1)
    start = starts[len(starts) - 1 - np.argmax(counts[::-1])]
    return float(median(log_s[(log_s >= start) & (log_s < start + _BIN)]))


def _shared_shape(cxx: np.ndarray, cyy: np.ndarray, cxy: np.ndarray, snr: np.ndarray,
                  among: np.ndarray) -> np.ndarray:
    """Which spots of pixel covariances ``cxx``, ``cyy``, ``cxy`` (px^2) and weighted-flux
    ``snr`` have the shape of those ``among`` (bool): an ellipticity vector (e cos 2 theta,
    e sin 2 theta, pixel width removed) within _SHAPE_FLOOR, and _SHAPE_SIGMAS of its own
    standard errors, of those spots' median vector.

    Adaptive moments measure each component of a spot's ellipticity to
    2 / SNR (Bernstein and Jarvis 2002); taking the pixel's width off
    scales it by trace(C) / trace(C_optics). The optics blur every star of
    a frame alike, so stars lie about their PSF's vector by their noise
    (and the optics' variation across the field): on the real frame
    openstartracker/img0.png (PSF 0.65 px, e 0.3) its sharp stars at SNR
    8-36 lie 0.2-0.55 from their median, 1-3.5 standard errors. Short
    particle tracks are as sharp, point every way and are bright: on the
    bench's glare and lunar frames 0.2-0.6 from their median at SNR 46-200,
    6-38 standard errors (of 12, two near the median by chance).
    """
    a = cxx - PIXEL_VARIANCE
    b = cyy - PIXEL_VARIANCE
    trace = np.maximum(a + b, 1e-12)
    e1, e2 = (a - b) / trace, 2.0 * cxy / trace
    error = 2.0 * (cxx + cyy) / trace / np.maximum(snr, 1e-12)
    allowed = np.hypot(_SHAPE_FLOOR, _SHAPE_SIGMAS * error)
    return np.hypot(e1 - median(e1[among]), e2 - median(e2[among])) <= allowed


def combine_stars(sigma, ellipticity, cxx, cyy, cxy, snr, min_stars: int) -> PsfEstimate | None:
    """The mode of the stars' sigmas and the median tensor of the stars near it.

    ``sigma``, ``ellipticity``, the pixel covariances ``cxx``, ``cyy``,
    ``cxy`` (px^2) and the weighted flux's signal-to-noise ratio ``snr`` of
    each star; None when fewer than ``min_stars`` agree.
    """
    if len(sigma) < min_stars:
        return None
    log_s = np.log(sigma)
    best = _densest(log_s)
    agree = np.abs(log_s - best) <= _AGREE
    wider = log_s > best + _OPTICS_GAP
    charge = math.log(CHARGE_SIGMA_PX)
    if best < charge and np.count_nonzero(wider) < 2:
        shared = np.count_nonzero(_shared_shape(cxx, cyy, cxy, snr, agree) & agree)
        if shared < min_stars or 2 * shared <= np.count_nonzero(agree):
            # as sharp as a particle's charge, no wider spots, and too few of them, or
            # not most of them, share one shape within their noise (a PSF's stars all
            # do): short tracks pointing every way, a few near their median by chance
            return None
    if best < charge and np.count_nonzero(wider) >= 2:
        # spots far wider than the mode: the mode is particles' charge, which the optics
        # never blurred, and the frame's stars are the wider spots (or, if they do not
        # agree among themselves, unknown)
        best = _densest(log_s[wider])
        agree = wider & (np.abs(log_s - best) <= _AGREE)
        if np.count_nonzero(agree) < min(min_stars, _WIDER_STARS):
            return None
    elif np.count_nonzero(agree) < (
            min(min_stars, _WIDER_STARS)
            if np.count_nonzero(log_s < min(best - _OPTICS_GAP, charge)) >= 2 else min_stars):
        # (beside particles' sharp spots, fewer stars measure the PSF)
        return None
    sel = (median(cxx[agree]), median(cyy[agree]), median(cxy[agree]))
    s_opt, e_opt, angle = pixel_tensor_to_optics(*sel)
    m = int(np.count_nonzero(agree))
    if not np.isfinite(s_opt):
        return None
    # standard error: from the agreeing stars' spread, or, if larger, from all the
    # stars' robust spread (when the mode is picked among noisy values, the stars
    # near it understate how far it can wander); particles' sharp charge, beside a
    # wider mode, is not among them
    stars = sigma[sigma >= CHARGE_SIGMA_PX] if best >= charge else sigma
    spread = max(float(np.std(sigma[agree])) / math.sqrt(m),
                 1.4826 * median(np.abs(stars - median(stars)))
                 / math.sqrt(len(stars)), 0.01 * float(s_opt) / math.sqrt(m))
    return PsfEstimate(float(np.clip(s_opt, SIGMA_MIN_PX, SIGMA_MAX_PX)), float(e_opt),
                       float(angle), m, 1.25 * spread)


class PsfTracker:
    """The PSF estimate across frames, starting at ``sigma_px``; see the module docstring."""

    def __init__(self, sigma_px: float, memory: int) -> None:
        self.start = float(np.clip(sigma_px, SIGMA_MIN_PX, SIGMA_MAX_PX))
        self.memory = max(1, int(memory))
        self.reset()

    def reset(self) -> None:
        self.current = PsfEstimate(self.start)
        self._weight = 0.0

    def update(self, measured: PsfEstimate | None) -> PsfEstimate:
        """Fold this frame's measurement in; returns the estimate for this frame."""
        if measured is None:
            if self._weight < 2.0:
                # one frame's word: the next frame may be another camera's (a folder of
                # frames replayed) as well as this one's; the configured start is the
                # better guess until a second frame agrees
                return PsfEstimate(self.start)
            self.current = PsfEstimate(self.current.sigma_px, self.current.ellipticity,
                                       self.current.angle_rad, 0, self.current.sigma_error_px)
            return self.current
        prior = self.current
        se = math.hypot(measured.sigma_error_px,
                        prior.sigma_error_px if math.isfinite(prior.sigma_error_px) else 0.0)
        if self._weight == 0.0 or abs(measured.sigma_px - prior.sigma_px) > 3.0 * se:
            self.current = measured
            self._weight = 1.0
            return measured
        self._weight = min(self._weight + 1.0, float(self.memory))
        f = 1.0 / self._weight
        sigma = (1.0 - f) * prior.sigma_px + f * measured.sigma_px
        ellipticity = (1.0 - f) * prior.ellipticity + f * measured.ellipticity
        self.current = PsfEstimate(sigma, ellipticity, measured.angle_rad, measured.stars,
                                   measured.sigma_error_px / math.sqrt(self._weight))
        return self.current
