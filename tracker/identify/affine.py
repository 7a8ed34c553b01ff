"""The seed method's identification (docs/seed-method.md), kept to reproduce its table.

Given at least three reference stars with known RA/Dec, fit an affine map
pixel (x, y) -> (RA, Dec) by least squares, map every centroid, and take
the nearest catalogue star within a tolerance (0.1 deg in the seed). RA is
unwrapped around the references' mean so fields across RA = 0 work; angles
between directions use the spherical law of cosines, as the seed did.
"""

from __future__ import annotations

import numpy as np

from tracker.attitude import radec_to_vector

__all__ = ["fit_affine", "apply_affine", "nearest_star", "law_of_cosines"]


def fit_affine(xy: np.ndarray, ra: np.ndarray, dec: np.ndarray) -> tuple[np.ndarray, float]:
    """Affine coefficients (3, 2) and the RA origin (radians) from >= 3 references.

    Raises ValueError for fewer than three references or collinear ones.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 3:
        raise ValueError(f"the affine fit needs at least 3 reference stars, got {len(xy)}")
    ra0 = float(np.angle(np.mean(np.exp(1j * np.asarray(ra)))))
    ra_rel = np.angle(np.exp(1j * (np.asarray(ra) - ra0)))
    A = np.column_stack([xy, np.ones(len(xy))])
    if np.linalg.matrix_rank(A) < 3:
        raise ValueError("the reference stars are collinear; pick three that span the image")
    coef, *_ = np.linalg.lstsq(A, np.column_stack([ra_rel, dec]), rcond=None)
    return coef, ra0


def apply_affine(coef: np.ndarray, ra0: float, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(RA in [0, 2 pi), Dec) in radians of pixel positions (n, 2)."""
    xy = np.asarray(xy, dtype=np.float64)
    out = np.column_stack([xy, np.ones(len(xy))]) @ coef
    return np.mod(out[:, 0] + ra0, 2 * np.pi), out[:, 1]


def law_of_cosines(ra1, dec1, ra2, dec2) -> np.ndarray:
    """Angle (radians) between directions by the spherical law of cosines."""
    c = (np.sin(dec1) * np.sin(dec2) + np.cos(dec1) * np.cos(dec2) * np.cos(ra1 - ra2))
    return np.arccos(np.clip(c, -1.0, 1.0))


def nearest_star(vectors: np.ndarray, ra: np.ndarray, dec: np.ndarray, tolerance: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Index of the nearest catalogue vector within ``tolerance`` (radians; -1 if none).

    Returns (index per direction, angle in radians).
    """
    dirs = radec_to_vector(ra, dec)
    dots = np.clip(dirs @ np.asarray(vectors).T, -1.0, 1.0)
    best = np.argmax(dots, axis=1)
    angle = np.arccos(dots[np.arange(len(best)), best])
    return np.where(angle <= tolerance, best, -1), angle
