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
from tracker.detect.multiplicative import interval_scores
from tracker.sim import SimFrame, random_attitude, render_sky
from tracker.sim.seednoise import QUANT_POWER, SEED_MODELS, noise_power

__all__ = ["DataSet", "bound_variance", "build_sets", "speckle_information", "SNR_LEVELS_DB",
           "QUICK_SNR_LEVELS_DB"]

_LEVELS_8BIT = 255.0

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


def speckle_information(param: float, clean: np.ndarray) -> np.ndarray:
    """Fisher information of a speckled 8-bit pixel about its clean value (0..1 scale).

    Exact for the seed's speckle as the simulator delivers it: the value is
    round(255 clip(s (1 + sqrt(param) Z), 0, 1)), so over the 256 possible
    values I(s) = sum_k P_k (d log P_k / ds)^2, with P_k from
    tracker.detect.multiplicative.interval_scores (rounding and both clips
    included). A clean value at full scale, clipped before the noise,
    carries none.
    """
    s = np.asarray(clean, np.float64)
    mu = np.clip(s * _LEVELS_8BIT, 1e-9, None)[..., None]
    k = np.arange(_LEVELS_8BIT + 1.0)
    lo = np.where(k <= 0, -np.inf, k - 0.5)
    hi = np.where(k >= _LEVELS_8BIT, np.inf, k + 0.5)
    log_p, by_mu, _ = interval_scores(lo, hi, mu, np.sqrt(param))
    with np.errstate(invalid="ignore", over="ignore"):
        terms = np.where(log_p > -700.0, np.exp(log_p) * by_mu ** 2, 0.0)  # P = 0: none
    info = np.sum(terms, axis=-1) * _LEVELS_8BIT ** 2
    return np.where(s < 1.0, info, 0.0)


def bound_variance(model: str, param: float) -> Callable[[np.ndarray], np.ndarray]:
    """A seed model's pixel noise as the bound (tracker.detect.crb) takes it, 0..1 scale.

    Maps the star's light per pixel to: for speckle, the reciprocal of the
    exact Fisher information (speckle_information), so its bound is the
    true Cramer-Rao bound of the speckled, rounded, clipped pixel; for the
    others, the expected noise power floored at the 8-bit rounding noise
    LSB^2/12, as the simulator's per-star SNR is (a deterministic rounding
    error is not a variance, and without the floor a pixel that happens to
    sit on the 8-bit grid would carry infinite information). For those
    models that is the bound of Gaussian noise of the same power, not an
    exact bound. ``param``: the model's parameter (tracker.sim.seednoise).
    """
    if model == "speckle":
        return lambda s: 1.0 / np.maximum(speckle_information(param, s), 1e-300)
    if model == "glare":  # the glare is smooth and known to a background estimate;
        # what is left is 8-bit rounding, modelled as uniform noise
        return lambda s: np.full(np.shape(s), QUANT_POWER)
    return lambda s: np.maximum(noise_power(model, param, np.clip(s, 0.0, 1.0)), QUANT_POWER)


def _seed_variance(model: str) -> Callable:
    """bound_variance of each frame's own parameter."""
    return lambda frame, i: bound_variance(model, frame.truth["noise"]["param"])


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
