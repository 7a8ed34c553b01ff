"""Maximum-likelihood star centres under multiplicative (speckle-like) noise.

Noise model: a pixel whose expected value is ``mu`` ADU delivers the integer
round(clip(mu (1 + s Z), 0, full)), Z standard normal and ``s`` the
relative noise (the seed method's speckle, or any camera whose noise
scales with the light). The probability of a delivered value k is

    P(k) = Phi(z(k + 1/2)) - Phi(z(k - 1/2)),   z(b) = (b / mu - 1) / s,

with the interval open below at k = 0 and above at k = full, so rounding
and both clips are part of the likelihood rather than approximations.
``mu`` = min(background + flux * g(x, y), full), g the pixel-integrated
Gaussian PSF of the detector's sigma. Light beyond full scale is clipped
before the noise as well as after it: that is the seed's speckle (a
displayed 0..1 image, then its noise), and for a sensor that clips only
after the noise it merely leaves the saturated core, which says little
about the centre either way, out of the fit, so saturated stars need no
separate treatment.

Why a likelihood fit: under this noise a bright pixel is, relatively, as
uncertain as a faint one, so the information about the centre lies in
the shape of the spot across its wings down to where rounding takes
over, and in which wing pixels came out zero. A centroid of any
weighting lets the noise of the brightest pixels pull it; the
maximum-likelihood fit weighs every pixel by what it actually says.

Method, per star, vectorised over the stars of a frame:

1. a coarse search: the likelihood on a 5 x 5 grid of centres within
   +-1.5 px of the candidate pixel (flux = window sum, s = 1). The
   likelihood has local maxima around single bright speckles; starting
   from the grid's best point puts the fit in the basin of the global one
   even when a noisy pixel has pulled the windowed centroid a pixel off;
2. Gauss-Newton steps in the BHHH form (curvature from the outer products
   of the per-pixel scores, so only first derivatives are needed) on the
   centre, the flux and log s, each step halved until the likelihood
   does not fall.

Each pixel's probability carries a floor (``_STRAY``, 1e-6): a value the
star's model cannot explain, such as a pixel of 1-3 ADU that a
neighbour's wing lights in a corner of the window where the model puts
0.04 ADU (probability near 1e-30), costs a fixed amount rather than
outweighing every pixel of the star and dragging the centre off it.

``s`` is fitted per star: it is nearly uncorrelated with the centre (by
symmetry), and a wrong s only changes how rounding and speckle share the
wings. Used only with ``detect.centroid_noise: multiplicative``; it works
on per-frame temporaries of (stars x window pixels).
"""

from __future__ import annotations

import numpy as np

from tracker.normal import log_interval, log_pdf, pixel_fractions

__all__ = ["MultiplicativeFit", "interval_scores"]

_GRID_PX = np.linspace(-1.5, 1.5, 5)
_MIN_MU = 1e-3          # ADU; an expected value below this says "certainly 0"
_MIN_FLUX = 1.0         # ADU
_HALVINGS = 6
_CONVERGED = 1e-3       # px: a star whose centre moved less, and whose flux and log s
_CONVERGED_SHAPE = 1e-2  # changed less than this (relative, log), has converged
_LOG_S_MIN, _LOG_S_MAX = np.log(1e-3), np.log(100.0)   # relative noise s kept in range
# a pixel's value comes, with this probability, from light that is not the star's (a
# neighbour's wing, an impulse): its log P is never below log(_STRAY)
_STRAY = 1e-6
_LOG_STRAY = np.log(_STRAY)


def _with_stray(log_p: np.ndarray) -> np.ndarray:
    """log(P + _STRAY): a value the star's model cannot explain costs a fixed amount."""
    with np.errstate(invalid="ignore"):       # a window that cannot be fitted stays NaN
        return np.logaddexp(log_p, _LOG_STRAY)


def _interval_log_p(lo, hi, mu, s):
    """(z_lo, z_hi, log P) of interval_scores."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        z_lo = (lo / mu - 1.0) / s
        z_hi = (hi / mu - 1.0) / s
    return z_lo, z_hi, log_interval(z_lo, z_hi)


def interval_scores(lo: np.ndarray, hi: np.ndarray, mu: np.ndarray,
                    s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log P of a delivered value and its derivatives by mu and by log s.

    The value stands for the interval (``lo``, ``hi``) ADU (-inf / +inf at
    the clips) and is mu (1 + s Z): P = Phi(z(hi)) - Phi(z(lo)),
    z(b) = (b / mu - 1) / s. Returns (log P, d log P / d mu, d log P / d log s),
    broadcast over the inputs; ``mu`` > 0 and ``s`` > 0.
    """
    z_lo, z_hi, log_p = _interval_log_p(lo, hi, mu, s)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        # phi(z) / P at each end; an open end contributes nothing
        t_lo = np.where(np.isfinite(z_lo), np.exp(log_pdf(z_lo) - log_p), 0.0)
        t_hi = np.where(np.isfinite(z_hi), np.exp(log_pdf(z_hi) - log_p), 0.0)
    z_lo = np.where(np.isfinite(z_lo), z_lo, 0.0)
    z_hi = np.where(np.isfinite(z_hi), z_hi, 0.0)
    by_mu = -((1.0 + s * z_hi) * t_hi - (1.0 + s * z_lo) * t_lo) / (mu * s)
    by_log_s = -(z_hi * t_hi - z_lo * t_lo)
    return log_p, by_mu, by_log_s


