"""Point-spread functions other than the round Gaussian, rendered by supersampling.

Real optics are not Gaussian: a defocused M12 lens has Moffat-like wings, a
sharp one an Airy core with rings, and any of them can be slightly
elliptical. :class:`PsfShape` names such a PSF by the sigma of the Gaussian
with the same full width at half maximum (so that the detector's
"PSF sigma" means the same thing whatever the shape):

* ``gaussian``: exp(-r^2 / (2 s^2)) / (2 pi s^2);
* ``moffat``: (beta - 1) / (pi a^2) (1 + r^2 / a^2)^-beta, with
  a = FWHM / (2 sqrt(2^(1/beta) - 1)) (Moffat 1969);
* ``airy``: pi / (4 L^2) (2 J1(x) / x)^2, x = pi r / L, with L = lambda N
  = FWHM / 1.029 (the diffraction pattern of a circular aperture; 16 % of
  its light lies beyond the first dark ring at r = 1.22 L).

FWHM = 2 sqrt(2 ln 2) sigma. Ellipticity e stretches the profile to axes
sqrt(1 + e) and sqrt(1 - e) times the round one's (so that the second
moments' (Mxx - Myy, 2 Mxy) / (Mxx + Myy) has length e for a Gaussian) along
``angle_rad`` measured from +x toward +y.

:func:`shaped_stamps` integrates the profile over each pixel by averaging it
at ``ss`` x ``ss`` points per pixel (ss chosen so the points are at most
1/8 sigma apart): a different code path from tracker.sim.psf's exact erf
integral of the round Gaussian, so the two check each other. Stamps reach
8 sigma (plus 2 px) from the star, where a Moffat of beta 2.5 still holds a
few per cent of its light: that light is lost, as it is into the noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker.sim.psf import Stamps, stamp_box

__all__ = ["PsfShape", "SHAPES", "shaped_stamps", "bessel_j1", "FWHM_PER_SIGMA", "shape_model"]

SHAPES = ("gaussian", "moffat", "airy")
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
_AIRY_FWHM_PER_L = 1.029          # FWHM of the Airy pattern in units of lambda * N
_STAMP_SIGMAS = 8.0
_POINTS_PER_SIGMA = 8.0
_CHUNK = 32                       # stars rendered at once (bounds the temporaries)


@dataclass(frozen=True)
class PsfShape:
    """A PSF: its family, Gaussian-equivalent sigma (px), Moffat beta, ellipticity, angle."""

    kind: str = "gaussian"
    sigma_px: float = 1.2
    beta: float = 3.0
    ellipticity: float = 0.0
    angle_rad: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in SHAPES:
            raise ValueError(f"unknown PSF shape {self.kind!r}; expected one of "
                             f"{', '.join(SHAPES)}")
        if not self.sigma_px > 0:
            raise ValueError(f"PSF sigma must be > 0 px; got {self.sigma_px}")
        if not 0.0 <= self.ellipticity < 1.0:
            raise ValueError(f"PSF ellipticity must be in [0, 1); got {self.ellipticity}")
        if self.kind == "moffat" and not self.beta > 1.0:
            raise ValueError(f"Moffat beta must be > 1; got {self.beta}")

    @property
    def is_round_gaussian(self) -> bool:
        return self.kind == "gaussian" and self.ellipticity == 0.0

    @property
    def half_width(self) -> int:
        """Pixels either side of a star's pixel that its stamp covers."""
        stretch = math.sqrt(1.0 + self.ellipticity)
        return int(math.ceil(_STAMP_SIGMAS * self.sigma_px * stretch)) + 2

    def density(self, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        """Light per unit area (px^-2) at offsets (dx, dy) px from the centre; integrates to 1."""
        c, s = math.cos(self.angle_rad), math.sin(self.angle_rad)
        e = self.ellipticity
        u = (c * dx + s * dy) / math.sqrt(1.0 + e)
        v = (-s * dx + c * dy) / math.sqrt(1.0 - e)
        r2 = u * u + v * v
        jacobian = 1.0 / math.sqrt((1.0 + e) * (1.0 - e))
        sigma = self.sigma_px
        if self.kind == "gaussian":
            return jacobian * np.exp(-0.5 * r2 / sigma ** 2) / (2.0 * math.pi * sigma ** 2)
        fwhm = FWHM_PER_SIGMA * sigma
        if self.kind == "moffat":
            a = fwhm / (2.0 * math.sqrt(2.0 ** (1.0 / self.beta) - 1.0))
            return (jacobian * (self.beta - 1.0) / (math.pi * a * a)
                    * (1.0 + r2 / (a * a)) ** (-self.beta))
        scale = fwhm / _AIRY_FWHM_PER_L
        x = math.pi * np.sqrt(r2) / scale
        ratio = np.where(x > 1e-6, 2.0 * bessel_j1(x) / np.maximum(x, 1e-6), 1.0)
        return jacobian * math.pi / (4.0 * scale * scale) * ratio * ratio


def bessel_j1(x: np.ndarray) -> np.ndarray:
    """Bessel function J1 for x >= 0 (Abramowitz and Stegun 9.4.4 and 9.4.6; error < 1e-7)."""
    x = np.asarray(x, dtype=np.float64)
    small = np.minimum(x, 3.0) / 3.0
    t = small * small
    near = x * (0.5 + t * (-0.56249985 + t * (0.21093573 + t * (-0.03954289 + t * (
        0.00443319 + t * (-0.00031761 + t * 0.00001109))))))
    w = 3.0 / np.maximum(x, 3.0)
    f1 = (0.79788456 + w * (0.00000156 + w * (0.01659667 + w * (0.00017105 + w * (
        -0.00249511 + w * (0.00113653 - w * 0.00020033))))))
    theta = (np.maximum(x, 3.0) - 2.35619449 + w * (0.12499612 + w * (0.00005650 + w * (
        -0.00637879 + w * (0.00074348 + w * (0.00079824 - w * 0.00029166))))))
    far = f1 * np.cos(theta) / np.sqrt(np.maximum(x, 3.0))
    return np.where(x <= 3.0, near, far)


def shaped_stamps(xs: np.ndarray, ys: np.ndarray, psf: PsfShape) -> Stamps:
    """Stamps (tracker.sim.psf.Stamps) of N stars at xs, ys (N,) or along paths (N, M).

    Each pixel's value is the mean of the density at ss x ss points spread
    evenly over it; a path's stamp is the mean over its M positions.
    """
    xs, ys, x0, y0, kx, ky = stamp_box(xs, ys, psf.half_width)
    ss = max(2, int(math.ceil(_POINTS_PER_SIGMA / psf.sigma_px)))
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    cols = (np.arange(kx)[:, None] + sub[None, :]).ravel()      # (kx * ss,)
    rows = (np.arange(ky)[:, None] + sub[None, :]).ravel()
    values = np.zeros((len(xs), ky, kx))
    for start in range(0, len(xs), _CHUNK):
        part = slice(start, start + _CHUNK)
        for m in range(xs.shape[1]):
            dx = (x0[part, None] + cols[None, :]) - xs[part, m, None]   # (n, kx*ss)
            dy = (y0[part, None] + rows[None, :]) - ys[part, m, None]
            dens = psf.density(dx[:, None, :], dy[:, :, None])          # (n, ky*ss, kx*ss)
            n = dens.shape[0]
            values[part] += dens.reshape(n, ky, ss, kx, ss).mean(axis=(2, 4))
    values /= xs.shape[1]
    return Stamps(x0=x0, y0=y0, values=values)


def shape_model(psf: PsfShape, step_px: float = 0.01):
    """``psf`` as tracker.detect.crb's model: light fractions on a box and their derivatives
    by the star's position (central differences of ``step_px``), by supersampling."""

    def model(x, y, x0, y0, size):
        def box(xs, ys):
            st = shaped_stamps(xs, ys, psf)
            out = np.zeros((len(xs), size, size))
            for i in range(len(xs)):
                ky, kx = st.values[i].shape
                r0, c0 = int(st.y0[i] - y0[i]), int(st.x0[i] - x0[i])
                rows = slice(max(r0, 0), min(r0 + ky, size))
                cols = slice(max(c0, 0), min(c0 + kx, size))
                out[i, rows, cols] = st.values[i][rows.start - r0:rows.stop - r0,
                                                  cols.start - c0:cols.stop - c0]
            return out
        h = step_px
        return (box(x, y), (box(x + h, y) - box(x - h, y)) / (2 * h),
                (box(x, y + h) - box(x, y - h)) / (2 * h))
    return model
