"""The realistic sensor: background, hot pixels, cosmic rays, shot and read noise, ADC.

Order of events for one frame (all charges in electrons):

1. expected charge = star light + sky + dark current * t + hot-pixel dark
   current * t + stray-light glare;
2. Poisson draw of that charge (shot noise of light and dark current);
3. plus cosmic-ray deposits (short straight tracks, random per frame);
4. clip at the full well;
5. plus Gaussian read noise;
6. ADU = round(e / gain + bias), clipped to 0 .. 2^bits - 1.

Hot pixels are fixed per sensor: their places and dark currents come from
``SimConfig.seed`` alone, not from the frame's generator. Gain and bias are
configured for a 10-bit ADC; an n-bit ADC sees gain * 2^(10-n) e-/ADU and
bias * 2^(n-10) ADU (RAW8 keeps the top 8 of the 10 bits).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from tracker.config import SimConfig

__all__ = ["SensorScale", "sensor_scale", "hot_pixels", "cosmic_rays", "glare_field",
           "digitise"]

_HOT_PIXEL_STREAM = 0x407  # child stream of the sensor seed used for the hot-pixel map


@dataclass(frozen=True)
class SensorScale:
    """Gain, bias and full scale of an ADC of ``bit_depth`` bits."""

    bit_depth: int
    gain_e_per_adu: float
    bias_adu: float
    max_adu: int

    @property
    def dtype(self) -> type:
        return np.uint8 if self.bit_depth <= 8 else np.uint16


def sensor_scale(cfg: SimConfig, bit_depth: int) -> SensorScale:
    """The ADC of ``bit_depth`` bits (1..16) implied by the 10-bit gain and bias."""
    if not 1 <= bit_depth <= 16:
        raise ValueError(f"bit depth must be 1..16; got {bit_depth}")
    factor = 2.0 ** (bit_depth - 10)
    return SensorScale(bit_depth=bit_depth, gain_e_per_adu=cfg.gain_e_per_adu / factor,
                       bias_adu=cfg.bias_adu * factor, max_adu=(1 << bit_depth) - 1)


@lru_cache(maxsize=8)
def _hot_pixel_map(shape: tuple[int, int], seed: int, fraction: float,
                   mean_e_s: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng([seed, _HOT_PIXEL_STREAM])
    size = shape[0] * shape[1]
    count = int(round(fraction * size))
    flat = np.sort(rng.choice(size, size=count, replace=False)) if count else \
        np.zeros(0, np.int64)
    dark = rng.exponential(mean_e_s, size=count)
    flat.setflags(write=False)
    dark.setflags(write=False)
    return flat, dark


def hot_pixels(shape: tuple[int, int], cfg: SimConfig) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices and dark currents (e-/s) of the sensor's hot pixels (read-only arrays)."""
    return _hot_pixel_map(tuple(shape), cfg.seed, cfg.hot_pixel_fraction,
                          cfg.hot_pixel_dark_e_s)


def cosmic_rays(shape: tuple[int, int], count: int, mean_e: float,
                rng: np.random.Generator) -> tuple[np.ndarray, list[dict]]:
    """Deposits (float64 image, e-) of ``count`` cosmic rays, and one truth dict per hit.

    Each hit is a straight track of projected length 0..6 px (the incidence
    angle decides it) in a random direction, sampled every 0.25 px; each
    pixel it crosses gets charge in proportion to the path inside it, about
    ``mean_e`` per pixel of length, times a 0.5..1.5 random factor per hit.
    The truth dict has the track's charge centroid ``x``, ``y``, its
    ``length_px`` and ``charge_e``.
    """
    height, width = shape
    image = np.zeros(height * width)
    hits = []
    for _ in range(count):
        x_start, y_start = rng.uniform(-0.5, width - 0.5), rng.uniform(-0.5, height - 0.5)
        length, angle = rng.uniform(0.0, 6.0), rng.uniform(0.0, 2.0 * np.pi)
        steps = np.linspace(0.0, 1.0, max(2, int(np.ceil(length / 0.25)) + 1))
        xs = np.clip(x_start + steps * length * np.cos(angle), 0, width - 1)
        ys = np.clip(y_start + steps * length * np.sin(angle), 0, height - 1)
        charge = mean_e * max(length, 1.0) * rng.uniform(0.5, 1.5)
        cols, rows = np.rint(xs).astype(np.int64), np.rint(ys).astype(np.int64)
        np.add.at(image, rows * width + cols, charge / len(steps))
        hits.append({"kind": "cosmic_ray", "x": float(np.mean(cols)),
                     "y": float(np.mean(rows)), "length_px": float(length),
                     "charge_e": float(charge)})
    return image.reshape(shape), hits


def glare_field(shape: tuple[int, int], centre: tuple[float, float], radius_px: float,
                amplitude: float) -> np.ndarray:
    """amplitude * exp(-r^2 / (2 radius^2)), r = distance (px) from ``centre`` (x, y)."""
    height, width = shape
    gx = np.exp(-((np.arange(width) - centre[0]) ** 2) / (2.0 * radius_px ** 2))
    gy = np.exp(-((np.arange(height) - centre[1]) ** 2) / (2.0 * radius_px ** 2))
    return amplitude * np.outer(gy, gx)


def digitise(electrons: np.ndarray, scale: SensorScale, read_noise_e: float,
             full_well_e: float, rng: np.random.Generator | None) -> np.ndarray:
    """ADC counts of a charge image: full-well clip, read noise (if rng), gain, bias."""
    charge = np.minimum(electrons, full_well_e)
    if rng is not None and read_noise_e > 0:
        charge = charge + rng.normal(0.0, read_noise_e, size=charge.shape)
    adu = np.rint(charge / scale.gain_e_per_adu + scale.bias_adu)
    return np.clip(adu, 0, scale.max_adu).astype(scale.dtype)