class MultiplicativeFit:
    """ML centres for stars in square windows of (2 ``radius`` + 1)^2 pixels.

    ``sigma``: PSF sigma, px. ``full``: the largest value a pixel can hold,
    ADU. ``iterations``: most Gauss-Newton steps.
    """

    def __init__(self, radius: int, sigma: float, full: float, iterations: int = 10) -> None:
        self.axis_edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
        self.sigma = float(sigma)
        self.full = float(full)
        self.iterations = int(iterations)

    def fit(self, values: np.ndarray, background: np.ndarray,
            flux: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centres (x, y), px from the window centre, and a validity mask, for n stars.

        ``values``: (n, side^2) delivered pixel values, ADU, rows of the
        window in order; ``background``: the same pixels' background, ADU;
        ``flux``: (n,) a first estimate of each star's flux, ADU.
        """
        k = np.asarray(values, np.float64)
        lo = np.where(k <= 0.0, -np.inf, k - 0.5)
        hi = np.where(k >= self.full, np.inf, k + 0.5)
        bg = np.asarray(background, np.float64)
        p = np.zeros((len(flux), 4))
        p[:, 2] = np.maximum(flux, _MIN_FLUX)
        p[:, :2] = self._grid_start(lo, hi, bg, p)
        p = self._climb(lo, hi, bg, p)
        ok = np.all(np.isfinite(p), axis=1)
        return p[:, 0], p[:, 1], ok

    def _climb(self, lo, hi, bg, p) -> np.ndarray:
        """Gauss-Newton steps from ``p`` (changed in place and returned)."""
        active = np.arange(len(p))                # stars still changing
        for _ in range(self.iterations):
            if len(active) == 0:
                break
            rows = (lo[active], hi[active], bg[active])
            ll, scores = self._likelihood(*rows, p[active], with_scores=True)
            np.nan_to_num(scores, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            grad = scores.sum(axis=1)
            curv = np.einsum("nki,nkj->nij", scores, scores) + 1e-9 * np.eye(4)
            step = np.zeros_like(grad)            # a star with no curvature stays put
            solvable = np.isfinite(curv).all(axis=(1, 2)) & (np.linalg.det(curv) > 0)
            step[solvable] = np.linalg.solve(curv[solvable], grad[solvable][..., None])[..., 0]
            moved = self._line_search(rows, p, active, ll, step)
            active = active[moved > _CONVERGED]
        return p

    def _line_search(self, rows, p, active, ll, step) -> np.ndarray:
        """Take ``step`` for the ``active`` stars, halved until the likelihood does not fall.

        Updates p in place; returns each star's largest change, the flux's
        (relative) and log s's scaled to the centre's tolerance (0 where no
        fraction of the step helped): the first steps mostly fix the flux
        and s, so a still centre alone does not mean convergence.
        """
        base = p[active]
        scale = np.ones(len(active))
        pending = np.arange(len(active))
        for _ in range(_HALVINGS):
            trial = base[pending] + scale[pending, None] * step[pending]
            trial[:, 2] = np.maximum(trial[:, 2], _MIN_FLUX)
            ll_trial, _ = self._likelihood(*(r[pending] for r in rows), trial)
            good = ll_trial >= ll[pending]
            p[active[pending[good]]] = trial[good]
            pending = pending[~good]
            if len(pending) == 0:
                break
            scale[pending] *= 0.5
        scale[pending] = 0.0
        change = np.abs(scale[:, None] * step)
        change[:, 2] /= base[:, 2]
        change[:, 2:] *= _CONVERGED / _CONVERGED_SHAPE
        return np.max(change, axis=1)

    def _grid_start(self, lo, hi, bg, p) -> np.ndarray:
        """(n, 2): the grid point of highest likelihood per star (flux from p, s = 1)."""
        best = np.full(len(p), -np.inf)
        start = np.zeros((len(p), 2))
        trial = p.copy()
        for gx in _GRID_PX:
            for gy in _GRID_PX:
                trial[:, 0], trial[:, 1] = gx, gy
                ll, _ = self._likelihood(lo, hi, bg, trial)
                better = ll > best
                best[better] = ll[better]
                start[better] = (gx, gy)
        return start

    def _likelihood(self, lo, hi, bg, p, with_scores: bool = False):
        """Log-likelihood per star and, if asked, per-pixel scores (n, pixels, 4).

        Parameters p (n, 4): x, y (px from the window centre), flux (ADU), log s.
        """
        n = len(p)
        fx, dfx = pixel_fractions(self.axis_edges[None, :] - p[:, 0, None], self.sigma)
        fy, dfy = pixel_fractions(self.axis_edges[None, :] - p[:, 1, None], self.sigma)
        shape = (fy[:, :, None] * fx[:, None, :]).reshape(n, -1)
        mu = bg + p[:, 2, None] * shape
        live = (mu > _MIN_MU) & (mu < self.full)   # else mu is clamped: no derivative
        mu = np.clip(mu, _MIN_MU, self.full)
        s = np.exp(np.clip(p[:, 3], _LOG_S_MIN, _LOG_S_MAX))[:, None]
        if not with_scores:
            return _with_stray(_interval_log_p(lo, hi, mu, s)[2]).sum(axis=1), None
        log_p, by_mu, by_log_s = interval_scores(lo, hi, mu, s)
        mixed = _with_stray(log_p)
        ll = mixed.sum(axis=1)
        own = np.exp(log_p - mixed)            # the share of the star's model in P
        by_mu = np.where(live, by_mu * own, 0.0)
        by_log_s = by_log_s * own
        flux = p[:, 2, None]
        gx = (fy[:, :, None] * dfx[:, None, :]).reshape(n, -1)
        gy = (dfy[:, :, None] * fx[:, None, :]).reshape(n, -1)
        scores = np.stack([by_mu * flux * gx, by_mu * flux * gy, by_mu * shape, by_log_s],
                          axis=2)
        return ll, scores
