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
# the 4-neighbour Laplacian's taps: (row offset, column offset, weight)
_TAPS = ((0, 0, 4.0), (-1, 0, -1.0), (1, 0, -1.0), (0, -1, -1.0), (0, 1, -1.0))


def _shifted(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``a`` moved by (dy, dx) over its last two axes: out[..., y, x] = a[..., y - dy, x - dx],
    zero where that is outside."""
    out = np.zeros_like(a)
    h, w = a.shape[-2:]
    out[..., max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        a[..., max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
    return out


def _laplacian_energy(side: int) -> dict[tuple[int, int], np.ndarray]:
    """Q0 = L'L for the 4-neighbour Laplacian on the inner pixels of a side x side window,
    by its diagonals: {(dy, dx): M} with M[j] = Q0[j, j + (dy, dx)] (side x side, pixel j
    in row-major window order; the 13 offsets of the stencil). Q0 has no other non-zero
    entries, so its products with the PSF take a few small array operations, not the
    dense (side^2)^2 matrix."""
    inner = np.zeros((side, side))
    inner[1:-1, 1:-1] = 1.0
    diagonals: dict[tuple[int, int], np.ndarray] = {}
    for ay, ax, wa in _TAPS:
        centre = _shifted(inner, ay, ax)      # 1 where pixel j - a is an inner centre
        for by, bx, wb in _TAPS:
            key = (by - ay, bx - ax)
            diagonals[key] = diagonals.get(key, 0.0) + wa * wb * centre
    return diagonals


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
        diagonals = _laplacian_energy(side)
        q_diag = diagonals[(0, 0)]
        # sum_k Q0_jk^2 (each row's), and the whole matrix's
        row_square = sum(m * m for m in diagonals.values())
        edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
        # the three phases' pixel-integrated PSFs, (3, side, side)
        p = np.stack([np.outer(pixel_fractions(edges - py, sigma_px)[0],
                               pixel_fractions(edges - px, sigma_px)[0])
                      for px, py in _PHASES])
        axes = (1, 2)
        e = np.sum(p * p, axis=axes)
        # (Q0 P)_j and P' (Q0 o Q0) P from the diagonals, P moved by each offset
        q0p = np.zeros_like(p)
        square_form = np.zeros(len(_PHASES))
        for (dy, dx), m in diagonals.items():
            ahead = _shifted(p, -dy, -dx)          # P[j + (dy, dx)]
            q0p += m * ahead
            square_form += np.sum(m * m * p * ahead, axis=axes)
        r0 = np.sum(p * q0p, axis=axes) / e
        qp = q0p - r0[:, None, None] * p           # Q P, Q = Q0 - r0 I
        # sums of Q's squares from Q0's: (Q0 - r0 I)^2 entrywise
        q_row = row_square - 2.0 * r0[:, None, None] * q_diag + (r0 * r0)[:, None, None]
        rows = np.stack([
            r0, e, np.sum(p * q_diag, axis=axes), np.sum(qp * qp, axis=axes),
            np.sum(p * qp * qp, axis=axes),
            np.sum(row_square) - 2.0 * r0 * np.sum(q_diag) + r0 * r0 * side * side,
            np.sum(p * q_row, axis=axes),
            square_form - 2.0 * r0 * np.sum(p * p * q_diag, axis=axes) + r0 * r0 * e],
            axis=1)
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
