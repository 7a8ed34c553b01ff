"""What a star's pixel-scale roughness reads, and how far its noise spreads it.

The windowed centroider (tracker.detect.windowed) reports a spot's
roughness R = (sum (L S)^2 - 20 m noise^2) / (sum S^2 - k noise^2) over its
window of k pixels, L the 4-neighbour Laplacian (on the m inner pixels) and
S the background-subtracted light: the Laplacian's energy over the light's,
the background's white noise taken out of both. The optics pass nothing
finer than the PSF, so no image of the sky reads rougher than a point
source, whose R (noise-free, px^-4) is r0 = P'Q0 P / P'P with P the
pixel-integrated PSF of unit flux and Q0 = L'L; a cluster of cosmic-ray
hits, made on the sensor, does.

A faint star is measured with noise, and not only the background's: its
own shot noise (g S per pixel, g ADU^2 per ADU of light: tracker.detect.
significance's convention) is not taken out, and adds g F sum_p P_p Q0_pp
(about 20 g F) to the numerator and g F to the denominator for a star of
flux F. Its expected R is therefore

    E[R] = (r0 e F^2 + d g F) / (e F^2 + g F),   e = P'P, d = sum_p P_p Q0_pp,

which for a star of SNR 35 on a 10-bit frame is three times r0. To first
order the numerator less r0 times the denominator is the star's light
through Q = Q0 - r0 I plus the noise: a linear part 2 (Q S)'n and a
quadratic part n'Q n, for pixel noise n of variance v_p = noise^2 + g S_p.
Their variances over (e F^2)^2 give R's spread:

    var R = [4 F^2 (noise^2 a + g F b)
             + 2 (noise^4 q0 + 2 noise^2 g F q1 + g^2 F^2 q2)] / (e F^2)^2,

with a = |Q P|^2, b = sum_p P_p (Q P)_p^2, q0 = sum Q^2,
q1 = sum_p P_p (Q Q)_pp and q2 = sum_pq P_p Q_pq^2 P_q, constants of the
PSF (averaged over a star centred on a pixel's centre, edge and corner).
At SNR 35 under a 1.3 px PSF that spread is a third of E[R]: a spot is
rougher than a star only by a margin its own noise cannot make.
"""

from __future__ import annotations

from dataclasses import astuple, dataclass

import numpy as np

from tracker.detect.significance import SHOT_ADU
from tracker.normal import pixel_fractions

__all__ = ["StarRoughness"]

_PHASES = ((0.0, 0.0), (0.5, 0.0), (0.5, 0.5))   # a pixel's centre, edge and corner


def _laplacian_energy(side: int) -> np.ndarray:
    """Q0 = L'L for the 4-neighbour Laplacian on the inner pixels of a side x side window."""
    inner = side - 2
    lap = np.zeros((inner, inner, side, side))
    for i in range(inner):
        for j in range(inner):
            lap[i, j, i + 1, j + 1] = 4.0
            lap[i, j, i, j + 1] = lap[i, j, i + 2, j + 1] = -1.0
            lap[i, j, i + 1, j] = lap[i, j, i + 1, j + 2] = -1.0
    lap = lap.reshape(inner * inner, side * side)
    return lap.T @ lap


@dataclass(frozen=True)
class StarRoughness:
    """The constants of a PSF for the roughness of a star under it (module docstring).

    ``r0``: a noise-free point source's roughness, px^-4; ``e``, ``d``,
    ``a``, ``b``, ``q0``, ``q1``, ``q2``: as in the module docstring.
    """

    r0: float
    e: float
    d: float
    a: float
    b: float
    q0: float
    q1: float
    q2: float

    @classmethod
    def of(cls, radius: int, sigma_px: float) -> StarRoughness:
        """The constants for windows of radius ``radius`` px and an optical PSF sigma
        ``sigma_px`` (pixel-integrated Gaussian), averaged over ``_PHASES``."""
        side = 2 * int(radius) + 1
        q_zero = _laplacian_energy(side)
        edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
        rows = []
        for phase in _PHASES:
            fx, _ = pixel_fractions(edges - phase[0], sigma_px)
            fy, _ = pixel_fractions(edges - phase[1], sigma_px)
            p = np.outer(fy, fx).ravel()
            e = float(p @ p)
            r0 = float(p @ q_zero @ p) / e
            q = q_zero - r0 * np.eye(side * side)
            qp = q @ p
            q2 = q * q
            rows.append((r0, e, float(p @ np.diag(q_zero)), float(qp @ qp),
                         float(p @ (qp * qp)), float(q2.sum()), float(p @ q2.sum(axis=1)),
                         float(p @ q2 @ p)))
        return cls(*np.mean(rows, axis=0).tolist())

    @classmethod
    def from_values(cls, values) -> StarRoughness:
        """From the floats :meth:`values` gave (a table row)."""
        return cls(*(float(x) for x in values))

    def values(self) -> tuple[float, ...]:
        """The constants as a tuple of floats, in field order."""
        return astuple(self)

    def expected(self, flux: np.ndarray, shot_adu: float = SHOT_ADU) -> np.ndarray:
        """E[R] of stars of ``flux`` ADU (floored at one ADU), px^-4."""
        f = np.maximum(np.asarray(flux, np.float64), 1.0)
        light = self.e * f * f
        return (self.r0 * light + self.d * shot_adu * f) / (light + shot_adu * f)

    def spread(self, flux: np.ndarray, noise: np.ndarray,
               shot_adu: float = SHOT_ADU) -> np.ndarray:
        """The standard deviation of R for stars of ``flux`` ADU (floored at one ADU)
        on a background of pixel noise ``noise`` ADU, px^-4."""
        f = np.maximum(np.asarray(flux, np.float64), 1.0)
        var = np.square(np.asarray(noise, np.float64))
        shot = shot_adu * f
        linear = 4.0 * f * f * (var * self.a + shot * self.b)
        quadratic = 2.0 * (var * var * self.q0 + 2.0 * var * shot * self.q1
                           + shot * shot * self.q2)
        return np.sqrt(linear + quadratic) / (self.e * f * f)
