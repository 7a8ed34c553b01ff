"""Synthetic centroid lists for the identification tests (no image rendering).

Catalogue stars are projected through a CameraModel at a known attitude,
blurred with Gaussian centroid noise, and mixed with uniformly placed false
stars (hot pixels, planets). Fluxes follow the magnitudes with 20 % scatter,
so the brightness order is realistic but not exact.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tracker.attitude import matrix_from_quat
from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.config import CameraConfig
from tracker.detect import STAR_DTYPE

EPOCH = 2025.0
BLENDS: dict[int, set] = {}


def same_star(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per row: the HIP found is the true one or a component of the same blend."""
    pairs = zip(found, truth, strict=True)
    return np.array([f == t or f in BLENDS.get(int(t), ()) for f, t in pairs], dtype=bool)


@lru_cache(maxsize=1)
def catalogue():
    return load_catalogue(epoch_year=EPOCH, mag_limit=7.5)


def camera(focal_mm: float = 16.0, **kw) -> CameraModel:
    return CameraModel.from_config(CameraConfig(focal_length_mm=focal_mm, **kw))


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return matrix_from_quat(q / np.linalg.norm(q))


def _merge_blends(pix, mag, hip, radius_px: float = 1.5):
    """Stars closer than radius_px are one spot (a detector cannot split them).

    The spot sits at the flux-weighted mean, has the summed flux and carries
    the brightest component's HIP number; BLENDS maps it to all components.
    Input is sorted brightest first.
    """
    flux = 10 ** (-0.4 * mag)
    keep = np.ones(len(pix), dtype=bool)
    pix = pix.copy()
    for i in range(len(pix)):
        if not keep[i]:
            continue
        near = np.flatnonzero(keep & (np.hypot(*(pix - pix[i]).T) < radius_px))
        near = near[near != i]
        if len(near):
            w = flux[np.r_[i, near]]
            pix[i] = (pix[np.r_[i, near]] * w[:, None]).sum(axis=0) / w.sum()
            flux[i] = w.sum()
            keep[near] = False
            BLENDS[int(hip[i])] = {int(h) for h in hip[np.r_[i, near]]}
    return pix[keep], -2.5 * np.log10(flux[keep]), hip[keep]


def synthetic_stars(cam: CameraModel, R: np.ndarray, rng: np.random.Generator, *,
                    mag_limit: float = 6.5, noise_px: float = 0.15, n_false: int = 2,
                    keep_brightest: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(STAR_DTYPE stars, true HIP per row, 0 for false stars)."""
    cat = catalogue()
    v = cat.vectors @ R.T
    front = v[:, 2] > 0.1
    pix = cam.vector_to_pixel(v[front])
    inside = cam.in_frame(pix, margin=1.0)
    pix, mag, hip = _merge_blends(pix[inside], cat.mag[front][inside], cat.hip[front][inside])
    seen = mag <= mag_limit
    pix, mag, hip = pix[seen], mag[seen], hip[seen]
    if keep_brightest is not None:
        pix, mag, hip = pix[:keep_brightest], mag[:keep_brightest], hip[:keep_brightest]
    pix = pix + rng.normal(scale=noise_px, size=pix.shape)
    flux = 1e4 * 10 ** (-0.4 * (mag - 4.0)) * np.exp(rng.normal(scale=0.2, size=len(mag)))
    stars = np.zeros(len(pix) + n_false, dtype=STAR_DTYPE)
    stars["x"][:len(pix)] = pix[:, 0]
    stars["y"][:len(pix)] = pix[:, 1]
    stars["flux"][:len(pix)] = flux
    if n_false:
        stars["x"][len(pix):] = rng.uniform(0, cam.width - 1, n_false)
        stars["y"][len(pix):] = rng.uniform(0, cam.height - 1, n_false)
        stars["flux"][len(pix):] = rng.uniform(0.5, 2.0, n_false) * np.median(flux)
    return stars, np.concatenate([hip, np.zeros(n_false, dtype=np.int32)])
