"""Star centres from a fit of the pixel-integrated Gaussian PSF: no pixel-phase bias.

A windowed centroid is exact for a well-sampled Gaussian, but a PSF of
sigma 0.6-0.9 px is undersampled: the light in a pixel is the PSF
integrated over it, and any centroid of the sampled values is pulled
toward the pixel centre or edge depending on where the star falls (the
pixel-phase bias, tens of millipixels at sigma 0.6 px). Fitting the model
the pixels really follow removes it:

    mu(c, r) = F * wx(c) * wy(r),   wx(c) = the Gaussian of sigma s integrated over pixel c

(tracker.normal.pixel_fractions; s is the frame's measured PSF sigma,
tracker.detect.psf). Unknowns are the centre (x, y) and the flux F; the
background is known (the detector subtracted it). Gauss-Newton steps
minimise sum (S - mu)^2 / var, var = noise^2 + max(mu, 0) ADU^2 (the
background's noise plus the star's own shot noise counted as one ADU^2 per
ADU, i.e. gains near 1 e-/ADU; the weights only set how pixels share the
information, so a gain several times off costs a few per cent of
precision, never bias). Pixels at or above ``saturation`` are left out
(censored): a clipped pixel says only "at least full scale", so saturated
stars are centred on their unclipped wings by the same fit.

Every step is clamped to ``max_shift`` px from the window's centre pixel.

The model is separable, mu = F fy(r) fx(c), so every entry of the normal
matrix and the gradient is a bilinear form a(r)^T M b(c) of a per-window
matrix M (the weights W, or W times the residual) with outer products of
the per-axis fractions and their derivatives: sum W jx jx = F^2 sum_r
fy^2 (W dfx^2)_r, and so on. Each Gauss-Newton step therefore passes over
the windows' pixels a handful of times (model, weights, weighted residual,
two batched matrix products), not once per entry of the normal matrix.
All arrays are preallocated for ``chunk`` windows of up to ``max_side``^2
pixels; the per-axis fractions and their products are the only per-call
temporaries (a few kB).
"""

from __future__ import annotations

import numpy as np

from tracker.normal import pixel_fractions

__all__ = ["PixelGaussianFit"]

_MIN_VAR = 1e-6


