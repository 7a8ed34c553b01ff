"""The seed method's baselines: other centroids on the seed's own blobs.

All four keep the seed pipeline's segmentation (Gaussian blur, 3x3
median, threshold at ``detect.seed_threshold_frac`` of the maximum,
8-connected blobs; tracker.detect.seed) so that, as in the dissertation's
comparison, only the centroid differs:

* ``com``: intensity-weighted centre of mass of the *unfiltered* frame over
  each blob's pixels (no background subtracted).
* ``gaussian_fit``: iterative least squares (Levenberg-Marquardt, at most
  ``_LM_ITERATIONS`` steps) of A exp(-r^2 / (2 s^2)) + B, five free
  parameters (sigma kept within 0.3 px .. h), to the unfiltered pixels of
  a (2h+1)^2 window.
* ``gaussian_fit_fast``: Wan et al. (Sensors 2018, 18(9):2836) fit the
  logarithm: ln S = c0 + c1 x + c2 y + c3 x^2 + c4 y^2 by linear least
  squares over the window's pixels with I > 0 after subtracting the
  window's background, weighted by I (minimise sum I (ln I - ln S)^2, as
  docs/seed-method.md states it); x = -c1 / (2 c3), y = -c2 / (2 c4).
* ``sieve``: the Sieve Search Algorithm (Karaparambil et al., Sensors 2023,
  23(6):3222), from its published outline: the window is cut into all
  contiguous 3x3 sub-matrices ("sieves"); each is scored by magnitude
  (its background-subtracted sum) times symmetry (1 - sum |A - A rotated
  180 deg| / (2 sum |A|), the paper's symmetry about the diagonals reduced
  to point symmetry about the sieve's centre); the sieves scoring at least
  half the best are selected; every pixel accumulates the scores of the
  selected sieves covering it and the centroid is the average of pixel
  positions weighted by that accumulated score. Assumed where the outline
  is silent: the sieve size (3x3), the symmetry measure, the product score
  and the half-of-best selection.

Window: (2h+1)^2 pixels centred on the pixel nearest the seed centroid,
h = max(2, ceil(3 ``detect.psf_sigma_px``)); its background is the median
of the window's outermost ring. A window that leaves the frame is clipped
to the edge pixels. A fit that fails (no peak, or a centre outside the
window) keeps the seed's blob centre.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.config import DetectConfig
from tracker.detect.seed import SeedDetector

__all__ = ["ComDetector", "GaussianFitDetector", "FastGaussianFitDetector", "SieveDetector"]

_LM_ITERATIONS = 30
_SIEVE = 3


class ComDetector(SeedDetector):
    """Seed blobs, centre of mass of the unfiltered frame."""

    com_on_filtered = False


class _WindowDetector(SeedDetector):
    """Seed blobs, a centroid fitted in a window of the unfiltered frame."""

    def __init__(self, cfg: DetectConfig, shape: tuple[int, int], bit_depth: int) -> None:
        super().__init__(cfg, shape, bit_depth)
        self.half = max(2, int(math.ceil(3.0 * cfg.psf_sigma_px)))
        d = np.arange(-self.half, self.half + 1)
        self.dy, self.dx = np.meshgrid(d, d, indexing="ij")
        self.xs = self.dx.ravel().astype(np.float64)   # window pixel offsets, flattened
        self.ys = self.dy.ravel().astype(np.float64)
        ring = np.maximum(np.abs(self.dx), np.abs(self.dy)) == self.half
        self.ring = ring.ravel()

    def _refine(self, count: int) -> None:
        if count == 0:
            return
        s = self.table.stars
        cx = np.rint(s["x"][:count]).astype(np.int64)
        cy = np.rint(s["y"][:count]).astype(np.int64)
        rows, cols = self.input.shape
        r = np.clip(cy[:, None, None] + self.dy[None], 0, rows - 1)
        c = np.clip(cx[:, None, None] + self.dx[None], 0, cols - 1)
        win = self.input.work[r, c].astype(np.float64)
        flat = win.reshape(count, -1)
        bg = np.median(flat[:, self.ring], axis=1)
        win -= bg[:, None, None]
        dx, dy, ok = self._fit(win)
        ok &= (np.abs(dx) <= self.half) & (np.abs(dy) <= self.half)
        s["x"][:count] = np.where(ok, cx + dx, s["x"][:count])
        s["y"][:count] = np.where(ok, cy + dy, s["y"][:count])

    def _fit(self, win: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Offsets (dx, dy) from the window centre and a success mask, per window."""
        raise NotImplementedError


