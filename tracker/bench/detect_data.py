"""Data sets of ``tracker bench detect``: simulated frames with truth (tracker.sim).

Each set carries the pixel-noise model the Cramer-Rao bound needs. The
detector is never told the PSF: its ``detect.psf_sigma_px`` stays at the
default 1.2 px while the frames' PSFs vary.

Tuned on (the conditions the detector was developed against):

* ``seed/<model>/<snr> dB``: the seed method's four noise models (8-bit,
  0..1 scale) at image SNRs across -5..+3 dB set through each model's
  parameter, over random attitudes. Detectable: matched-filter SNR >= 7,
  of what the delivered frame shows of the star (tracker.sim.frame: the
  change of its pixels' mean against their noise; clipped noise passes on
  only part of a faint star's light).
* ``seed-written/<model>/...``: the same models at the parameters the
  seed method wrote down (Gaussian+Poisson variance 0.15, salt and pepper
  at density 0.05, speckle variance 0.15, glare of amplitude 1 and radius
  200-600 px), on a black sky (``dark``) and at -5..+3 dB reached through
  the sky level under the stars (``sim.snr_sets: sky``); the stars are
  brightened (``sim.seed_star_gain``) until a frame holds some that such
  noise leaves detectable. Speckle's SNR does not depend on the sky (about
  +8 dB): it has only its ``dark`` set.
* ``realistic/16mm/100ms``, ``realistic/8mm/100ms``, ``realistic/16mm/400ms``:
  10-bit OV2311 frames under the realistic sensor model with glare
  (``GLARE_E`` peak), the sensor's hot pixels and a cosmic-ray rate raised
  to ``COSMIC_RATE``, each frame with its own PSF: sigma log-uniform in
  0.6-3 px, Gaussian or Moffat (beta 2.5-5), ellipticity up to 0.12.
  Detectable: peak SNR >= 5.
* ``glare/16mm/100ms``: the Sun's glare from just outside the frame,
  saturating a band along one edge, and a particle event of 50-150 tracks
  (tracker.sim.scene).
* ``lunar/16mm`` and ``lunar/8mm``: on the lunar surface: a sunlit
  cratered horizon, often the Earth, the Sun's glare, lens ghosts, a
  particle event (tracker.sim.scene.lunar_scene). Their frames are also
  solved (tracker.bench.detect).

Held out (never used to tune the detector: its scores were read, its frames
never examined):

* ``held-out/airy``: Airy PSFs (sigma 0.8-2.5 px, ellipticity up to 0.15)
  on frames whose sensor differs at random from the default: RAW8 or
  RAW10, read noise 1.5-4 e-, gain 0.7-1.5 x, sky 19.5-22 mag/arcsec^2,
  hot pixels 0-0.05 %, glare 0-1500 e-, 16 or 8 mm.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tracker.camera import CameraModel
from tracker.config import Config
from tracker.detect.multiplicative import interval_scores
from tracker.sim import SimFrame, random_attitude, render_sky
from tracker.sim.psf_shapes import PsfShape
from tracker.sim.scene import glare_scene, lunar_scene
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
PSF_SIGMA_PX = (0.6, 3.0)        # realistic sets: the range PSFs are drawn from
HELD_OUT_SIGMA_PX = (0.8, 2.5)
# seed models at their written parameters: star brightness that leaves some detectable
WRITTEN_GAIN = {"gaussian_poisson": 50.0, "salt_pepper": 10.0, "speckle": 1.0, "glare": 1.0}


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
    camera: object = None            # CameraConfig of scene sets that are solved too
    held_out: bool = False


def _sensor_variance(frame: SimFrame, i: int):
    """Shot noise of the star's own light plus the noise power of its pixel's background
    (sky, dark current, glare and scene light, read noise, rounding), in electrons."""
    floor = float(frame.stars["bg_power"][i])
    return lambda s: s + floor


def _sensor_saturation(bit_depth: int) -> Callable:
    """Star light (e-) that takes a pixel to the ADC's full scale, over its background."""

    def for_star(frame: SimFrame, i: int) -> float:
        noise = frame.truth["noise"]
        full = ((1 << bit_depth) - 1 - noise["bias_adu"]) * noise["gain_e_per_adu"]
        return min(full, noise["full_well_e"]) - float(frame.stars["bg_power"][i])
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


def _random_psf(rng: np.random.Generator, sigma_px: tuple[float, float],
                kinds: tuple[str, ...], max_ellipticity: float) -> PsfShape:
    sigma = float(np.exp(rng.uniform(np.log(sigma_px[0]), np.log(sigma_px[1]))))
    return PsfShape(str(rng.choice(kinds)), sigma, beta=float(rng.uniform(2.5, 5.0)),
                    ellipticity=float(rng.uniform(0.0, max_ellipticity)),
                    angle_rad=float(rng.uniform(0.0, np.pi)))


def _seed_set(name, group, model, shots) -> DataSet:
    return DataSet(name, group, shots, 8, "mf_snr >= 7", _seed_variance(model),
                   lambda f: f.truth["noise"]["full_scale_e"],
                   lambda f, i: f.truth["noise"]["full_scale_e"],
                   MODEL_SETTINGS.get(model, {}))


def _sensor_set(name, group, shots, camera, solved=False, held_out=False) -> DataSet:
    return DataSet(name, group, shots, camera.bit_depth, "peak_snr >= 5", _sensor_variance,
                   lambda f: 1.0, _sensor_saturation(camera.bit_depth),
                   camera=camera if solved else None, held_out=held_out)


