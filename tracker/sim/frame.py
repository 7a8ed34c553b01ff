"""One synthetic frame from point sources: PSF, photometry already done, noise, truth.

:func:`render_points` is the core every other renderer uses: given star
paths in pixels and their photo-electrons it renders the noise-free star
image, applies the chosen noise model, digitises, and computes each star's
expected SNR and the frame's measured SNR.

Noise models (``SimConfig.noise_model``):

* ``realistic``: tracker.sim.sensor (sky, dark, hot pixels, cosmic rays,
  glare, shot and read noise, ADC of the camera's bit depth);
* ``none``: star light only, digitised (bias, gain, rounding);
* ``gaussian_poisson``, ``salt_pepper``, ``speckle``, ``glare``: the seed
  method's models (tracker.sim.seednoise) on an 8-bit frame whose full
  scale is 255 ADU at the 8-bit gain (no bias).

Per-star expected SNR, for a star's own light s_i in pixel i:
``peak_snr`` = s_peak / noise at that pixel, ``mf_snr`` = sqrt(sum_i
s_i^2 / noise_i^2) (the matched-filter SNR), where for the sensor models
s_i is the star's light and the noise power s + background + read^2 +
gain^2/12 in e-; for the seed models s_i is the change of the pixel's
delivered mean that the star's light makes and the noise power the larger
of the delivered value's variances with and without the star's light
(:func:`tracker.sim.seednoise.delivered_moments`: clipped noise passes on
only part of a faint star's light, and a detector's threshold is set by
the sky's noise even where a clipped core is quieter; speckle's noise is
the star's own), floored at the 8-bit rounding noise LSB^2/12: light that
rounds away is not detectable, whatever the multiplicative (speckle) noise
on it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.config import CameraConfig, SimConfig
from tracker.sim import seednoise, sensor
from tracker.sim.photometry import sky_electrons_per_pixel
from tracker.sim.psf import Stamps, add_stamps, psf_stamps, stamp_pixels
from tracker.sim.psf_shapes import PsfShape, shaped_stamps

__all__ = ["SIM_STAR_DTYPE", "SimFrame", "render_points", "sim_psf", "star_stamps"]

SIM_STAR_DTYPE = np.dtype([
    ("x", np.float64),        # column at the exposure mid-point, px
    ("y", np.float64),        # row at the exposure mid-point, px
    ("mag", np.float32),      # Hp magnitude (NaN for explicit sources without one)
    ("hip", np.int32),        # Hipparcos number, -1 if none
    ("flux_e", np.float64),   # photo-electrons in the exposure (whole PSF)
    ("peak_snr", np.float64),  # expected peak-pixel SNR
    ("mf_snr", np.float64),   # expected matched-filter SNR
    ("in_frame", np.bool_),   # centre inside the image (else it only spills light in)
    ("saturated", np.bool_),  # its expected peak pixel reaches the full scale
    ("bg_power", np.float64),  # noise power of its peak pixel without its own light (sensor
                               # models: e-^2 of sky, dark, scene light, read, rounding)
])

_HOT_PIXEL_SIGMAS = 5.0  # hot pixels listed as false sources: dark charge >= 5 read noise


@dataclass
class SimFrame:
    """A rendered frame with its truth.

    ``image``: uint8 (bit_depth 8) or uint16 (bit_depth > 8) ADC counts.
    ``signal_e``: the noise-free star light, float32 photo-electrons per pixel.
    ``stars``: :data:`SIM_STAR_DTYPE` rows, one per rendered star.
    ``false_sources``: dicts {"kind": "hot_pixel"|"cosmic_ray", "x", "y", ...}.
    ``truth``: the JSON-ready dict written beside the image (tracker.sim.io).
    ``R``: attitude (v_cam = R @ v_icrs) or None for explicit sources.
    ``labels``: what lit each pixel when a scene was rendered (tracker.sim.scene).
    """

    image: np.ndarray
    bit_depth: int
    signal_e: np.ndarray
    stars: np.ndarray
    false_sources: list
    truth: dict
    R: np.ndarray | None = None
    labels: np.ndarray | None = None   # tracker.sim.scene.LABELS per pixel, if a scene


def sim_psf(sim_cfg: SimConfig, sigma_px: float | None = None) -> PsfShape:
    """The PSF ``sim_cfg`` describes (``sigma_px`` overrides its sigma)."""
    return PsfShape(sim_cfg.psf_shape,
                    sim_cfg.psf_sigma_px if sigma_px is None else float(sigma_px),
                    sim_cfg.psf_beta, sim_cfg.psf_ellipticity, np.radians(sim_cfg.psf_angle_deg))


def star_stamps(xs, ys, psf: PsfShape) -> Stamps:
    """Stamps of stars at xs, ys (N,) or along paths (N, M): exact erf integration for a
    round Gaussian (tracker.sim.psf), supersampling for any other shape."""
    if psf.is_round_gaussian:
        return psf_stamps(xs, ys, psf.sigma_px)
    return shaped_stamps(xs, ys, psf)


def _noise_settings(sim_cfg: SimConfig, noise_model: str | None, snr_db: float | None):
    model = sim_cfg.noise_model if noise_model is None else noise_model
    choices = ("realistic", "none") + seednoise.SEED_MODELS
    if model not in choices:
        raise ValueError(f"unknown noise model {model!r}; expected one of {', '.join(choices)}")
    target = sim_cfg.snr_db if snr_db is None else snr_db
    if target is not None and model not in seednoise.SEED_MODELS:
        raise ValueError(f"a target SNR applies to the seed noise models "
                         f"({', '.join(seednoise.SEED_MODELS)}), not to {model!r}")
    return model, target


def _seed_param(model: str, sim_cfg: SimConfig) -> float:
    return {"gaussian_poisson": sim_cfg.gp_variance, "salt_pepper": sim_cfg.sp_density,
            "speckle": sim_cfg.speckle_variance, "glare": 1.0}[model]


def _gather(image: np.ndarray, stamps: Stamps) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``image`` under each stamp pixel, and the mask of pixels inside it."""
    height, width = image.shape
    rows, cols, inside = stamp_pixels(image.shape, stamps)
    values = image[np.clip(rows, 0, height - 1), np.clip(cols, 0, width - 1)]
    return values, inside


