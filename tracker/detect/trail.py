"""Centroids of stars trailed by the camera's motion: a line-spread model fitted to each.

A star that moves by the vector s (px) during the exposure is its PSF swept
along a segment of length L = |s|, centred on its mid-exposure position c
(the position the frame's time stamps). For a Gaussian PSF of sigma
``sigma`` (the pixel-integrated one: tracker.detect.default.effective_sigma)
and coordinates a along the trail and b across it, measured from c,

    I(a, b) = F exp(-b^2 / 2 sigma^2) / (sqrt(2 pi) sigma)
              x [Phi((a + L/2) / sigma) - Phi((a - L/2) / sigma)] / L

(the line-spread function: a box of length L convolved with the Gaussian;
Phi the normal CDF). A Gaussian-windowed centroid (tracker.detect.windowed)
has no unique fixed point along a trail much longer than its window: any
point of the flat top is one, and noise picks it. The fit of (F, c) by
Gauss-Newton on the pixels of a band along the trail (:class:`TrailFit`),
the background taken as the median of the border of a square box holding
the band, has one: the trail's centre.

Used by tracking, which knows the smear of each star from the rate
(tracker.identify.predict); stars whose trail is shorter than
``MIN_TRAIL_SIGMAS`` sigma keep their windowed centroid, and so do stars
whose box leaves the frame or whose fitted centre lies more than
``max_shift`` px from the detection. The two agree on short trails: on realistic
16 mm frames (PSF 1.0-1.6 px, 3 fields each, 50-110 stars) their RMS errors
against the truth differed by less than 10 %, either way, up to 2.5 sigma
of trail; from 3 sigma the fit's was 10-40 % lower.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.detect.layout import window_view

__all__ = ["TrailFit", "normal_cdf", "MIN_TRAIL_SIGMAS"]

MIN_TRAIL_SIGMAS = 2.5
_REAL = np.float32   # the band's arrays: the model to 1e-7, its sums over the band to 1e-5;
                     # the centres within 1e-5 px of float64's, the steps twice as fast
_ALONG = -math.sqrt(math.pi / 2.0)   # the along column's scale: dg / dda = that column / _ALONG
# the table's rows (model along, across, flux; data) whose products a step sums per star:
# M_aa, M_ab, M_bb, M_aF, M_bF, M_FF, then J^T d along, across, flux
_LEFT, _RIGHT = np.array([0, 0, 1, 0, 1, 2, 0, 1, 2]), np.array([0, 1, 1, 2, 2, 2, 3, 3, 3])
# the Schur complement's (saa, sab, sbb) from (M_aF, M_bF), and the entries (sbb, saa) the
# step's numerators take
_SCHUR_I, _SCHUR_J = np.array([0, 0, 1]), np.array([0, 1, 1])
# the entries (sbb, sbb, saa) and residuals (ra, ra, rb; rb, rb, ra) of the step's numerators
_SCHUR_STEP, _STEP_R, _STEP_CROSS = np.array([2, 2, 0]), np.array([0, 0, 1]), np.array([1, 1, 0])


def _runs(band: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The flat indices of ``band``'s (n, side, side) true pixels, each star's first one among
    them and their count per star (C order: star by star; a band holds the pixels next to
    the point it is centred on, so no run is empty)."""
    count = band.sum(axis=(1, 2))
    return band.ravel().nonzero()[0], count.cumsum() - count, count


def _box_inside(ixy: np.ndarray, half: int, shape: tuple[int, int]) -> np.ndarray:
    """Mask (n,) of the boxes of ``half`` px around the pixels ``ixy`` (n, 2) (x, y) that lie
    inside a frame of ``shape`` (rows, columns)."""
    h, w = shape[:2]
    return ((ixy >= half) & (ixy < (w - half, h - half))).all(axis=1)


def normal_cdf(z: np.ndarray) -> np.ndarray:
    """Phi(z), the standard normal CDF, to 1.5e-7 (Abramowitz and Stegun 7.1.26 for erf)."""
    return 0.5 + 0.5 * _signed_erf(z, np.exp(-0.5 * z * z))