class PixelGaussianFit:
    """Fits flux and centre of a pixel-integrated Gaussian to square windows."""

    def __init__(self, chunk: int, max_side: int, iterations: int = 3) -> None:
        self.chunk = int(chunk)
        self.max_side = int(max_side)
        self.iterations = int(iterations)
        size = self.chunk * self.max_side ** 2
        self._flat = {name: np.zeros(size, np.float64)
                      for name in ("model", "weight", "resid", "usable")}
        self._rows = np.zeros(self.chunk * self.max_side * 3, np.float64)   # W b(c), R b(c)
        self._axis = np.zeros(self.chunk * self.max_side * 3, np.float64)   # b(c)
        self._normal = np.zeros((self.chunk, 3, 3), np.float64)
        self._grad = np.zeros((self.chunk, 3), np.float64)
        self._flux = np.zeros(self.chunk, np.float64)
        self._edges = np.zeros(2 * self.chunk * (self.max_side + 1), np.float64)
        self.side = 0
        self.sigma = 0.0
        self.edges = np.zeros(0)

    def configure(self, radius: int, sigma: float) -> None:
        """Windows of (2 radius + 1)^2 pixels; PSF sigma ``sigma`` px (optical, not integrated)."""
        self.side = 2 * int(radius) + 1
        if self.side > self.max_side:
            raise ValueError(f"window side {self.side} exceeds the fit's {self.max_side}")
        self.sigma = float(sigma)
        self.edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5

    def _views(self, m: int) -> dict:
        side = self.side
        k = side * side
        return {name: buf[: m * k].reshape(m, side, side) for name, buf in self._flat.items()}

    def _columns(self, m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(m, side, n) views of the per-axis factors b(c) and of W b(c) (or R b(c))."""
        size = m * self.side * n
        shape = (m, self.side, n)
        return self._axis[:size].reshape(shape), self._rows[:size].reshape(shape)

    def _normal_equations(self, m: int, fx, dfx, fy, dfy, flux, v: dict) -> None:
        """normal (m, 3, 3) and grad (m, 3) over (x, y, F) from the weights ``v["weight"]``
        and the weighted residuals ``v["resid"]`` (module docstring: bilinear forms).

        Each row factor meets all the column products it needs in one
        contraction (fy^2 with W dfx^2, W dfx fx and W fx^2; fy dfy with the
        last two; fy with R dfx and R fx).
        """
        normal, grad = self._normal[:m], self._grad[:m]
        cols, wb = self._columns(m, 3)
        np.multiply(dfx, dfx, out=cols[..., 0])
        np.multiply(dfx, fx, out=cols[..., 1])
        np.multiply(fx, fx, out=cols[..., 2])
        np.matmul(v["weight"], cols, out=wb)            # (W dfx^2, W dfx fx, W fx^2)
        fy2, fydy = fy * fy, fy * dfy
        f, f2 = flux, flux * flux
        by_fy2 = np.einsum("ij,ijk->ik", fy2, wb)       # (xx, xf, ff) / (F^2, F, 1)
        by_fydy = np.einsum("ij,ijk->ik", fydy, wb[..., 1:])   # (xy, yf) / (F^2, F)
        normal[:, 0, 0] = f2 * by_fy2[:, 0]
        normal[:, 1, 1] = f2 * np.einsum("ij,ij->i", dfy * dfy, wb[..., 2])
        normal[:, 2, 2] = by_fy2[:, 2]
        normal[:, 0, 1] = normal[:, 1, 0] = f2 * by_fydy[:, 0]
        normal[:, 0, 2] = normal[:, 2, 0] = f * by_fy2[:, 1]
        normal[:, 1, 2] = normal[:, 2, 1] = f * by_fydy[:, 1]
        cols, rb = self._columns(m, 2)
        np.copyto(cols[..., 0], dfx)
        np.copyto(cols[..., 1], fx)
        np.matmul(v["resid"], cols, out=rb)             # (R dfx, R fx)
        by_fy = np.einsum("ij,ijk->ik", fy, rb)
        np.multiply(by_fy[:, 0], f, out=grad[:, 0])
        np.multiply(np.einsum("ij,ij->i", dfy, rb[..., 1]), f, out=grad[:, 1])
        np.copyto(grad[:, 2], by_fy[:, 1])

    def run(self, m: int, signal: np.ndarray, raw: np.ndarray, x: np.ndarray, y: np.ndarray,
            noise: np.ndarray, saturation: float, max_shift: float) -> np.ndarray:
        """Refine centres ``x``, ``y`` (m,) in place; returns the fitted fluxes (m,).

        ``signal`` (m, side^2): background-subtracted windows, ADU; ``raw``
        the same pixels as delivered (for the saturation test); centres are
        px from each window's centre pixel; ``noise`` (m,) the background's
        pixel noise, ADU. A star whose normal matrix is singular keeps its
        centre.
        """
        v = self._views(m)
        side = self.side
        grid = (m, side, side)
        flux = self._flux[:m]
        np.sum(signal, axis=1, out=flux)
        np.maximum(flux, 1.0, out=flux)
        usable = v["usable"]
        np.less(raw.reshape(grid), saturation, out=usable)   # 1.0 where not clipped
        noise2 = np.maximum(np.square(noise[:m]), _MIN_VAR)[:, None, None]
        normal, grad = self._normal[:m], self._grad[:m]
        w, model, resid = v["weight"], v["model"], v["resid"]
        for _ in range(self.iterations):
            edges = self._edges[: 2 * m * (side + 1)].reshape(2, m, side + 1)
            np.subtract(self.edges, x[:, None], out=edges[0])
            np.subtract(self.edges, y[:, None], out=edges[1])
            frac, dfrac = pixel_fractions(edges, self.sigma)
            fx, fy, dfx, dfy = frac[0], frac[1], dfrac[0], dfrac[1]
            np.multiply((flux[:, None] * fy)[:, :, None], fx[:, None, :], out=model)
            # weights 1 / (noise^2 + max(model, 0)), zero for clipped pixels
            np.maximum(model, 0.0, out=w)
            np.add(w, noise2, out=w)
            np.divide(usable, w, out=w)
            np.subtract(signal.reshape(grid), model, out=resid)
            np.multiply(resid, w, out=resid)
            self._normal_equations(m, fx, dfx, fy, dfy, flux, v)
            det = np.linalg.det(normal)
            good = np.isfinite(det) & (det > 0)
            if not good.any():
                break
            if good.all():   # the usual case: every star steps, no gathering
                step = np.linalg.solve(normal, grad[..., None])[..., 0]
                for pos, axis_step in ((x, step[:, 0]), (y, step[:, 1])):
                    np.add(pos, axis_step, out=pos)
                    np.maximum(pos, -max_shift, out=pos)
                    np.minimum(pos, max_shift, out=pos)
                np.add(flux, step[:, 2], out=flux)
                np.maximum(flux, 1.0, out=flux)
                continue
            step = np.linalg.solve(normal[good], grad[good][..., None])[..., 0]
            x[good] = np.clip(x[good] + step[:, 0], -max_shift, max_shift)
            y[good] = np.clip(y[good] + step[:, 1], -max_shift, max_shift)
            flux[good] = np.maximum(flux[good] + step[:, 2], 1.0)
        return flux