def _star_snrs(own: np.ndarray, noise_power: np.ndarray,
               inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Peak and matched-filter SNR, and peak value, per star from its own light and the
    pixel noise power."""
    if own.size == 0:
        return np.zeros(len(own)), np.zeros(len(own)), np.zeros(len(own))
    own = np.where(inside, own, 0.0)
    noise_power = np.where(inside, np.maximum(noise_power, 1e-300), 1.0)
    flat_own = own.reshape(len(own), -1)
    peak_at = np.argmax(flat_own, axis=1)
    rows = np.arange(len(own))
    peak = flat_own[rows, peak_at]
    peak_snr = peak / np.sqrt(noise_power.reshape(len(own), -1)[rows, peak_at])
    matched = np.sqrt(np.sum(own ** 2 / noise_power, axis=(1, 2)))
    return peak_snr, matched, peak


def _as_paths(values) -> np.ndarray:
    """Positions (N,) or paths (N, M) as a float64 (N, M) array."""
    values = np.atleast_1d(np.asarray(values, dtype=np.float64))
    return values[:, None] if values.ndim == 1 else values


def render_points(shape: tuple[int, int], xs, ys, electrons, sim_cfg: SimConfig,
                  rng: np.random.Generator, *, bit_depth: int = 10, mags=None, hips=None,
                  noise_model: str | None = None, snr_db: float | None = None,
                  psf_sigma_px: float | None = None, sky_e: float | None = None,
                  pixel_size_um: float | None = None, psf: PsfShape | None = None,
                  light_e: np.ndarray | None = None,
                  deposits: tuple[np.ndarray, list] | None = None) -> SimFrame:
    """Render explicit point sources; returns a :class:`SimFrame` (``R`` None).

    ``xs``, ``ys``: positions in px, shape (N,), or paths (N, M) sampled
    evenly through the exposure (the truth position is the path's mean).
    ``electrons``: photo-electrons per source in the exposure. ``bit_depth``
    is used by the sensor models; the seed models always give 8 bits.
    ``noise_model``, ``snr_db``, ``psf_sigma_px`` override ``sim_cfg``.
    ``sky_e`` (e-/pixel) defaults to the sky of the default 16 mm camera;
    ``pixel_size_um`` (sensor area for cosmic rays) to the default camera's.
    ``psf`` (tracker.sim.psf_shapes.PsfShape) overrides the configured PSF
    and ``psf_sigma_px``. Sensor models only: ``light_e`` (e-/pixel, frame
    shape) is further light under the stars (glare, lit terrain, a planet;
    tracker.sim.scene), and ``deposits`` further charge after the shot noise
    with its truth (particle tracks: (image in e-, list of dicts)).
    """
    height, width = int(shape[0]), int(shape[1])
    if height < 1 or width < 1:
        raise ValueError(f"image shape must be positive; got {shape}")
    model, target = _noise_settings(sim_cfg, noise_model, snr_db)
    if psf is None:
        psf = sim_psf(sim_cfg, psf_sigma_px)
    sigma = psf.sigma_px
    xs, ys = _as_paths(xs), _as_paths(ys)
    electrons = np.atleast_1d(np.asarray(electrons, dtype=np.float64))
    if len(electrons) != len(xs) or np.any(~(electrons >= 0)):
        raise ValueError("need one finite electron count >= 0 per source")
    default_cam = CameraConfig()
    pixel_size_um = default_cam.pixel_size_um if pixel_size_um is None else pixel_size_um
    if sky_e is None:
        sky_e = sky_electrons_per_pixel(default_cam.focal_length_mm, pixel_size_um, sim_cfg)

    stamps = star_stamps(xs, ys, psf)
    signal = add_stamps((height, width), stamps, electrons)
    own = stamps.values * electrons[:, None, None]
    n = len(electrons)
    stars = np.zeros(n, SIM_STAR_DTYPE)
    stars["x"] = xs.mean(axis=1)
    stars["y"] = ys.mean(axis=1)
    stars["mag"] = np.nan if mags is None else mags
    stars["hip"] = -1 if hips is None else hips
    stars["flux_e"] = electrons
    stars["in_frame"] = ((stars["x"] >= -0.5) & (stars["x"] <= width - 0.5)
                         & (stars["y"] >= -0.5) & (stars["y"] <= height - 0.5))

    if model in seednoise.SEED_MODELS:
        image, info, power_of, total, glare = _seed_frame(signal, model, target, sim_cfg, rng)
        own = own / info["full_scale_e"]
        # the part of each star's light that survives the clip at full scale, and what
        # the delivered frame shows of it: the change of its pixels' mean, against
        # their spread (seednoise.delivered_moments)
        under, _ = _gather(total, stamps)
        lit, unlit = np.minimum(under, 1.0), np.minimum(under - own, 1.0)
        own = lit - unlit
        glare_under = None if glare is None else _gather(glare, stamps)[0]
        mean_lit, variance = seednoise.delivered_moments(model, info["param"], lit,
                                                         glare_under)
        mean_unlit, variance_unlit = seednoise.delivered_moments(model, info["param"], unlit,
                                                                 glare_under)
        seen = mean_lit - mean_unlit
        variance = np.maximum(variance, variance_unlit)
        depth = 8
    else:
        depth = bit_depth
        image, info, power_of, false_sources = _sensor_frame(
            signal, model, sim_cfg, rng, depth, sky_e, pixel_size_um, light_e, deposits)
    values, inside = _gather(power_of, stamps)
    if model in seednoise.SEED_MODELS:
        power = np.maximum(variance, seednoise.QUANT_POWER)
        stars["peak_snr"], stars["mf_snr"], _ = _star_snrs(seen, power, inside)
        peak = _star_snrs(own, power, inside)[2]
    else:
        power = values + (own if model == "realistic" else 0.0)
        stars["peak_snr"], stars["mf_snr"], peak = _star_snrs(own, power, inside)
    if len(own):
        at_peak = np.argmax(np.where(inside, own, -1.0).reshape(len(own), -1), axis=1)
        stars["bg_power"] = values.reshape(len(own), -1)[np.arange(len(own)), at_peak]
    stars["saturated"] = peak >= info.pop("full_scale")
    truth = {
        "frame": None, "seed": sim_cfg.seed, "bit_depth": depth, "psf_sigma_px": sigma,
        "psf": {"kind": psf.kind, "sigma_px": sigma, "beta": psf.beta,
                "ellipticity": psf.ellipticity, "angle_deg": float(np.degrees(psf.angle_rad))},
        "exposure_ms": sim_cfg.exposure_ms, "noise_model": model,
        "snr_db": info.pop("snr_db"), "snr_db_target": target,
        "snr_db_definition": seednoise.SNR_DEFINITION, "noise": info,
        "stars": [], "false_sources": [], "q": None, "ra_deg": None, "dec_deg": None,
        "roll_deg": None, "epoch_year": None, "t_s": 0.0, "rate_deg_s": None, "camera": None,
    }
    frame = SimFrame(image=image, bit_depth=depth, signal_e=signal.astype(np.float32),
                     stars=stars, false_sources=[] if model in seednoise.SEED_MODELS
                     else false_sources, truth=truth)
    truth["stars"] = [_star_record(row) for row in stars]
    truth["false_sources"] = frame.false_sources
    return frame


def _star_record(row) -> dict:
    mag = float(row["mag"])
    return {"x": float(row["x"]), "y": float(row["y"]), "mag": None if mag != mag else mag,
            "hip": int(row["hip"]), "flux_e": float(row["flux_e"]),
            "peak_snr": float(row["peak_snr"]), "mf_snr": float(row["mf_snr"]),
            "in_frame": bool(row["in_frame"]), "saturated": bool(row["saturated"])}


def _seed_frame(signal: np.ndarray, model: str, target: float | None, sim_cfg: SimConfig,
                rng: np.random.Generator):
    """8-bit frame under a seed noise model; returns image, info, per-pixel noise power,
    the clean light before the clip at full scale and the unit glare profile (or None)."""
    # star light (e-) that fills the 0..1 scale
    full_scale_e = sensor.sensor_scale(sim_cfg, 8).gain_e_per_adu * 255.0 / sim_cfg.seed_star_gain
    stars = signal / full_scale_e
    height, width = stars.shape
    glare = None
    centre = None
    if model == "glare":
        centre = (float(rng.uniform(0, width - 1)), float(rng.uniform(0, height - 1)))
        glare = sensor.glare_field(stars.shape, centre, sim_cfg.glare_radius_px, 1.0)
    sky = sim_cfg.seed_sky
    param = _seed_param(model, sim_cfg)
    if target is not None and sim_cfg.snr_sets == "sky":
        sky = seednoise.sky_for_snr(model, stars, param, target, glare)
    clean = np.minimum(stars + sky, 1.0)
    if target is not None and sim_cfg.snr_sets == "parameter":
        param = seednoise.param_for_snr(model, clean, target, glare)
    noisy, info = seednoise.apply_seed_noise(clean, model, rng, param=param,
                                             glare_centre=centre,
                                             glare_radius_px=sim_cfg.glare_radius_px)
    image = np.rint(noisy * 255.0).astype(np.uint8)
    info["snr_db"] = seednoise.snr_db(clean, image / 255.0)
    info["full_scale_e"] = full_scale_e
    info["sky"] = float(sky)
    info["full_scale"] = (1.0 - sky) * (1.0 - 1e-9)   # a star that reaches it is clipped
    power = seednoise.noise_power(model, param, clean, glare)
    return image, info, power, stars + sky, glare


def _sensor_frame(signal: np.ndarray, model: str, sim_cfg: SimConfig,
                  rng: np.random.Generator, bit_depth: int, sky_e: float,
                  pixel_size_um: float, light_e: np.ndarray | None = None,
                  deposits: tuple[np.ndarray, list] | None = None):
    """Sensor-model frame; returns image, info, background noise power (e-^2), false sources."""
    scale = sensor.sensor_scale(sim_cfg, bit_depth)
    shape = signal.shape
    exposure_s = sim_cfg.exposure_ms / 1000.0
    quant = scale.gain_e_per_adu ** 2 / 12.0
    info = {"gain_e_per_adu": scale.gain_e_per_adu, "bias_adu": scale.bias_adu,
            "full_well_e": sim_cfg.full_well_e,
            "full_scale": min(sim_cfg.full_well_e,
                              (scale.max_adu - scale.bias_adu) * scale.gain_e_per_adu)}
    if model == "none":
        image = sensor.digitise(signal, scale, 0.0, sim_cfg.full_well_e, None)
        electrons = (image.astype(np.float64) - scale.bias_adu) * scale.gain_e_per_adu
        info["snr_db"] = seednoise.snr_db(signal, electrons)
        return image, info, np.full(shape, quant), []
    background = np.full(shape, sky_e + sim_cfg.dark_current_e_s * exposure_s)
    if sim_cfg.glare_e > 0:
        centre = (float(rng.uniform(-0.5, 1.5) * shape[1]),
                  float(rng.uniform(-0.5, 1.5) * shape[0]))
        background += sensor.glare_field(shape, centre, sim_cfg.glare_radius_px,
                                         sim_cfg.glare_e)
        info["glare_centre"] = list(centre)
    if light_e is not None:
        background += light_e
    hot_flat, hot_dark = sensor.hot_pixels(shape, sim_cfg)
    background.ravel()[hot_flat] += hot_dark * exposure_s
    area_cm2 = shape[0] * shape[1] * (pixel_size_um * 1e-4) ** 2
    count = int(rng.poisson(sim_cfg.cosmic_ray_rate_cm2_s * area_cm2 * exposure_s))
    rays, ray_truth = sensor.cosmic_rays(shape, count, sim_cfg.cosmic_ray_e, rng)
    if deposits is not None:
        rays = rays + deposits[0]
        ray_truth = ray_truth + list(deposits[1])
    charge = rng.poisson(signal + background).astype(np.float64) + rays
    image = sensor.digitise(charge, scale, sim_cfg.read_noise_e, sim_cfg.full_well_e, rng)
    electrons = (image.astype(np.float64) - scale.bias_adu) * scale.gain_e_per_adu
    info["snr_db"] = seednoise.snr_db(signal, electrons)
    info.update(sky_e=sky_e, hot_pixels=int(len(hot_flat)), cosmic_rays=count)
    loud = hot_dark * exposure_s >= _HOT_PIXEL_SIGMAS * max(sim_cfg.read_noise_e, 1.0)
    false_sources = [{"kind": "hot_pixel", "x": float(f % shape[1]), "y": float(f // shape[1]),
                      "charge_e": float(d * exposure_s)}
                     for f, d in zip(hot_flat[loud], hot_dark[loud], strict=True)]
    noise = background + sim_cfg.read_noise_e ** 2 + quant
    return image, info, noise, false_sources + ray_truth