class GaussianFitDetector(_WindowDetector):
    """Seed blobs, 2-D Gaussian + constant fitted by Levenberg-Marquardt."""

    def _fit(self, win):
        n = len(win)
        x, y, z = self.xs, self.ys, win.reshape(n, -1)
        sigma0 = max(self.cfg.psf_sigma_px, 0.5)
        p = np.stack([np.maximum(z.max(axis=1), 1e-6), np.zeros(n), np.zeros(n),
                      np.full(n, sigma0), np.zeros(n)], axis=1)
        lam = np.full(n, 1e-3)
        cost = self._cost(p, x, y, z)
        for _ in range(_LM_ITERATIONS):
            jac, resid = self._jacobian(p, x, y, z)
            jtj = np.einsum("nki,nkj->nij", jac, jac)
            jtr = np.einsum("nki,nk->ni", jac, resid)
            damp = jtj + lam[:, None, None] * np.eye(5) * np.diagonal(
                jtj, axis1=1, axis2=2)[:, :, None]
            try:
                step = np.linalg.solve(damp, jtr[..., None])[..., 0]
            except np.linalg.LinAlgError:
                break
            trial = p + step
            trial[:, 3] = np.clip(np.abs(trial[:, 3]), 0.3, float(self.half))
            new = self._cost(trial, x, y, z)
            better = new < cost
            p[better] = trial[better]
            cost[better] = new[better]
            lam = np.where(better, lam * 0.3, lam * 10.0)
        ok = np.isfinite(p).all(axis=1) & (p[:, 0] > 0)
        return p[:, 1], p[:, 2], ok

    @staticmethod
    def _model(p, x, y):
        e = np.exp(-((x[None] - p[:, 1:2]) ** 2 + (y[None] - p[:, 2:3]) ** 2)
                   / (2.0 * p[:, 3:4] ** 2))
        return p[:, 0:1] * e + p[:, 4:5], e

    def _cost(self, p, x, y, z):
        m, _ = self._model(p, x, y)
        return np.sum((z - m) ** 2, axis=1)

    def _jacobian(self, p, x, y, z):
        m, e = self._model(p, x, y)
        a, s = p[:, 0:1], p[:, 3:4]
        ex, ey = x[None] - p[:, 1:2], y[None] - p[:, 2:3]
        jac = np.stack([e, a * e * ex / s ** 2, a * e * ey / s ** 2,
                        a * e * (ex ** 2 + ey ** 2) / s ** 3, np.ones_like(e)], axis=2)
        return jac, z - m


class FastGaussianFitDetector(_WindowDetector):
    """Seed blobs, weighted linear least squares on the logarithm (Wan et al. 2018)."""

    def _fit(self, win):
        n = len(win)
        x, y, z = self.xs, self.ys, win.reshape(n, -1)
        w = np.where(z > 0, z, 0.0)
        logz = np.log(np.where(z > 0, z, 1.0))
        design = np.stack([np.ones_like(x), x, y, x ** 2, y ** 2], axis=1)  # (K, 5)
        a = np.einsum("nk,ki,kj->nij", w, design, design)
        b = np.einsum("nk,ki,nk->ni", w, design, logz)
        ok = np.linalg.matrix_rank(a) == 5
        c = np.zeros((n, 5))
        if np.any(ok):
            c[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
        ok &= (c[:, 3] < 0) & (c[:, 4] < 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            return -c[:, 1] / (2.0 * c[:, 3]), -c[:, 2] / (2.0 * c[:, 4]), ok


class SieveDetector(_WindowDetector):
    """Seed blobs, Sieve Search Algorithm centroid (Karaparambil et al. 2023)."""

    def _fit(self, win):
        n, size, _ = win.shape
        k = _SIEVE
        m = size - k + 1                                     # sieves per axis
        sieves = np.lib.stride_tricks.sliding_window_view(win, (k, k), axis=(1, 2))
        magnitude = sieves.sum(axis=(3, 4))                  # (n, m, m)
        asym = np.abs(sieves - sieves[..., ::-1, ::-1]).sum(axis=(3, 4))
        total = np.abs(sieves).sum(axis=(3, 4))
        with np.errstate(divide="ignore", invalid="ignore"):
            symmetry = np.where(total > 0, 1.0 - asym / (2.0 * total), 0.0)
        score = np.maximum(magnitude, 0.0) * symmetry
        best = score.reshape(n, -1).max(axis=1)
        selected = np.where(score >= 0.5 * best[:, None, None], score, 0.0)
        selected[best <= 0] = 0.0
        weight = np.zeros((n, size, size))
        for i in range(k):
            for j in range(k):
                weight[:, i:i + m, j:j + m] += selected
        total_w = weight.sum(axis=(1, 2))
        ok = total_w > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (weight * self.dx[None]).sum(axis=(1, 2)) / total_w
            dy = (weight * self.dy[None]).sum(axis=(1, 2)) / total_w
        return dx, dy, ok
