"""Data sets of ``tracker bench detect``: simulated frames with truth (tracker.sim).

* ``seed/<model>/<snr> dB``: the seed method's four noise models (8-bit,
  0..1 scale) at image SNRs across -5..+3 dB, over random attitudes of the
  configured camera. Detectable: matched-filter SNR >= 7 (the issue's
  criterion for these sets).
* ``realistic/16mm/100ms``, ``realistic/8mm/100ms``, ``realistic/16mm/400ms``:
  10-bit OV2311 frames under the realistic sensor model with glare
  (``GLARE_E`` peak), the sensor's hot pixels and a cosmic-ray rate raised
  to ``COSMIC_RATE`` hits/cm^2/s (about 6 per 100 ms frame; the default LEO
  rate gives 0.1). Detectable: peak SNR >= 5.

Each set also carries the pixel-noise model the Cramer-Rao bound needs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tracker.config import Config
from tracker.sim import SimFrame, random_attitude, render_sky
from tracker.sim.seednoise import QUANT_POWER, SEED_MODELS, noise_power

__all__ = ["DataSet", "build_sets", "SNR_LEVELS_DB", "QUICK_SNR_LEVELS_DB"]

SNR_LEVELS_DB = (-5.0, -3.0, -1.0, 1.0, 3.0)
QUICK_SNR_LEVELS_DB = (-5.0, -1.0, 3.0)
GLARE_E = 400.0
COSMIC_RATE = 300.0
# (focal length mm, exposure ms): the sim's 100 ms frames hold few stars above peak
# SNR 20, so a 400 ms 16 mm set tests the centroid near the bound.
REALISTIC = ((16.0, 100.0), (8.0, 100.0), (16.0, 400.0))


@dataclass
class DataSet:
    """Frames of one kind with their truth and the noise model of the bound."""

    name: str
    group: str                       # "seed/<model>" or "realistic"
    frames: list[SimFrame]
    bit_depth: int
    criterion: str                   # "peak_snr >= 5" or "mf_snr >= 7"
    variance: Callable[[SimFrame, int], Callable[[np.ndarray], np.ndarray]]
    flux_unit: Callable[[SimFrame], float]   # divide flux_e by this for the bound's unit
    saturation: Callable[[SimFrame, int], float]  # star light that clips a pixel, bound's unit
    # detect.* settings a user would choose for this kind of frame (our methods only)
    detect_settings: dict = dataclasses.field(default_factory=dict)


def _sensor_variance(sim) -> Callable:
    """Shot + sky + dark + glare at the star + read + rounding, in electrons."""

    def for_star(frame: SimFrame, i: int):
        noise = frame.truth["noise"]
        bg = noise["sky_e"] + sim.dark_current_e_s * sim.exposure_ms / 1000.0
        if "glare_centre" in noise:
            star = frame.stars[i]
            gx, gy = noise["glare_centre"]
            r2 = (star["x"] - gx) ** 2 + (star["y"] - gy) ** 2
            bg += sim.glare_e * float(np.exp(-r2 / (2.0 * sim.glare_radius_px ** 2)))
        floor = bg + sim.read_noise_e ** 2 + noise["gain_e_per_adu"] ** 2 / 12.0
        return lambda s: s + floor
    return for_star


def _sensor_saturation(sim, bit_depth: int) -> Callable:
    """Star light (e-) that takes a pixel to the ADC's full scale, over its background."""

    def for_star(frame: SimFrame, i: int) -> float:
        noise = frame.truth["noise"]
        full = ((1 << bit_depth) - 1 - noise["bias_adu"]) * noise["gain_e_per_adu"]
        bg = noise["sky_e"] + sim.dark_current_e_s * sim.exposure_ms / 1000.0
        return min(full, sim.full_well_e) - bg
    return for_star


def _seed_variance(model: str) -> Callable:
    """The seed model's expected noise power for the star's own light (0..1 scale).

    Floored at the 8-bit rounding noise LSB^2/12, as the simulator's per-star
    SNR is: a deterministic rounding error is not a variance, and without
    the floor a pixel that happens to sit on the 8-bit grid would carry
    infinite information.
    """

    def for_star(frame: SimFrame, i: int):
        param = frame.truth["noise"]["param"]
        if model == "glare":  # the glare is smooth and known to a background estimate;
            # what is left is 8-bit rounding, modelled as uniform noise
            return lambda s: np.full(np.shape(s), QUANT_POWER)
        return lambda s: np.maximum(noise_power(model, param, np.clip(s, 0.0, 1.0)),
                                    QUANT_POWER)
    return for_star


# Speckle multiplies the light by noise: the user of such a camera says so.
MODEL_SETTINGS = {"speckle": {"centroid_noise": "multiplicative"}}


def build_sets(cfg: Config, catalogue, frames: int, realistic_frames: int, quick: bool,
               rng: np.random.Generator) -> list[DataSet]:
    """All data sets: seed models x SNR levels, then the realistic lenses."""
    sets = []
    levels = QUICK_SNR_LEVELS_DB if quick else SNR_LEVELS_DB
    for model in SEED_MODELS:
        for snr in levels:
            shots = [render_sky(cfg.camera, catalogue, random_attitude(rng), cfg.sim, rng,
                                noise_model=model, snr_db=snr) for _ in range(frames)]
            sets.append(DataSet(f"seed/{model}/{snr:+.0f} dB", f"seed/{model}", shots, 8,
                                "mf_snr >= 7", _seed_variance(model),
                                lambda f: f.truth["noise"]["full_scale_e"],
                                lambda f, i: f.truth["noise"]["full_scale_e"],
                                MODEL_SETTINGS.get(model, {})))
    for lens, exposure in REALISTIC:
        sim = dataclasses.replace(cfg.sim, glare_e=GLARE_E, cosmic_ray_rate_cm2_s=COSMIC_RATE,
                                  noise_model="realistic", exposure_ms=exposure)
        camera = dataclasses.replace(cfg.camera, focal_length_mm=lens)
        shots = [render_sky(camera, catalogue, random_attitude(rng), sim, rng)
                 for _ in range(realistic_frames)]
        sets.append(DataSet(f"realistic/{lens:.0f}mm/{exposure:.0f}ms", "realistic", shots,
                            camera.bit_depth, "peak_snr >= 5", _sensor_variance(sim),
                            lambda f: 1.0, _sensor_saturation(sim, camera.bit_depth)))
    return sets
