"""Frames of a grid of spots (stars and impostors) on a 10-bit sensor, for the shape tests.

A 512 x 512 frame holds a 15 x 15 grid of spots 32 px apart; the sky is 60 e- a
pixel at 1.35 e-/ADU with 2 ADU of read noise.
"""

from __future__ import annotations

import numpy as np

from tracker.normal import pixel_fractions

SHAPE = (512, 512)
GAIN_E_PER_ADU = 1.35
READ_NOISE_ADU = 2.0
SKY_E = 60.0


def spot(flux: float, sigma_px: float, radius: int, phase: tuple[float, float]) -> np.ndarray:
    """A pixel-integrated Gaussian of ``flux`` in a (2r+1)^2 box, centred ``phase`` px off."""
    edges = np.arange(-radius, radius + 2, dtype=np.float64) - 0.5
    fx, _ = pixel_fractions(edges - phase[0], sigma_px)
    fy, _ = pixel_fractions(edges - phase[1], sigma_px)
    return flux * np.outer(fy, fx)


def grid_centres() -> tuple[np.ndarray, np.ndarray]:
    """(x, y) of the grid's pixel centres, px, raveled."""
    gy, gx = np.meshgrid(np.arange(24, 490, 32), np.arange(24, 490, 32), indexing="ij")
    return gx.ravel(), gy.ravel()


def sensor_frame(light_e: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The 10-bit frame (uint16) of ``light_e`` (e- a pixel, sky included): shot noise, gain,
    read noise, rounding and clipping."""
    image = rng.poisson(light_e) / GAIN_E_PER_ADU + rng.normal(0.0, READ_NOISE_ADU,
                                                               light_e.shape)
    return np.clip(np.rint(image), 0, 1023).astype(np.uint16)


def found(stars: np.ndarray, xs: np.ndarray, ys: np.ndarray, star: np.ndarray) -> np.ndarray:
    """(stars found, impostors found): spots of (``xs``, ``ys``) with a detection of
    ``stars`` within 2 px, ``star`` telling which spots are stars."""
    d = np.hypot(xs[:, None] - stars["x"][None], ys[:, None] - stars["y"][None])
    near = d.min(axis=1) < 2.0 if len(stars) else np.zeros(len(xs), bool)
    return np.array([np.count_nonzero(near & star), np.count_nonzero(near & ~star)])
