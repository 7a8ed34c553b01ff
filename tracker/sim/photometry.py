"""Photo-electrons from magnitudes: stars and sky.

A star of Hipparcos magnitude Hp delivers, in one exposure,

    N_e = Z * 10^(-0.4 Hp) * A * T * QE * t

photo-electrons, with Z the photon flux of a Hp = 0 star across the band
(``zero_point_photons``, photon m^-2 s^-1), A = pi (D/2)^2 the entrance
pupil (D = focal length / f-number), T the optics transmission, QE the
band-averaged quantum efficiency and t the exposure.

Z = 4.0e10: the V = 0 flux density 3.64e-11 W m^-2 nm^-1 at 550 nm is
1.0e8 photon m^-2 s^-1 nm^-1 (divide by hc/lambda = 3.61e-19 J), times
about 400 nm effective width of the broad Hp passband (340-890 nm).
Hp and V agree to a few tenths of a magnitude for most stars, which is
the accuracy of this model. For a 16 mm f/2.0 lens (A = 5.0e-5 m^2),
T = 0.85, QE = 0.45 and 100 ms, a Hp = 6 star gives about 310 e-.

The sky is a surface brightness (mag per arcsec^2) through the same
chain, times the solid angle of one pixel.
"""

from __future__ import annotations

import numpy as np

from tracker.config import SimConfig

__all__ = ["star_electrons", "sky_electrons_per_pixel", "aperture_area_m2"]

_ARCSEC_PER_RAD = 180.0 * 3600.0 / np.pi


def aperture_area_m2(focal_length_mm: float, f_number: float) -> float:
    """Entrance-pupil area (m^2) of a lens of the given focal length (mm) and f-number."""
    diameter_m = focal_length_mm / f_number / 1000.0
    return float(np.pi * diameter_m ** 2 / 4.0)


def _electrons_per_zero_mag(focal_length_mm: float, cfg: SimConfig) -> float:
    """Photo-electrons one exposure collects from a Hp = 0 source."""
    return (cfg.zero_point_photons * aperture_area_m2(focal_length_mm, cfg.f_number)
            * cfg.transmission * cfg.quantum_efficiency * cfg.exposure_ms / 1000.0)


def star_electrons(mag: np.ndarray, focal_length_mm: float, cfg: SimConfig) -> np.ndarray:
    """Photo-electrons (float64) in one exposure for stars of magnitude ``mag`` (Hp)."""
    mag = np.asarray(mag, dtype=np.float64)
    return _electrons_per_zero_mag(focal_length_mm, cfg) * 10.0 ** (-0.4 * mag)


def sky_electrons_per_pixel(focal_length_mm: float, pixel_size_um: float,
                            cfg: SimConfig) -> float:
    """Sky photo-electrons per pixel per exposure from ``cfg.sky_mag_arcsec2``."""
    pixel_arcsec = pixel_size_um / (focal_length_mm * 1000.0) * _ARCSEC_PER_RAD
    return float(_electrons_per_zero_mag(focal_length_mm, cfg)
                 * 10.0 ** (-0.4 * cfg.sky_mag_arcsec2) * pixel_arcsec ** 2)
