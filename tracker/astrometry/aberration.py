"""Stellar aberration: where a moving observer sees the catalogue's stars.

A star's astrometric direction ``u`` (ICRS, barycentric, at the epoch:
tracker.catalogue) is seen by an observer moving with velocity ``v`` (ICRS
axes, relative to the barycentre) in the apparent direction (special
relativity; e.g. Klioner 2003, AJ 125, 1580, eq. 27 without light
deflection)::

    u' = (u / gamma + beta + (u . beta) beta / (1 + 1/gamma)) / (1 + u . beta)

with beta = v / c and gamma = 1 / sqrt(1 - beta^2). The displacement is
toward the velocity, |beta| sin(angle) radians to first order: up to 20.5
arcsec for the Earth's orbital 30 km/s, plus up to 5 arcsec for a low Earth
orbit's 7.5 km/s. The inverse is the same formula with -beta.

The observer's barycentric velocity is the Earth's
(tracker.astrometry.earth, from the time) plus the observer's velocity
relative to the geocentre, which the flight computer supplies (ICRS axes,
km/s); their relativistic composition differs from the sum by < 1e-9 and
is not applied.

Left out, each below 0.02 arcsec away from the Sun: gravitational light
deflection by the Sun (4 mas at 90 deg from it, 1.75 arcsec at its limb),
annual parallax (< 0.77 arcsec, Proxima Centauri alone above 0.4), and
the second-order terms beyond the formula above (it is exact).
"""

from __future__ import annotations

import numpy as np

from tracker.astrometry.earth import C_KM_S, earth_barycentric_velocity_km_s
from tracker.astrometry.timescale import jd_tt_from_tai_ns

__all__ = ["aberrate", "observer_beta"]


def observer_beta(t_tai_ns: int, geocentric_velocity_km_s=None) -> np.ndarray:
    """The observer's barycentric velocity over c, ICRS axes, shape (3,).

    ``t_tai_ns``: TAI ns since 1970 (tracker.astrometry.timescale);
    ``geocentric_velocity_km_s``: the observer's velocity relative to the
    Earth's centre (ICRS axes, km/s), None for an observer at rest there.
    """
    jd1, jd2 = jd_tt_from_tai_ns(t_tai_ns)
    v = earth_barycentric_velocity_km_s(jd1 + jd2)
    if geocentric_velocity_km_s is not None:
        v = v + np.asarray(geocentric_velocity_km_s, dtype=np.float64)
    return v / C_KM_S


def aberrate(u: np.ndarray, beta: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Apparent directions (..., 3) of astrometric unit vectors ``u`` for velocity ``beta``.

    ``beta`` is v / c (3,), ICRS axes; pass ``-beta`` to go from apparent
    back to astrometric. ``out`` may be ``u`` itself (in place).
    """
    u = np.asarray(u, dtype=np.float64)
    beta = np.asarray(beta, dtype=np.float64)
    b2 = float(beta @ beta)
    if b2 >= 1.0:
        raise ValueError(f"observer speed {np.sqrt(b2):.3g} c is not below light's")
    inv_gamma = np.sqrt(1.0 - b2)
    ub = u @ beta
    result = u * inv_gamma if out is None else np.multiply(u, inv_gamma, out=out)
    result += beta * (1.0 + ub / (1.0 + inv_gamma))[..., None]
    result /= (1.0 + ub)[..., None]
    return result
