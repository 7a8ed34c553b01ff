"""The seed method's four noise models, on images scaled 0..1 (docs/seed-method.md).

* ``gaussian_poisson`` (parameter: variance, default 0.15): add N(0, var),
  clip to 0..1, then photon noise: Poisson(255 * value) / 255, clip.
* ``salt_pepper`` (parameter: density, default 0.05): round(density * size)
  distinct pixels, half of them set to 0.0 and half to 1.0.
* ``speckle`` (parameter: variance, default 0.15): multiply by a Gaussian
  mask of mean 1 and that variance, clip.
* ``glare`` (parameter: amplitude, default 1.0): add
  amplitude * exp(-r^2 / (2 r0^2)) around a centre (x, y), clip.

Image SNR (the definition written into every truth file)::

    snr_db = 10 log10( sum(S^2) / sum((I - S)^2) )

over the whole frame, S = the noise-free image and I = the delivered one,
both on the 0..1 scale (for the realistic sensor: electrons above bias).
:func:`noise_power` gives the expected E[(I - S)^2] of a pixel of clean
value S (closed form over the Gaussian draws), which sets a model's
parameter for a target SNR and gives each star's expected SNR.
"""

from __future__ import annotations

import numpy as np

from tracker.normal import erf
from tracker.sim.sensor import glare_field

__all__ = ["SEED_MODELS", "SNR_DEFINITION", "apply_seed_noise", "delivered_moments",
           "noise_power", "param_for_snr", "sky_for_snr", "snr_db"]

SEED_MODELS = ("gaussian_poisson", "salt_pepper", "speckle", "glare")
SNR_DEFINITION = ("10*log10(sum(S^2)/sum((I-S)^2)) over the frame; S = noise-free star "
                  "image, I = delivered image, same scale (0..1 for seed models, "
                  "electrons above bias for the sensor models)")
# 8-bit output: photon count per unit intensity of the Poisson stage, and the
# rounding noise power every 8-bit pixel carries.
_LEVELS = 255.0
QUANT_POWER = 1.0 / (12.0 * _LEVELS ** 2)   # 8-bit rounding as uniform noise, (0..1)^2


def _check_model(model: str) -> None:
    if model not in SEED_MODELS:
        raise ValueError(f"unknown seed noise model {model!r}; expected one of "
                         f"{', '.join(SEED_MODELS)}")


def _rounded(values: np.ndarray) -> np.ndarray:
    """Values (0..1) as the 8-bit frame delivers them."""
    return np.rint(values * _LEVELS) / _LEVELS


def noise_power(model: str, param: float, clean: np.ndarray,
                glare: np.ndarray | None = None) -> np.ndarray:
    """Expected (I - S)^2 per pixel of clean value ``clean`` (0..1), 8-bit output rounding included.

    For ``glare`` pass the unit glare profile exp(-r^2/(2 r0^2)) at the same
    pixels; the glare is deterministic, so its "noise" is its own square.
    Salt and pepper, glare and Gaussian+Poisson are exact (the Poisson
    stage puts values on the 8-bit grid); speckle adds an approximate
    rounding term min(1/12 LSB^2, s^2).
    """
    _check_model(model)
    s = np.asarray(clean, dtype=np.float64)
    if model == "salt_pepper":
        return (1.0 - param) * (_rounded(s) - s) ** 2 + 0.5 * param * ((1.0 - s) ** 2 + s ** 2)
    if model == "glare":
        return (_rounded(np.minimum(s + param * glare, 1.0)) - s) ** 2
    spread = np.sqrt(param) * (1.0 if model == "gaussian_poisson" else s)
    second, mean = _clipped_moments(s, spread)
    if model == "gaussian_poisson":
        return second + mean / _LEVELS
    return second + np.minimum(QUANT_POWER, s * s)