def build_sets(cfg: Config, catalogue, frames: int, realistic_frames: int, quick: bool,
               rng: np.random.Generator, scene_frames: int | None = None) -> list[DataSet]:
    """All data sets (module docstring); ``scene_frames`` per glare and lunar set."""
    sets = []
    levels = QUICK_SNR_LEVELS_DB if quick else SNR_LEVELS_DB
    for model in SEED_MODELS:
        for snr in levels:
            shots = [render_sky(cfg.camera, catalogue, random_attitude(rng), cfg.sim, rng,
                                noise_model=model, snr_db=snr) for _ in range(frames)]
            sets.append(_seed_set(f"seed/{model}/{snr:+.0f} dB", f"seed/{model}", model, shots))
    for model in SEED_MODELS:
        written = dataclasses.replace(cfg.sim, seed_star_gain=WRITTEN_GAIN[model])
        variants = [("dark", None)] + ([] if model == "speckle" else
                                       [(f"{snr:+.0f} dB", snr) for snr in levels])
        for label, snr in variants:
            sim = written if snr is None else dataclasses.replace(written, snr_sets="sky")
            shots = []
            for _ in range(frames):
                if model == "glare":
                    sim = dataclasses.replace(sim, glare_radius_px=float(rng.uniform(200, 600)))
                shots.append(render_sky(cfg.camera, catalogue, random_attitude(rng), sim, rng,
                                        noise_model=model, snr_db=snr))
            sets.append(_seed_set(f"seed-written/{model}/{label}", f"seed-written/{model}",
                                  model, shots))
    for lens, exposure in REALISTIC:
        sim = dataclasses.replace(cfg.sim, glare_e=GLARE_E, cosmic_ray_rate_cm2_s=COSMIC_RATE,
                                  noise_model="realistic", exposure_ms=exposure)
        camera = dataclasses.replace(cfg.camera, focal_length_mm=lens)
        shots = [render_sky(camera, catalogue, random_attitude(rng), sim, rng,
                            psf=_random_psf(rng, PSF_SIGMA_PX, ("gaussian", "moffat"), 0.12))
                 for _ in range(realistic_frames)]
        sets.append(_sensor_set(f"realistic/{lens:.0f}mm/{exposure:.0f}ms", "realistic",
                                shots, camera))
    scenes = scene_frames if scene_frames is not None else max(1, realistic_frames // 2)
    sets.append(_glare_set(cfg, catalogue, scenes, rng))
    for lens in (16.0, 8.0):
        sets.append(_lunar_set(cfg, catalogue, lens, scenes, rng))
    sets.append(_held_out_set(cfg, catalogue, realistic_frames, rng))
    return sets


def _glare_set(cfg, catalogue, n, rng) -> DataSet:
    sim = dataclasses.replace(cfg.sim, noise_model="realistic")
    shape = (cfg.camera.height, cfg.camera.width)
    shots = [render_sky(cfg.camera, catalogue, random_attitude(rng), sim, rng,
                        psf=_random_psf(rng, PSF_SIGMA_PX, ("gaussian", "moffat"), 0.12),
                        scene=glare_scene(shape, rng, sim.full_well_e))
             for _ in range(n)]
    return _sensor_set("glare/16mm/100ms", "glare", shots, cfg.camera)


def _lunar_set(cfg, catalogue, lens, n, rng) -> DataSet:
    sim = dataclasses.replace(cfg.sim, noise_model="realistic")
    camera = dataclasses.replace(cfg.camera, focal_length_mm=lens)
    f_px = CameraModel.from_config(camera).f_px
    shape = (camera.height, camera.width)
    shots = [render_sky(camera, catalogue, random_attitude(rng), sim, rng,
                        psf=_random_psf(rng, PSF_SIGMA_PX, ("gaussian", "moffat"), 0.12),
                        scene=lunar_scene(shape, rng, sim.full_well_e, f_px))
             for _ in range(n)]
    return _sensor_set(f"lunar/{lens:.0f}mm", "lunar", shots, camera, solved=True)


def _held_out_set(cfg, catalogue, n, rng) -> DataSet:
    """Airy PSFs on sensors unlike the default (module docstring), frames of both depths."""
    shots, depths = [], []
    for _ in range(n):
        depth = int(rng.choice([8, 10]))
        camera = dataclasses.replace(cfg.camera, bit_depth=depth,
                                     focal_length_mm=float(rng.choice([16.0, 8.0])))
        sim = dataclasses.replace(
            cfg.sim, noise_model="realistic", read_noise_e=float(rng.uniform(1.5, 4.0)),
            gain_e_per_adu=cfg.sim.gain_e_per_adu * float(rng.uniform(0.7, 1.5)),
            sky_mag_arcsec2=float(rng.uniform(19.5, 22.0)),
            hot_pixel_fraction=float(rng.uniform(0.0, 5e-4)),
            glare_e=float(rng.choice([0.0, rng.uniform(100.0, 1500.0)])),
            cosmic_ray_rate_cm2_s=float(rng.uniform(5.0, 300.0)))
        shots.append(render_sky(camera, catalogue, random_attitude(rng), sim, rng,
                                psf=_random_psf(rng, HELD_OUT_SIGMA_PX, ("airy",), 0.15)))
        depths.append(depth)
    # the set's depth is per frame; the bound reads it from each frame's truth
    out = _sensor_set("held-out/airy", "held-out", shots, cfg.camera, held_out=True)
    out.saturation = lambda f, i: _sensor_saturation(f.bit_depth)(f, i)
    return out
