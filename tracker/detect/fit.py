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
All arrays are preallocated for ``chunk`` windows of up to ``max_side``^2
pixels; the separable per-axis fractions are the only per-call temporaries
(a few kB).
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
                      for name in ("shape", "model", "weight", "resid", "jx", "jy", "tmp")}
        self._normal = np.zeros((self.chunk, 3, 3), np.float64)
        self._grad = np.zeros((self.chunk, 3), np.float64)
        self._flux = np.zeros(self.chunk, np.float64)
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
        k = self.side * self.side
        return {name: buf[: m * k].reshape(m, k) for name, buf in self._flat.items()}

    def _model(self, m: int, x: np.ndarray, y: np.ndarray, flux: np.ndarray, v: dict) -> None:
        """shape, model and the Jacobian columns jx, jy (flux times the shape's derivatives)."""
        side = self.side
        fx, dfx = pixel_fractions(self.edges[None, :] - x[:, None], self.sigma)
        fy, dfy = pixel_fractions(self.edges[None, :] - y[:, None], self.sigma)
        grid = (m, side, side)
        np.multiply(fy[:, :, None], fx[:, None, :], out=v["shape"].reshape(grid))
        np.multiply(fy[:, :, None], dfx[:, None, :], out=v["jx"].reshape(grid))
        np.multiply(dfy[:, :, None], fx[:, None, :], out=v["jy"].reshape(grid))
        np.multiply(v["jx"], flux[:, None], out=v["jx"])
        np.multiply(v["jy"], flux[:, None], out=v["jy"])
        np.multiply(v["shape"], flux[:, None], out=v["model"])

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
        flux = self._flux[:m]
        np.sum(signal, axis=1, out=flux)
        np.maximum(flux, 1.0, out=flux)
        usable = v["tmp"]
        np.less(raw, saturation, out=usable)        # 1.0 where the pixel is not clipped
        noise2 = np.maximum(np.square(noise[:m]), _MIN_VAR)
        normal, grad = self._normal[:m], self._grad[:m]
        for _ in range(self.iterations):
            self._model(m, x, y, flux, v)
            # weights 1 / (noise^2 + max(model, 0)), zero for clipped pixels
            w = v["weight"]
            np.maximum(v["model"], 0.0, out=w)
            np.add(w, noise2[:, None], out=w)
            np.divide(usable, w, out=w)
            np.subtract(signal, v["model"], out=v["resid"])
            cols = (v["jx"], v["jy"], v["shape"])
            for a in range(3):
                np.multiply(cols[a], w, out=v["model"])          # model: scratch from here on
                grad[:, a] = np.einsum("ij,ij->i", v["model"], v["resid"])
                for b in range(a, 3):
                    normal[:, a, b] = normal[:, b, a] = np.einsum("ij,ij->i", v["model"],
                                                                  cols[b])
            det = np.linalg.det(normal)
            good = np.isfinite(det) & (det > 0)
            if not np.any(good):
                break
            step = np.linalg.solve(normal[good], grad[good][..., None])[..., 0]
            x[good] = np.clip(x[good] + step[:, 0], -max_shift, max_shift)
            y[good] = np.clip(y[good] + step[:, 1], -max_shift, max_shift)
            flux[good] = np.maximum(flux[good] + step[:, 2], 1.0)
        return flux