def delivered_moments(model: str, param: float, clean: np.ndarray,
                      glare: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of the delivered value (0..1) of a pixel of clean value ``clean``.

    What a detector sees of a star: its signal in a pixel is the change of
    the delivered mean its light makes, mean(b + a) - mean(b), and the noise
    is the delivered value's spread about that mean. Noise clipped at black
    takes part of a faint star's light with it (on a black sky under
    Gaussian+Poisson variance 0.15 half of it: the clip at 0 moves the
    mean by only P(0 < s + noise < 1) per unit of light) and puts a bias in
    :func:`noise_power`'s (I - S)^2 that a background estimate removes, so
    neither the star's own light nor that power is its detectability.

    * ``gaussian_poisson``: exact for C = clip(s + N(0, var)) (module doc),
      then Var = Var(C) + E[C] / 255 from the Poisson stage (its clip at 1
      left out: it touches only pixels near full scale).
    * ``salt_pepper``: exact: mean (1 - d) round(s) + d / 2.
    * ``speckle``: the clipped Gaussian's moments plus the rounding term of
      :func:`noise_power`.
    * ``glare``: the glare counts as the noise it is in :func:`noise_power`
      (a detector has to tell a star from the glare under it); the mean is
      the clean value.

    The caller floors the variance at :data:`QUANT_POWER` as it does the power.
    """
    _check_model(model)
    s = np.asarray(clean, dtype=np.float64)
    if model == "salt_pepper":
        r = _rounded(s)
        mean = (1.0 - param) * r + 0.5 * param
        return mean, (1.0 - param) * r * r + 0.5 * param - mean * mean
    if model == "glare":
        return s, noise_power(model, param, s, glare)
    spread = np.sqrt(param) * (1.0 if model == "gaussian_poisson" else s)
    second, mean = _clipped_moments(s, spread)
    variance = np.maximum(second - (mean - s) ** 2, 0.0)
    if model == "gaussian_poisson":
        return mean, variance + mean / _LEVELS
    return mean, variance + np.minimum(QUANT_POWER, s * s)


def _clipped_moments(s: np.ndarray, spread: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """E[(C - s)^2] and E[C] for C = clip(s + spread * Z, 0, 1), Z standard normal.

    Exact, from the normal CDF Phi and density phi at the clip points
    z0 = -s / spread and z1 = (1 - s) / spread.
    """
    s, spread = np.broadcast_arrays(np.asarray(s, np.float64), np.asarray(spread, np.float64))
    b = np.where(spread > 0, spread, 1.0)
    z0, z1 = -s / b, (1.0 - s) / b
    cdf0, cdf1 = 0.5 * (1.0 + erf(z0 / np.sqrt(2.0))), 0.5 * (1.0 + erf(z1 / np.sqrt(2.0)))
    pdf0, pdf1 = np.exp(-0.5 * z0 * z0), np.exp(-0.5 * z1 * z1)
    pdf0, pdf1 = pdf0 / np.sqrt(2.0 * np.pi), pdf1 / np.sqrt(2.0 * np.pi)
    inner = (cdf1 - z1 * pdf1) - (cdf0 - z0 * pdf0)  # integral of z^2 phi over [z0, z1]
    second = s * s * cdf0 + b * b * inner + (1.0 - s) ** 2 * (1.0 - cdf1)
    mean = s * (cdf1 - cdf0) + b * (pdf0 - pdf1) + (1.0 - cdf1)
    still = spread <= 0
    return np.where(still, 0.0, second), np.where(still, s, mean)


def param_for_snr(model: str, clean: np.ndarray, target_db: float,
                  glare: np.ndarray | None = None) -> float:
    """The model parameter whose expected image SNR is ``target_db`` (dB).

    Bisection on log(parameter) over the expected noise power (salt and
    pepper in closed form); raises ValueError if no parameter reaches it.
    """
    _check_model(model)
    s = np.asarray(clean, dtype=np.float64).ravel()
    signal = float(np.mean(s ** 2))
    if signal <= 0:
        raise ValueError("the noise-free image is black: its SNR is -inf for any noise")
    wanted = signal / 10.0 ** (target_db / 10.0)
    if model == "salt_pepper":  # mean power = base + density * slope
        base = float(np.mean((_rounded(s) - s) ** 2))
        slope = float(np.mean(0.5 * ((1.0 - s) ** 2 + s ** 2))) - base
        density = (wanted - base) / slope
        if not 0.0 <= density <= 1.0:
            raise ValueError(f"image SNR {target_db:g} dB is out of reach for salt_pepper "
                             f"(it needs density {density:.3g})")
        return float(density)
    if model == "glare":  # smooth noise: every 4th pixel estimates its mean power
        sample, counts, glare = s[::4], None, np.asarray(glare).ravel()[::4]
    else:  # pixels of (nearly) equal clean value share their expected noise: histogram
        idx = np.rint(s * 4095).astype(np.int64)
        counts = np.bincount(idx, minlength=4096)
        sums = np.bincount(idx, weights=s, minlength=4096)
        keep = counts > 0
        sample, counts = sums[keep] / counts[keep], counts[keep]

    def power_at(log_param: float) -> float:
        return float(np.average(noise_power(model, np.exp(log_param), sample, glare),
                                weights=counts))

    lo, hi = np.log(1e-12), np.log(1e4)
    if not power_at(lo) <= wanted <= power_at(hi):
        raise ValueError(f"image SNR {target_db:g} dB is out of reach for {model}: it spans "
                         f"{10 * np.log10(signal / power_at(hi)):.2f} to "
                         f"{10 * np.log10(signal / power_at(lo)):.2f} dB here")
    for _ in range(45):
        mid = 0.5 * (lo + hi)
        if power_at(mid) < wanted:
            lo = mid
        else:
            hi = mid
    return float(np.exp(0.5 * (lo + hi)))


def sky_for_snr(model: str, stars: np.ndarray, param: float, target_db: float,
                glare: np.ndarray | None = None) -> float:
    """The sky level (0..1) under ``stars`` whose expected image SNR is ``target_db`` (dB).

    The model keeps its parameter ``param``; the noise-free image is
    min(stars + sky, 1), and the SNR counts the sky as signal (it is part
    of the noise-free image). Bisection over the expected noise power of
    every 4th pixel; raises ValueError if no sky level in 0..1 reaches the
    target (speckle's SNR hardly depends on it: its noise scales with the
    light).
    """
    _check_model(model)
    s = np.asarray(stars, dtype=np.float64).ravel()[::4]
    g = None if glare is None else np.asarray(glare).ravel()[::4]

    def snr_at(sky: float) -> float:
        clean = np.minimum(s + sky, 1.0)
        power = float(np.mean(noise_power(model, param, clean, g)))
        signal = float(np.mean(clean ** 2))
        return 10.0 * np.log10(max(signal, 1e-300) / max(power, 1e-300))

    lo, hi = 0.0, 1.0
    low, high = snr_at(lo), snr_at(hi)
    if not min(low, high) <= target_db <= max(low, high):
        raise ValueError(f"image SNR {target_db:g} dB is out of reach for {model} at its "
                         f"parameter {param:g}: the sky level spans {low:.2f} to "
                         f"{high:.2f} dB")
    rising = high >= low
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if (snr_at(mid) < target_db) == rising:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def apply_seed_noise(image01: np.ndarray, model: str, rng: np.random.Generator, *,
                     param: float, glare_centre: tuple[float, float] | None = None,
                     glare_radius_px: float = 400.0) -> tuple[np.ndarray, dict]:
    """Noisy copy (float64, 0..1, not yet rounded) of a clean 0..1 image, and its settings.

    ``param`` is the model's variance, density or amplitude (module doc).
    For ``glare`` the centre (x, y) in pixels defaults to a random point in
    the frame. The returned dict has ``model``, ``param`` and, for glare,
    ``glare_centre`` and ``glare_radius_px``.
    """
    _check_model(model)
    s = np.asarray(image01, dtype=np.float64)
    if s.ndim != 2:
        raise ValueError(f"image must be 2-D; got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("image has non-finite pixels")
    if not param >= 0:
        raise ValueError(f"{model} parameter must be >= 0; got {param}")
    info: dict = {"model": model, "param": float(param)}
    if model == "gaussian_poisson":
        noisy = np.clip(s + rng.normal(0.0, np.sqrt(param), size=s.shape), 0.0, 1.0)
        noisy = np.clip(rng.poisson(noisy * _LEVELS) / _LEVELS, 0.0, 1.0)
    elif model == "salt_pepper":
        hits = rng.choice(s.size, size=int(round(param * s.size)), replace=False)
        noisy = s.copy()
        noisy.ravel()[hits[: len(hits) // 2]] = 0.0
        noisy.ravel()[hits[len(hits) // 2:]] = 1.0
    elif model == "speckle":
        noisy = np.clip(s * (1.0 + rng.normal(0.0, np.sqrt(param), size=s.shape)), 0.0, 1.0)
    else:
        height, width = s.shape
        if glare_centre is None:
            glare_centre = (float(rng.uniform(0, width - 1)), float(rng.uniform(0, height - 1)))
        noisy = np.clip(s + glare_field(s.shape, glare_centre, glare_radius_px, param),
                        0.0, 1.0)
        info.update(glare_centre=[float(glare_centre[0]), float(glare_centre[1])],
                    glare_radius_px=float(glare_radius_px))
    return noisy, info


def snr_db(clean: np.ndarray, delivered: np.ndarray) -> float:
    """Measured image SNR (dB) by :data:`SNR_DEFINITION`; +inf for a perfect copy."""
    clean = np.asarray(clean, dtype=np.float64)
    noise = float(np.sum((np.asarray(delivered, dtype=np.float64) - clean) ** 2))
    signal = float(np.sum(clean ** 2))
    if noise == 0:
        return float("inf")
    if signal == 0:
        return float("-inf")
    return 10.0 * np.log10(signal / noise)
