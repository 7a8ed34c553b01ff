"""The Earth's barycentric velocity from an analytic model, for aberration.

Model, accurate to about 0.01 km/s from 1800 to 2050 (tests compare it with
IAU SOFA's ``epv00``, itself good to about 0.5 mm/s):

1. **Earth-Moon barycentre (EMB) about the Sun:** a Keplerian ellipse with
   the mean elements of E. M. Standish, "Keplerian Elements for Approximate
   Positions of the Major Planets" (JPL, Table 1, 1800-2050 AD; mean
   ecliptic and equinox of J2000), differentiated analytically.
2. **The Sun about the barycentre:** minus the mass-weighted heliocentric
   velocities of Jupiter, Saturn, Uranus and Neptune (same table; IAU 2009
   mass ratios). It reaches 0.016 km/s.
3. **The Earth about the EMB:** minus mu times the Moon's geocentric
   velocity, mu = M_moon / (M_earth + M_moon) = 0.012150 (0.0125 km/s), the
   Moon on a Keplerian orbit with its mean elements (Meeus, Astronomical
   Algorithms, ch. 47) and the 5.145 deg inclination to the ecliptic.
4. Ecliptic J2000 -> ICRS: a rotation by the obliquity 84381.406 arcsec
   (IAU 2006); the 23 mas frame bias is ignored.

The time argument is TDB, taken equal to TT (they differ by < 1.7 ms).
Velocities are km/s in ICRS axes.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["earth_barycentric_velocity_km_s", "AU_KM", "C_KM_S"]

AU_KM = 149_597_870.700
C_KM_S = 299_792.458
_J2000_JD = 2451545.0
_DAYS_PER_CENTURY = 36525.0
_OBLIQUITY_RAD = math.radians(84381.406 / 3600.0)

# Standish Table 1: a (AU), e, I, L, long. peri., long. node (deg), each
# value at J2000 and its rate per Julian century.
_ELEMENTS = {
    "emb": ((1.00000261, 0.00000562), (0.01671123, -0.00004392),
            (-0.00001531, -0.01294668), (100.46457166, 35999.37244981),
            (102.93768193, 0.32327364), (0.0, 0.0)),
    "jupiter": ((5.20288700, -0.00011607), (0.04838624, -0.00013253),
                (1.30439695, -0.00183714), (34.39644051, 3034.74612775),
                (14.72847983, 0.21252668), (100.47390909, 0.20469106)),
    "saturn": ((9.53667594, -0.00125060), (0.05386179, -0.00050991),
               (2.48599187, 0.00193609), (49.95424423, 1222.49362201),
               (92.59887831, -0.41897216), (113.66242448, -0.28867794)),
    "uranus": ((19.18916464, -0.00196176), (0.04725744, -0.00004397),
               (0.77263783, -0.00242939), (313.23810451, 428.48202785),
               (170.95427630, 0.40805281), (74.01692503, 0.04240589)),
    "neptune": ((30.06992276, 0.00026291), (0.00859048, 0.00005105),
                (1.77004347, 0.00035372), (-55.12002969, 218.45945325),
                (44.96476227, -0.32241464), (131.78422574, -0.00508664)),
}
# Sun mass / planet mass (IAU 2009 system of astronomical constants).
_SUN_OVER_PLANET = {"jupiter": 1047.348644, "saturn": 3497.9018,
                    "uranus": 22902.98, "neptune": 19412.26}
_SUN_OVER_EMB = 328900.5596
_MU_MOON = 1.0 / (1.0 + 81.300568)      # M_moon / (M_earth + M_moon)
# Moon's mean elements (Meeus ch. 47): L', M', node (deg, deg per century),
# with a = 384400 km, e = 0.0549, I = 5.145 deg.
_MOON_L = (218.3164477, 481267.88123421)
_MOON_M = (134.9633964, 477198.8675055)
_MOON_NODE = (125.0445479, -1934.1362891)
_MOON_A_KM, _MOON_E, _MOON_I_DEG = 384400.0, 0.0549, 5.145


def _kepler_velocity(a: float, e: float, inc: float, mean_anomaly: float, peri_arg: float,
                     node: float, n: float) -> np.ndarray:
    """Velocity on a Kepler ellipse (units of a per unit of n's time), ecliptic axes.

    Angles in radians; ``n`` the mean motion (rad per time unit).
    """
    E = mean_anomaly
    for _ in range(8):      # Newton on E - e sin E = M; e < 0.06 converges in 3
        E -= (E - e * math.sin(E) - mean_anomaly) / (1.0 - e * math.cos(E))
    e_dot = n / (1.0 - e * math.cos(E))
    vx = -a * math.sin(E) * e_dot
    vy = a * math.sqrt(1.0 - e * e) * math.cos(E) * e_dot
    cw, sw = math.cos(peri_arg), math.sin(peri_arg)
    co, so = math.cos(node), math.sin(node)
    ci, si = math.cos(inc), math.sin(inc)
    return np.array([
        (cw * co - sw * so * ci) * vx + (-sw * co - cw * so * ci) * vy,
        (cw * so + sw * co * ci) * vx + (-sw * so + cw * co * ci) * vy,
        (sw * si) * vx + (cw * si) * vy,
    ])


def _planet_velocity_au_day(name: str, T: float) -> np.ndarray:
    """Heliocentric velocity (AU/day, ecliptic J2000) from Standish's elements."""
    (a0, a1), (e0, e1), (i0, i1), (L0, L1), (w0, w1), (o0, o1) = _ELEMENTS[name]
    a, e = a0 + a1 * T, e0 + e1 * T
    inc, L = math.radians(i0 + i1 * T), math.radians(L0 + L1 * T)
    peri, node = math.radians(w0 + w1 * T), math.radians(o0 + o1 * T)
    n = math.radians(L1) / _DAYS_PER_CENTURY
    return _kepler_velocity(a, e, inc, L - peri, peri - node, node, n)


def _moon_velocity_km_day(T: float) -> np.ndarray:
    """The Moon's geocentric velocity (km/day, ecliptic axes), mean Keplerian orbit."""
    L = math.radians(_MOON_L[0] + _MOON_L[1] * T)
    M = math.radians(_MOON_M[0] + _MOON_M[1] * T)
    node = math.radians(_MOON_NODE[0] + _MOON_NODE[1] * T)
    n = math.radians(_MOON_M[1]) / _DAYS_PER_CENTURY
    peri = L - M
    return _kepler_velocity(_MOON_A_KM, _MOON_E, math.radians(_MOON_I_DEG), M, peri - node,
                            node, n)


def earth_barycentric_velocity_km_s(jd_tt: float) -> np.ndarray:
    """The Earth's (geocentre's) velocity relative to the solar-system barycentre.

    ``jd_tt``: Julian date, TT (TDB). Returns km/s in ICRS axes, shape (3,).
    """
    T = (jd_tt - _J2000_JD) / _DAYS_PER_CENTURY
    emb = _planet_velocity_au_day("emb", T)
    total_mass = 1.0 + 1.0 / _SUN_OVER_EMB + sum(1.0 / r for r in _SUN_OVER_PLANET.values())
    sun = -sum(_planet_velocity_au_day(p, T) / r for p, r in _SUN_OVER_PLANET.items())
    sun = sun / total_mass
    v_ecl = (emb + sun) * (AU_KM / 86400.0) - _MU_MOON * _moon_velocity_km_day(T) / 86400.0
    c, s = math.cos(_OBLIQUITY_RAD), math.sin(_OBLIQUITY_RAD)
    return np.array([v_ecl[0], c * v_ecl[1] - s * v_ecl[2], s * v_ecl[1] + c * v_ecl[2]])