def _signed_erf(z: np.ndarray, gauss: np.ndarray) -> np.ndarray:
    """2 Phi(z) - 1 = erf(z / sqrt 2), given ``gauss`` = exp(-z^2 / 2) (the line-spread
    model has it already); a new array of ``z``'s type.

    Each operation writes into one of two arrays of ``z``'s shape: the same arithmetic,
    in the same order, as the expression written out, without a new array for each of
    its sixteen steps (a fifth less time on a frame's band).
    """
    t = np.abs(z)
    t *= 0.3275911 / math.sqrt(2.0)
    t += 1.0
    np.reciprocal(t, out=t)
    poly = t * 1.061405429                  # Horner's rule, the innermost coefficient first
    for coefficient in (-1.453152027, 1.421413741, -0.284496736, 0.254829592):
        poly += coefficient
        poly *= t
    poly *= gauss
    np.subtract(1.0, poly, out=poly)
    return np.copysign(poly, z, out=poly)


class TrailFit:
    """Fits trailed stars of a PSF of ``sigma`` px: ``iterations`` Gauss-Newton steps each.

    All trailed stars of a frame are fitted together, each on the pixels
    its model reaches: within ``L / 2 + 3 sigma`` along the trail of the
    first moment of its light and ``3 sigma`` across (beyond, a pixel holds
    under 1.1 % of the peak). That moment (the start of the fit: the
    detection may sit anywhere on the trail's flat top) is taken over a
    wider search band, ``L / 2 + 3 sigma + 2`` px along from the detection
    and ``3 sigma + 1`` across. Both bands are picked from a square box
    around the detection of the side that holds every star's search band
    (the boxes read from the frame as one view). The fit's pixels of all
    stars lie in one flat array, each star's a contiguous run; a step is a
    few whole-array operations over them and one segmented sum per star
    (np.add.reduceat), no per-star loop and no test of convergence. On 16
    mm frames at 3 deg/s (trails of 4 px) the fit's band holds 93 pixels a
    star against the search band's 155, which the steps ran on before: the
    fit's thread CPU 0.58 -> 0.49 ms a frame (23 stars), the centres'
    errors against the truth as they were (bench track cross and roll RMS
    within 0.01 px and 0.1 arcsec on seeds 13, 102 and 103; on 12 frames
    trailed 6-14 px median 0.396 -> 0.392 px, RMS 0.944 -> 0.935 px).
    From there two steps land within 0.01-0.03 px of twelve steps' centre for the median
    star of 16 mm frames trailed 6-14 px (90th percentile 0.2-0.5 px: faint
    and blended stars), far inside the centres' errors against the truth,
    which a third step leaves as they are (median 0.24-0.37 px, RMS
    0.39-0.91 px with two steps; 0.25-0.35 and 0.41-1.05 px with three, 4
    fields each); from the detection itself the 90th percentile on 14 px
    trails was 0.6 px.

    The unknowns are the centre's offsets from the start along and across
    the trail in units of sigma, and the flux; the model is fitted up to a
    constant factor per star (the flux takes it), so its constants are left
    out of every pixel's arithmetic. The band's pixel arrays are float32
    (``_REAL``), their sums per star float64; the centres are kept in float64.
    """

    def __init__(self, sigma: float, iterations: int = 2, max_shift: float = 3.0) -> None:
        self.sigma = float(sigma)
        self.min_length = MIN_TRAIL_SIGMAS * self.sigma     # shorter trails are not fitted
        self.iterations = int(iterations)
        self.max_shift = float(max_shift)
        self._rim_side, self._rim_index = 0, np.zeros(0, np.intp)

    def refine(self, image: np.ndarray, xy: np.ndarray, smear: np.ndarray) -> np.ndarray:
        """Centres (n, 2) of the stars near ``xy`` (n, 2) trailed by ``smear`` (n, 2), px.

        Returns a new array; rows not fitted (module docstring) keep ``xy``.
        """
        out = np.array(xy, dtype=np.float64, copy=True)
        length = np.hypot(smear[:, 0], smear[:, 1])
        rows = (length >= self.min_length).nonzero()[0]
        if len(rows) == 0:
            return out
        s = self.sigma
        along_half = length[rows] / 2.0 + 3.0 * s + 2.0         # the band, px from the start
        half = self.box_half(float(length[rows].max()))        # the box holding every band
        ixy = np.rint(out[rows]).astype(np.intp)               # (x, y) the box's middle pixel
        inside = _box_inside(ixy, half, image.shape)
        if not inside.all():                # (the usual frame: every box inside, no copies)
            rows, ixy, along_half = rows[inside], ixy[inside], along_half[inside]
            if len(rows) == 0:
                return out
        n = len(rows)
        u = smear[rows] / length[rows, None]                     # unit vector along the trail
        start = out[rows]
        side = 2 * half + 1
        box = window_view(image, side)[ixy[:, 1] - half, ixy[:, 0] - half]   # (n, side, side)
        rim = box.reshape(n, -1)[:, self._rim(side)]
        mid = rim.shape[1] // 2                                  # an even count: two middles
        rim.partition((mid - 1, mid), axis=1)                   # (a copy: in place)
        sky = np.add(rim[:, mid - 1], rim[:, mid], dtype=np.float64)   # their mean, as
        sky *= 0.5                                                       # np.mean's, exact
        # pixel - start along the box's columns and rows, sigma; a pixel's place along and
        # across the trail is a column's share plus a row's
        dx, dy = ((np.arange(-half, half + 1) - (start - ixy)[:, :, None]) / s).transpose(1, 0, 2)
        ux, uy = u[:, 0:1], u[:, 1:2]
        a = (dx * ux)[:, None, :] + (dy * uy)[:, :, None]        # (n, side, side)
        b = (dy * ux)[:, :, None] - (dx * uy)[:, None, :]
        # the first moment along of the light within the search band (the detection may sit
        # anywhere on the trail's flat top), summed over the whole box with the light
        # outside the band zeroed (a box holds a few hundred pixels: fewer numpy calls
        # than picking the band's)
        light = box - sky[:, None, None]
        np.maximum(light, 0.0, out=light)
        abs_b = np.abs(b)
        light *= (np.abs(a) <= (along_half / s)[:, None, None]) & (abs_b <= (3.0 * s + 1.0) / s)
        first = (light * a).sum(axis=(1, 2)) / np.maximum(light.sum(axis=(1, 2)), 1e-30)
        # the fit's band: the pixels the model reaches from there, L / 2 + 3 sigma along
        # and 3 sigma across (beyond, a pixel holds under 1.1 % of the peak: noise, next to
        # no information)
        hl = length[rows] / (2.0 * s)
        pick, runs, count = _runs((np.abs(a - first[:, None, None]) <= (hl + 3.0)[:, None, None])
                                  & (abs_b <= 3.0))
        # rows 0-2 the unit-flux model and its derivatives (:meth:`_model`), row 3 the data
        table = np.empty((4, len(pick)), _REAL)
        np.subtract(box.reshape(-1)[pick], sky.repeat(count), out=table[3], casting="unsafe")
        a_band = a.reshape(-1)[pick]
        # the pixels' places from the start: along less and plus the half length (from
        # the trail's two ends), across; sigma
        ends = np.empty((3, table.shape[1]), _REAL)
        h = hl.repeat(count)
        np.add(a_band, h, out=ends[0], casting="unsafe")
        np.subtract(a_band, h, out=ends[1], casting="unsafe")
        ends[2] = b.reshape(-1)[pick]
        centre = np.zeros((3, n))           # from the start: along (twice) and across, sigma
        centre[0] = centre[1] = first
        with np.errstate(divide="ignore", invalid="ignore"):    # (the steps' divisions)
            for _ in range(self.iterations):
                centre += self._step(table, runs, ends - centre.astype(_REAL).repeat(count,
                                                                                     axis=1))
        across = np.array((-u[:, 1], u[:, 0])).T                 # b's direction
        c = start + s * (centre[0][:, None] * u + centre[2][:, None] * across)
        ok = (np.abs(c - start) <= self.max_shift).all(axis=1)   # (False where NaN or inf)
        if ok.all():
            out[rows] = c
        else:
            out[rows[ok]] = c[ok]
        return out

    def box_half(self, longest: float) -> int:
        """Half the side (px, the middle pixel left out) of the box :meth:`refine` reads
        around each star when the longest trail it fits is ``longest`` px."""
        return int(math.ceil(longest / 2.0 + 3.0 * self.sigma + 2.0))

    def fitted(self, shape: tuple[int, int], xy: np.ndarray, smear: np.ndarray,
               longest: float) -> np.ndarray:
        """Mask (n,) of the stars at ``xy`` (n, 2) trailed by ``smear`` (n, 2) px that
        :meth:`refine` fits (rather than leaving at ``xy``) in a frame of ``shape`` (rows,
        columns) among stars none trailed longer than ``longest`` px: long enough, and
        their boxes inside the frame (a fitted centre may still stay at ``xy``: one
        that moves beyond ``max_shift``)."""
        return ((np.hypot(smear[:, 0], smear[:, 1]) >= self.min_length)
                & _box_inside(np.rint(xy).astype(np.intp), self.box_half(longest), shape))

    def _rim(self, side: int) -> np.ndarray:
        """Flat indices of a square box's border pixels (any order: the sky is their median),
        kept for the last side."""
        if self._rim_side != side:
            ring = np.ones((side, side), bool)
            ring[1:-1, 1:-1] = False
            self._rim_index, self._rim_side = np.flatnonzero(ring), side
        return self._rim_index

    def _step(self, table: np.ndarray, runs: np.ndarray, z: np.ndarray) -> np.ndarray:
        """The Gauss-Newton step (3, n) of the centres along (twice: rows 0 and 1) and across,
        sigma, the flux solved at each.

        ``table`` (4, k): rows 0-2 are filled with the model (:meth:`_model`, of ``z``),
        row 3 holds the band's data; ``runs`` each star's first pixel in it. With the
        flux F at its least-squares value for the current centre (the gradient along F
        is zero), the step of the 3 x 3 system in (c, F) is that of its 2 x 2 Schur
        complement in c: (S / F) dc = J_c r, S = M_cc - M_cF M_Fc / M_FF, M the unit-flux
        model's normal matrix; each entry a product of per-star sums, no batched solve.
        """
        self._model(z, table[:3])
        # per star: M_aa, M_ab, M_bb, M_aF, M_bF, M_FF and J^T d (a, b, F): the nine sums of
        # products of the table's rows
        sums = np.add.reduceat(table[_LEFT] * table[_RIGHT], runs, axis=1, dtype=np.float64)
        # the entries' pairs side by side, (a, b) or (aa, ab, bb): each of the few calls
        # does the arithmetic of two or three
        mff = sums[5]
        mf = sums[3:5]                                         # (M_aF, M_bF)
        flux = sums[8] / mff                 # (the caller ignores division by zero: no step)
        r = sums[6:8] - flux * mf                              # (ra, rb)
        sch = sums[0:3] - mf[_SCHUR_I] * mf[_SCHUR_J] / mff    # saa, sab, sbb
        sab = sch[1]
        scale = flux * (sch[0] * sch[2] - sab * sab)
        # sbb ra - sab rb (along, twice), saa rb - sab ra (across)
        step = sch[_SCHUR_STEP] * r[_STEP_R] - sab * r[_STEP_CROSS]
        step[:2] *= _ALONG
        step /= scale
        step[:, ~(np.abs(scale) > 1e-30)] = 0.0                # singular (or NaN): no step
        return step

    @staticmethod
    def _model(z: np.ndarray, out: np.ndarray) -> None:
        """Into ``out`` (3, k): the trail g at the pixels ``z`` (3, k): sigma along from the
        trail's two ends (a + h, a - h) and across from its centre (b), up to a factor
        per star, and its derivatives by the centre's offsets along (scaled by 1 /
        _ALONG) and across.

        g = exp(-b^2 / 2) [erf((a + h) / sqrt 2) - erf((a - h) / sqrt 2)], h the half
        length in sigma; the centre moving by da moves a by -da, so dg / dda =
        -sqrt(2 / pi) exp(-b^2 / 2) (e(a + h) - e(a - h)), e(z) = exp(-z^2 / 2), and
        dg / ddb = b g.
        """
        e = z * z
        e *= -0.5
        np.exp(e, out=e)                              # e(a + h), e(a - h), exp(-b^2 / 2)
        edge = _signed_erf(z[:2], e[:2])
        np.subtract(edge[0], edge[1], out=edge[0])
        np.multiply(e[2], edge[0], out=out[2])
        np.subtract(e[0], e[1], out=e[0])
        np.multiply(e[2], e[0], out=out[0])
        np.multiply(z[2], out[2], out=out[1])
