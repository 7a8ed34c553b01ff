"""Configuration: one YAML file loaded into validated, frozen dataclasses.

Every key has a shipped default, a unit and a one-line description, declared
once with :func:`knob` in the section dataclasses below. The same declarations
drive the loader's validation, ``tracker config`` (which prints the effective
configuration as commented YAML) and the README's key table.

A bad file is refused with a :class:`ConfigError` whose message is one line
naming the file, the key, what was found and what was expected, e.g.::

    cfg.yaml: camera.focal_length_mm: found -3 (int), expected a number >= 0.1

Each pipeline stage receives only its own section (``cfg.detect``,
``cfg.link`` ...), never the whole configuration.
"""

from __future__ import annotations

import dataclasses
import hashlib
import reprlib
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tracker.errors import UserError
from tracker.regular_file import FileRefused, read_regular_file
from tracker.yaml_bounded import YamlError, parse_yaml

__all__ = ["ConfigError", "Config", "knob", "load_config", "render_yaml", "config_checksum",
           "check_config", "MAX_SENSOR_PIXELS", "MAX_CONFIG_BYTES"]


class ConfigError(UserError, ValueError):
    """A configuration file that cannot be used; the message is one line."""


def knob(default: Any, doc: str, unit: str = "", *, min: float | None = None,
         max: float | None = None, choices: tuple | None = None) -> Any:
    """Declare a configuration key: default, description, unit and limits."""
    meta = {"doc": doc, "unit": unit, "min": min, "max": max, "choices": choices}
    if isinstance(default, (list, dict)):
        raise TypeError("mutable defaults are not allowed; use a tuple")
    return dataclasses.field(default=default, metadata=meta)


# --------------------------------------------------------------------------
# Sections. Each stage owns one; add keys with knob() and document them.
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class CameraConfig:
    """Pinhole camera with radial distortion (conventions: tracker.camera)."""

    width: int = knob(1600, "image width", "px", min=1, max=65535)
    height: int = knob(1300, "image height", "px", min=1, max=65535)
    pixel_size_um: float = knob(3.0, "pixel pitch", "um", min=0.1, max=100.0)
    focal_length_mm: float = knob(16.0, "lens focal length", "mm", min=0.1, max=10000.0)
    cx: float | None = knob(None, "principal point column; null = (width-1)/2", "px")
    cy: float | None = knob(None, "principal point row; null = (height-1)/2", "px")
    k1: float = knob(0.0, "radial distortion, r^2 term (normalised coordinates)", "",
                     min=-10.0, max=10.0)
    k2: float = knob(0.0, "radial distortion, r^4 term (normalised coordinates)", "",
                     min=-100.0, max=100.0)
    bit_depth: int = knob(10, "bits per pixel delivered by the sensor", "bit",
                          choices=(8, 10, 12, 16))


@dataclass(frozen=True)
class CatalogueConfig:
    """The bundled Hipparcos-derived star list (tracker.catalogue).

    The bundled file holds the 78,352 stars with Hp <= 9.0. With mag_limit
    null the solver takes as many as the field needs (tracker/data/README.md):
    about 150 stars in an average frame, never fewer than its pattern
    database uses; a number makes that the limit for everything.
    """

    path: str | None = knob(None, "catalogue file (with <file>.sha256 beside it); "
                            "null = the bundled one (tracker/data/stars.npz)")
    epoch_year: float | None = knob(
        None, "observation epoch for proper motion when frames carry no absolute time, "
        "decimal Julian year; null = now (system clock); a frame's absolute time (TIME_SYNC, "
        "a replay's utc) sets the epoch instead", "yr", min=1900.0, max=2200.0)
    epoch_step_years: float = knob(
        0.01, "re-propagate the catalogue when a frame's absolute time is further than this "
        "from its epoch (the fastest star, 8.67 arcsec/yr, is then off by at most 0.09 "
        "arcsec; the next frame is solved lost in space)", "yr", min=0.0001, max=100.0)
    mag_limit: float | None = knob(None, "faintest Hipparcos Hp magnitude used; null = what "
                                   "the camera's field needs; at most the file's own limit "
                                   "(9.0 for the bundled file)", "mag", min=-2.0, max=12.5)


@dataclass(frozen=True)
class SimConfig:
    """Synthetic frames (tracker.sim)."""

    seed: int = knob(1, "random seed; equal seeds give identical frames", min=0)
    noise_model: str = knob(
        "realistic", "sensor model (realistic, none) or one of the seed method's 8-bit "
        "noise models", choices=("realistic", "none", "gaussian_poisson", "salt_pepper",
                                 "speckle", "glare"))
    psf_sigma_px: float = knob(1.2, "PSF sigma (M12 lens slightly defocused); for other "
                               "shapes, the sigma of the Gaussian of the same FWHM", "px",
                               min=0.2, max=20.0)
    psf_shape: str = knob("gaussian", "PSF family: gaussian, moffat (broad wings) or airy "
                          "(diffraction core and rings); tracker.sim.psf_shapes", "name",
                          choices=("gaussian", "moffat", "airy"))
    psf_beta: float = knob(3.0, "moffat: wing exponent beta (small = broad wings)", "",
                           min=1.1, max=50.0)
    psf_ellipticity: float = knob(0.0, "PSF ellipticity (a^2 - b^2) / (a^2 + b^2) of its "
                                  "axes", "ratio", min=0.0, max=0.9)
    psf_angle_deg: float = knob(0.0, "direction of the PSF's long axis from +x toward +y",
                                "deg", min=-360.0, max=360.0)
    exposure_ms: float = knob(100.0, "exposure time", "ms", min=0.001, max=60000.0)
    f_number: float = knob(2.0, "lens focal ratio; aperture = focal length / f_number", "f/#",
                           min=0.5, max=64.0)
    transmission: float = knob(0.85, "optics transmission, band average", "fraction", min=0.0,
                               max=1.0)
    quantum_efficiency: float = knob(
        0.45, "sensor QE averaged over the Hp band (OV2311 peak about 0.6)", "e-/photon", min=0.0,
        max=1.0)
    zero_point_photons: float = knob(
        4.0e10, "photons of a Hp = 0 star above the atmosphere across the Hp band",
        "photon/m^2/s", min=0.0)
    sky_mag_arcsec2: float = knob(21.0, "sky surface brightness (dark site 21-22; space "
                                  "zodiacal light about 22.5)", "mag/arcsec^2", min=5.0,
                                  max=30.0)
    dark_current_e_s: float = knob(10.0, "mean dark current of a normal pixel", "e-/s",
                                   min=0.0)
    read_noise_e: float = knob(2.2, "read noise (full well / 10^(68 dB / 20))", "e-",
                               min=0.0)
    full_well_e: float = knob(5500.0, "full-well capacity (10^(37.4 dB / 10))", "e-",
                              min=1.0)
    gain_e_per_adu: float = knob(
        1.35, "conversion gain at 10 bits (5.4 e-/ADU at analogue gain 1; default = gain 4); "
        "an n-bit ADC uses gain * 2^(10-n)", "e-/ADU", min=0.001)
    bias_adu: float = knob(64.0, "black level at 10 bits (scaled by 2^(n-10) for n bits)",
                           "ADU", min=0.0)
    hot_pixel_fraction: float = knob(2e-4, "fraction of pixels with high dark current "
                                     "(fixed per seed, i.e. per sensor)", "fraction", min=0.0,
                                     max=0.1)
    hot_pixel_dark_e_s: float = knob(5000.0, "mean dark current of a hot pixel "
                                     "(exponentially distributed)", "e-/s", min=0.0)
    cosmic_ray_rate_cm2_s: float = knob(5.0, "cosmic-ray hits on the sensor (LEO about 1-10, "
                                        "ground about 0.02)", "1/cm^2/s", min=0.0)
    cosmic_ray_e: float = knob(800.0, "mean charge a cosmic ray leaves per pixel of its "
                               "track", "e-", min=0.0)
    glare_e: float = knob(0.0, "realistic model: stray-light peak at the glare centre "
                          "(0 = none)", "e-", min=0.0)
    glare_radius_px: float = knob(400.0, "glare Gaussian radius r0 (seed method: 200-600)",
                                  "px", min=1.0)
    gp_variance: float = knob(0.15, "gaussian_poisson: Gaussian variance on the 0..1 scale",
                              "(full scale)^2", min=0.0)
    sp_density: float = knob(0.05, "salt_pepper: fraction of pixels set to 0 or 1", "fraction",
                             min=0.0, max=1.0)
    speckle_variance: float = knob(0.15, "speckle: variance of the multiplicative mask "
                                   "(mean 1)", "(mask value)^2", min=0.0)
    snr_db: float | None = knob(None, "seed noise models: target image SNR (sets the model's "
                                "strength, or the sky level: snr_sets); null = use its "
                                "parameter and seed_sky as given", "dB",
                                min=-40.0, max=60.0)
    snr_sets: str = knob("parameter", "seed noise models: what a target snr_db sets: the "
                         "model's parameter, or the sky level under the stars with the "
                         "parameter as given (sky)", "name", choices=("parameter", "sky"))
    seed_star_gain: float = knob(1.0, "seed noise models: factor on the stars' light before "
                                 "the noise (a longer exposure of the photographed screen)",
                                 "", min=1e-6, max=1e6)
    seed_sky: float = knob(0.0, "seed noise models: sky level under the stars before the "
                           "noise (a photographed screen's glow)", "fraction", min=0.0,
                           max=1.0)
    smear: bool = knob(True, "integrate star motion within the exposure when slewing")
    fps: float = knob(10.0, "frame rate of simulated sequences", "Hz", min=0.001,
                      max=1000.0)
    rate_deg_s: tuple[float, ...] = knob((0.0, 0.0, 0.0), "body angular rate about the "
                                         "camera x, y, z axes", "deg/s")


@dataclass(frozen=True)
class DetectConfig:
    """Star detection and centroiding (tracker.detect)."""

    method: str = knob("default", "detection and centroiding method: default (fixed-memory "
                       "detector), seed (the dissertation's pipeline), com, gaussian_fit, "
                       "gaussian_fit_fast, sieve (its baselines)", "name",
                       choices=("default", "seed", "com", "gaussian_fit", "gaussian_fit_fast",
                                "sieve"))
    max_stars: int = knob(256, "largest number of stars reported per frame", "stars", min=1,
                          max=65535)
    seed_blur_sigma_px: float = knob(1.5, "seed method: Gaussian blur sigma", "px",
                                     min=0.3, max=10.0)
    seed_blur_ksize_px: int = knob(7, "seed method: Gaussian blur kernel size (odd)", "px",
                                   choices=(3, 5, 7, 9, 11, 13, 15))
    seed_threshold_frac: float = knob(0.3, "seed method: threshold as a fraction of the "
                                      "filtered image's maximum", "fraction", min=0.01, max=0.99)
    psf_sigma_px: float = knob(1.2, "default: PSF sigma of the optics to start from (the "
                               "Gaussian of the same FWHM); each frame's stars then measure "
                               "it (psf_measure), and it sets the matched filter, the "
                               "centroid window and the centroid fit", "px",
                               min=0.45, max=3.5)
    psf_measure: bool = knob(True, "default: measure the PSF on every frame from its bright, "
                             "isolated, unsaturated stars (false: psf_sigma_px throughout)")
    psf_min_stars: int = knob(5, "default: fewest agreeing stars for a frame's own PSF "
                              "measurement (fewer: the previous estimate is kept)", "stars",
                              min=1, max=64)
    psf_min_peak_sigma: float = knob(10.0, "default: a star measures the PSF if its peak "
                                     "pixel is this far above the background", "sigma",
                                     min=3.0, max=1e6)
    psf_memory_frames: int = knob(20, "default: frames whose agreeing PSF measurements are "
                                  "averaged (1 = each frame alone); a measurement that "
                                  "disagrees replaces the average at once", "frames",
                                  min=1, max=100000)
    false_alarms_per_frame: float = knob(0.1, "default: noise peaks a frame may report on "
                                         "average; sets the detection threshold on the "
                                         "matched-filtered image for the frame's size, PSF "
                                         "and noise (tracker.detect.threshold)", "peaks",
                                         min=1e-9, max=1000.0)
    threshold_sigma: float | None = knob(None, "default: detection threshold on the "
                                         "matched-filtered image, in units of its background "
                                         "noise, instead of false_alarms_per_frame's (raised "
                                         "for skewed noise either way)", "sigma",
                                         min=1.0, max=1000.0)
    background_tile_px: int = knob(32, "default: side of the background grid's tiles", "px",
                                   min=4, max=4096)
    background_step_px: int = knob(4, "default: spacing of the pixels sampled in each "
                                   "background tile", "px", min=1, max=256)
    impulse_sigma: float = knob(5.0, "default: an impulse (hot pixel, cosmic ray) differs "
                                "from its 3x3 median by more than this", "sigma",
                                min=1.0, max=1000.0)
    impulse_contrast: float | None = knob(
        None, "default: ... and by more than this fraction of its height above the "
        "background; null = halfway between a centred PSF's value and 1", "fraction",
        min=0.0, max=1.0)
    max_impulses: int = knob(32768, "default: impulse candidates tested one by one; more "
                             "switch to a whole-frame test", "pixels", min=1, max=10000000)
    deblend_dip_sigma: float = knob(1.5, "default: a fainter local maximum is a separate "
                                    "star if the filtered image dips this far below it "
                                    "on the way to a brighter one", "sigma",
                                    min=0.0, max=1000.0)
    blend_radius_px: int | None = knob(None, "default: distance within which two stars are "
                                       "a pair (deblend test, BLENDED flag); null = twice "
                                       "the centroid window's radius (windows overlap)",
                                       "px", min=1, max=64)
    centroid_noise: str = knob("additive", "default: noise the centroid is made for: additive "
                               "(shot, read, background: windowed centroid) or multiplicative "
                               "(speckle-like, noise proportional to the light: maximum-"
                               "likelihood fit, about 0.1 s more per frame; the shape tests "
                               "are off)", "name",
                               choices=("additive", "multiplicative"))
    centroid_iterations: int = knob(8, "default: most iterations of the windowed centroid",
                                    "iterations", min=1, max=100)
    centroid_tolerance_px: float = knob(0.001, "default: stop iterating when no centroid "
                                        "moves more than this", "px", min=0.0, max=1.0)
    sharp_size_ratio: float = knob(0.4, "default: reject a spot whose windowed second "
                                   "moment across its narrowest axis is below this "
                                   "fraction of the PSF's (a cosmic-ray hit or track; a "
                                   "streaked star keeps the PSF's width)", "fraction",
                                   min=0.0, max=1.0)
    rough_ratio: float = knob(12.0, "default: reject a spot whose pixel-scale roughness "
                              "(Laplacian energy over energy) exceeds this multiple of a star's "
                              "of its flux under the frame's PSF, and by more than its noise "
                              "makes (clusters of cosmic-ray hits and touching impulses; no "
                              "image of the sky is rougher than a point)",
                              "ratio", min=1.0, max=1e6)
    sharp_min_snr: float = knob(10.0, "default: apply the sharpness and elongation tests "
                                "only above this SNR (below it a spot narrower than "
                                "sharp_size_ratio is rejected only when narrower than a star "
                                "by 4 spreads of its width's noise)", "sigma", min=0.0,
                                max=1e6)
    elongation_max: float = knob(0.3, "default: flag ELONGATED above this ellipticity of "
                                 "the windowed moments", "ratio", min=0.0, max=1.0)
    extended_ratio: float = knob(2.0, "default: flag EXTENDED an unsaturated source whose "
                                 "flux/peak (its effective area) exceeds this multiple of "
                                 "the frame's median", "ratio", min=1.0, max=100.0)
    body_ratio: float = knob(5.0, "default: mask (do not report) a source whose flux/peak "
                             "exceeds this multiple of the frame's median: a maximum on a "
                             "ghost's disc, a planet or lit ground, as wide as the centroid "
                             "window", "ratio", min=1.0, max=1000.0)
    min_sky_sectors: int = knob(3, "default: mask a candidate with fewer of the eight sectors "
                                "around it (3.5 PSF sigmas out) at the sky's level and noise: a "
                                "bump on lit terrain, foliage or a planet's disc; also one on a "
                                "thin line of light (a crescent, a ghost's ring) or sharing a "
                                "clipped plateau with another (0 = off, all three; a star "
                                "beside such a body keeps the sectors on the sky side)",
                                "sectors", min=0, max=8)
    saturation_adu: float | None = knob(None, "default: level flagged SATURATED; null = "
                                        "full scale of the bit depth", "ADU", min=1.0)
    max_candidates: int = knob(2048, "default: local maxima examined per frame (brightest "
                               "kept)", "maxima", min=1, max=1000000)
    max_pixels_above: int = knob(262144, "default: pixels above threshold examined per "
                                 "frame; more raise the threshold (reason 'crowded')",
                                 "pixels", min=1, max=100000000)
    threads: int = knob(2, "default: threads sharing the full-frame passes: the Gaussian "
                        "filter and threshold tests in horizontal slabs, the median and the "
                        "float copy on a worker beside the Python work (1 = the calling "
                        "thread alone; the Pi 5 has 4 cores)", "threads", min=1, max=16)
    opencv_threads: int = knob(1, "threads OpenCV's own parallel loops may use inside each "
                               "call (cv2.setNumThreads, for the whole process): 1 = none, "
                               "the slabs above being the detector's parallelism (a pool "
                               "under each slab competes with them for the cores); 0 = "
                               "OpenCV's default (every core)", "threads", min=0, max=16)


@dataclass(frozen=True)
class IdentifyConfig:
    """Star identification (tracker.identify)."""

    enabled: bool = knob(True, "identify stars and solve attitude")
    database: str | None = knob(None, "pattern database file; null = the one designed for "
                                "the camera section (the same design and catalogue, nothing "
                                "else), from the package's data folder or the cache folder, "
                                "built there on first use", "path")
    cache_dir: str | None = knob(None, "folder of built pattern databases; null = "
                                 "$STATE_DIRECTORY (the systemd unit's StateDirectory), else "
                                 "$XDG_CACHE_HOME/startracker, else ~/.cache/startracker",
                                 "path")
    focal_tolerance: float = knob(0.06, "lost in space finds the focal length within this "
                                  "fraction of camera.focal_length_mm (0.06 covers a label "
                                  "up to 5 % off either way)", "fraction", min=0.0, max=0.3)
    focal_search: float = knob(0.3, "when lost in space fails, search this wider fraction to "
                               "say which focal length the stars fit (the frame stays "
                               "failed); 0 = off", "fraction", min=0.0, max=0.5)
    distortion_px: float = knob(3.0, "prior on the radial distortion (k1) to fit: one sigma "
                                "of its displacement at the image corner", "px", min=0.0,
                                max=1000.0)
    lens_time_constant_s: float = knob(600.0, "memory of the slow filter of focal length "
                                       "and k1 over solved frames (they drift with "
                                       "temperature); 0 = no forgetting", "s", min=0.0,
                                       max=1e7)
    pattern_stars: int = knob(12, "brightest image stars whose four-star patterns lost in "
                              "space tries (in brightness order; if that finds nothing, once more "
                              "with those the detector flagged saturated, elongated or at "
                              "the edge last)", "stars", min=4,
                              max=64)
    verify_stars: int = knob(40, "brightest image stars checked against a hypothesis "
                             "(in the order pattern_stars are drawn)", "stars", min=5,
                             max=1024)
    pattern_tolerance_px: float = knob(2.0, "largest error expected on the length of a "
                                       "pattern's edge (centroid errors plus unmodelled "
                                       "distortion)", "px", min=0.01, max=100.0)
    match_radius_px: float = knob(1.0, "an image star matches a predicted catalogue star "
                                  "within this distance; the chance of a false match grows "
                                  "with its square, so keep it a few times the centroid "
                                  "and calibration error", "px", min=0.01, max=100.0)
    max_prob_false: float = knob(1e-6, "accept a match only if the chance that it is wrong "
                                 "is below this (per frame; tracker.identify.verify)",
                                 "probability", min=1e-30, max=0.5)
    min_matched: int = knob(5, "fewest matched stars for an accepted attitude", "stars",
                            min=5, max=1000)
    max_patterns: int = knob(500, "lost in space: most image patterns looked up per frame "
                             "(a work budget: the same stars give the same answer on any "
                             "machine)", "patterns", min=1, max=100000)
    max_hypotheses: int = knob(500, "lost in space: most hypotheses verified per frame",
                               "hypotheses", min=1, max=100000)
    min_separation_px: float = knob(8.0, "patterns with two stars closer together than "
                                    "this are not tried", "px", min=0.0, max=10000.0)
    duplicate_px: float = knob(0.5, "centroids closer than this are one star (the fainter "
                               "is dropped)", "px", min=0.0, max=100.0)
    centroid_sigma_px: float = knob(0.25, "prior centroid noise per axis, blended with the "
                                    "fit residuals for the reported sigmas (the attitude's "
                                    "per-star weights are the centroids' own: "
                                    "tracker.identify.predict.centroid_variance)", "px",
                                    min=0.001, max=100.0)
    mag_tolerance: float = knob(1.5, "a match is dropped when its catalogue magnitude is "
                                "this far from the one its flux implies (zero point: "
                                "median over the frame's matches)", "mag", min=0.1,
                                max=20.0)
    track_gate_px: float = knob(12.0, "tracking: predicted stars are searched this far "
                                "from their prediction", "px", min=0.1, max=1000.0)
    track_max_gap_s: float = knob(2.0, "tracking: predict only from a solution this recent",
                                  "s", min=0.0, max=3600.0)
    rate_valid_sigma_deg_s: float = knob(0.2, "the rate is reported (ATTITUDE RATE_VALID) "
                                         "only when its 1-sigma is below this on every "
                                         "axis", "deg/s", min=0.0001, max=100.0)
    track_windows: bool = knob(True, "tracking with a known rate detects only in windows "
                               "around the predicted stars, plus a slice of the frame; "
                               "false: the whole frame every frame")
    track_stamps: bool = knob(True, "windowed tracking detects in its windows by the lean "
                              "stacked-window detector (tracker.detect.stamps), the full "
                              "detector over a mosaic of them only on the frames that "
                              "measure the PSF (one in track_lens_every); false: the "
                              "mosaic every frame")
    track_window_stars: int = knob(32, "tracking: most predicted catalogue stars given a "
                                   "window (those carrying track_window_information, "
                                   "brightest first)", "stars", min=4, max=1024)
    track_window_information: float = knob(0.95, "tracking: windows for the fewest "
                                           "predicted stars that carry this share of the "
                                           "attitude's information, cross-boresight and "
                                           "roll each (1/sigma^2 of their centroids from "
                                           "the SNR the last matches predict)", "",
                                           min=0.1, max=1.0)
    track_window_mag_margin: float = knob(0.5, "tracking: windows only for predicted stars "
                                          "at most this much fainter than the faintest "
                                          "star matched lately (that limit falls by 0.02 "
                                          "mag a frame at most)", "mag", min=0.0, max=30.0)
    track_window_unknown: int = knob(4, "tracking: unidentified stars of the last frame "
                                     "(brightest) followed in windows too", "stars", min=0,
                                     max=256)
    track_sweep_windows: int = knob(4, "tracking: fewest windows a frame that sweep the "
                                    "whole frame in turn (new stars, surprises); windows "
                                    "not needed by stars sweep too", "windows", min=0,
                                    max=1024)
    track_window_sigma: float = knob(3.0, "tracking: window half-width in radial sigmas of "
                                     "the predicted position (plus half the exposure's "
                                     "smear and the PSF's reach)", "sigma", min=1.0,
                                     max=20.0)
    track_accel_deg_s2: float = knob(2.0, "tracking: angular acceleration (1 sigma per axis) "
                                     "the prediction allows between frames", "deg/s^2",
                                     min=0.0, max=1000.0)
    track_lens_every: int = knob(10, "windowed tracking fits the lens (focal length, k1) and "
                                 "measures the PSF in its windows on one frame in this many; "
                                 "the others take the filtered lens and the PSF as it stands",
                                 "frames", min=1, max=100000)
    track_window_max_px: int = knob(96, "tracking: largest window; a prediction needing "
                                    "more is searched in the whole frame", "px", min=16,
                                    max=1024)


@dataclass(frozen=True)
class LinkConfig:
    """Serial link to the flight computer (tracker.protocol)."""

    port: str = knob("/dev/ttyAMA0", "serial device of the flight-computer UART (or a "
                     "pyserial URL)")
    baudrate: int = knob(921600, "UART speed; 8N1, so baudrate/10 bytes per second", "baud",
                         min=1200, max=4000000)
    bandwidth_fraction: float = knob(0.9, "share of baudrate/10 the writer may use; it "
                                     "paces itself so queue priority, not the kernel buffer, "
                                     "decides what goes first", "fraction", min=0.05,
                                     max=1.0)
    attitude_rate_hz: float = knob(30.0, "ATTITUDE output rate; 0 = off (SET_OUTPUT "
                                   "changes it at run time)", "Hz", min=0.0, max=100.0)
    centroids_rate_hz: float = knob(1.0, "CENTROIDS output rate; 0 = off", "Hz",
                                    min=0.0, max=100.0)
    status_rate_hz: float = knob(1.0, "STATUS output rate; 0 = off", "Hz", min=0.0,
                                 max=100.0)
    max_centroids: int = knob(48, "most stars sent per frame in CENTROIDS (brightest "
                              "first), over several packets of up to 40", "stars",
                              min=0, max=1020)
    queue_attitude: int = knob(4, "ATTITUDE packets waiting to be sent; when full the "
                               "oldest is dropped", "packets", min=1, max=1024)
    queue_replies: int = knob(256, "ACK/NACK replies waiting; a burst of up to this many "
                              "commands gets every reply, a longer flood sheds the oldest",
                              "packets", min=1, max=65536)
    queue_centroids: int = knob(8, "CENTROIDS packets waiting; oldest dropped when full",
                                "packets", min=1, max=1024)
    queue_status: int = knob(2, "STATUS packets waiting; oldest dropped when full",
                             "packets", min=1, max=1024)
    max_age_ms: float = knob(500.0, "a queued telemetry packet older than this is dropped "
                             "unsent (replies are not)", "ms", min=1.0, max=60000.0)
    write_timeout_s: float = knob(0.5, "a write to the port that takes longer counts as a "
                                  "port error (the port is reopened)", "s", min=0.01,
                                  max=60.0)
    read_timeout_s: float = knob(0.05, "longest wait of the reader for command bytes", "s",
                                 min=0.001, max=5.0)
    reopen_backoff_s: float = knob(0.5, "first wait before reopening a failed port; "
                                   "doubles after each failure", "s", min=0.01, max=60.0)
    reopen_backoff_max_s: float = knob(8.0, "longest wait between reopen attempts", "s",
                                       min=0.01, max=600.0)


@dataclass(frozen=True)
class CaptureConfig:
    """Where frames come from (tracker.capture)."""

    backend: str = knob("replay", "frame source", choices=("replay", "picamera2", "v4l2"))
    replay_path: str | None = knob(None, "file or folder replayed by the replay backend")
    loop: bool = knob(False, "replay: start again after the last file")
    fps: float = knob(0.0, "frames per second; 0 = replay as fast as possible, live: the "
                      "longest frame the exposure allows", "Hz", min=0.0, max=1000.0)
    replay_interval_s: float = knob(0.1, "replay: the time between frames whose files carry "
                                    "no recorded t_ns when fps is 0 (with fps > 0: 1/fps); "
                                    "they are stamped start + index x interval, so a replay's "
                                    "answer does not depend on how fast it runs", "s",
                                    min=1e-4, max=3600.0)
    device: str = knob("0", "live: picamera2 camera number; v4l2: which rp1-cfe with a sensor "
                       "(its number among them, or /dev/mediaN)")
    raw_format: str = knob("R16", "raw format asked for; picamera2: the granted one is "
                           "checked and *_PISP_COMP* (lossy) refused; v4l2: R16 = Y16 (the CFE "
                           "unpacks), R10_CSI2P = Y10P, R8 = GREY",
                           choices=("R16", "R10", "R8", "R10_CSI2P", "R8_CSI2P"))
    raw_shift: int = knob(6, "right shift applied to 16-bit raw words (6: 10-bit data in the "
                          "high bits of R16, unverified on the Pi: `tracker selftest` says "
                          "which bits vary)", "bit", min=0, max=8)
    exposure_us: float = knob(20000.0, "starting exposure time", "us", min=10.0,
                              max=2_000_000.0)
    exposure_min_us: float = knob(100.0, "exposure control: shortest exposure", "us",
                                  min=10.0, max=2_000_000.0)
    exposure_max_us: float = knob(100000.0, "exposure control: longest exposure", "us",
                                  min=10.0, max=2_000_000.0)
    gain: float = knob(4.0, "starting analogue gain", "x", min=1.0, max=64.0)
    gain_max: float = knob(16.0, "exposure control: highest analogue gain", "x",
                           min=1.0, max=64.0)
    gain_code_per_x: float = knob(100.0, "v4l2: the sensor's ANALOGUE_GAIN control units "
                                  "per 1x gain (arducam-pivariety: 100, as its libcamera "
                                  "helper)", "code", min=1.0, max=1e6)
    auto_exposure: bool = knob(True, "adjust exposure and gain to keep stars detectable "
                               "and unsaturated")
    target_peak: float = knob(0.5, "exposure control: wanted brightest-star peak as a "
                              "fraction of full scale", "", min=0.05, max=0.95)
    buffer_count: int = knob(4, "live: camera buffers queued", min=2, max=16)
    timeout_s: float = knob(2.0, "live: a frame later than its period plus this is lost "
                            "(camera_timeout); three in a row and the camera is reopened",
                            "s", min=0.05, max=60.0)


@dataclass(frozen=True)
class ServiceConfig:
    """The daemon loop (tracker.daemon)."""

    log_level: str = knob("INFO", "logging threshold",
                          choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    frames: int = knob(0, "stop after this many frames; 0 = run until stopped", min=0)
    watchdog_s: float = knob(10.0, "in-process stall watchdog: a loop stuck this long dumps "
                             "its stacks and exits for systemd to restart it; 0 = off", "s",
                             min=0.0, max=3600.0)
    status_period_s: float = knob(1.0, "interval of systemd STATUS lines (STATUS packets: "
                                  "link.status_rate_hz)", "s", min=0.05, max=3600.0)
    retry_initial_s: float = knob(0.5, "first wait before reopening a failed camera", "s",
                                  min=0.01, max=60.0)
    retry_max_s: float = knob(1.0, "longest wait between camera reopen attempts (doubling "
                              "backoff); a camera that comes back is streaming within "
                              "about this long", "s", min=0.01, max=600.0)
    track_after: int = knob(2, "consecutive solved frames before lost_in_space becomes "
                            "tracking", min=1, max=1000)
    lost_after: int = knob(3, "consecutive unsolved frames before tracking falls back to "
                           "lost_in_space", min=1, max=1000)
    fault_after: int = knob(20, "consecutive failed frames (unreadable, late, stage error) "
                            "before the mode is fault (no camera: at once)", min=1,
                            max=100000)
    start_state: str = knob("lost_in_space", "mode at start; standby waits for the flight "
                            "computer's SET_MODE", choices=("standby", "lost_in_space"))
    capture_ahead: str = knob("live", "capture the next frame in a thread of its own while "
                              "this one is processed: live (cameras; the newest frame is "
                              "processed next, one left waiting is superseded), always "
                              "(replay too, nothing superseded), never (one thread: capture, "
                              "then process)", choices=("live", "always", "never"))


@dataclass(frozen=True)
class TimeConfig:
    """Absolute time and the observer's velocity (tracker.daemon.timebase)."""

    system_clock: str = knob(
        "never", "use the tracker's own clock (UTC, leap seconds from the table) as "
        "absolute time until the flight computer's TIME_SYNC: never; synchronised (while "
        "the kernel says NTP or PTP keeps it within 16 s: adjtimex, as timedatectl); always "
        "(a clock set by other means, e.g. a battery-backed RTC); tracker record writes utc "
        "under the same rule", choices=("never", "synchronised", "always"))
    velocity_max_age_s: float = knob(
        10.0, "a SET_VELOCITY further than this from a frame's time is stale and not "
        "applied (in low Earth orbit the velocity turns 0.066 deg/s: 0.006 arcsec of "
        "aberration error per second of age)", "s", min=0.001, max=86400.0)


@dataclass(frozen=True)
class Config:
    """The whole configuration; one attribute per section."""

    camera: CameraConfig = CameraConfig()
    catalogue: CatalogueConfig = CatalogueConfig()
    sim: SimConfig = SimConfig()
    detect: DetectConfig = DetectConfig()
    identify: IdentifyConfig = IdentifyConfig()
    link: LinkConfig = LinkConfig()
    capture: CaptureConfig = CaptureConfig()
    service: ServiceConfig = ServiceConfig()
    time: TimeConfig = TimeConfig()


# --------------------------------------------------------------------------
# Loading and validation
# --------------------------------------------------------------------------


def _expectation(tp: Any, meta: dict) -> str:
    """Human wording of what a key accepts."""
    base = typing.get_origin(tp)
    args = typing.get_args(tp)
    nullable = base in (typing.Union, types.UnionType) and type(None) in args
    if nullable:
        tp = next(a for a in args if a is not type(None))
    if meta.get("choices"):
        text = "one of " + ", ".join(repr(c) for c in meta["choices"])
    else:
        text = {int: "an integer", float: "a number", str: "a string",
                bool: "true or false"}.get(tp, str(tp))
        if typing.get_origin(tp) is tuple:
            text = "a list of numbers"
        lo, hi = meta.get("min"), meta.get("max")
        if lo is not None and hi is not None:
            text += f" in [{lo:g}, {hi:g}]"
        elif lo is not None:
            text += f" >= {lo:g}"
        elif hi is not None:
            text += f" <= {hi:g}"
    return text + (" or null" if nullable else "")


def _coerce(value: Any, tp: Any, meta: dict) -> Any:
    """Return value converted to tp, or raise ValueError if it does not fit."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        tp = next(a for a in args if a is not type(None))
        origin = typing.get_origin(tp)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError
        return tuple(_coerce(v, typing.get_args(tp)[0], {}) for v in value)
    if tp is bool:
        if not isinstance(value, bool):
            raise ValueError
    elif tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError
        value = float(value)
        if value != value or value in (float("inf"), float("-inf")):
            raise ValueError
    elif tp is str:
        if not isinstance(value, str):
            raise ValueError
    if meta.get("choices") and value not in meta["choices"]:
        raise ValueError
    if meta.get("min") is not None and value < meta["min"]:
        raise ValueError
    if meta.get("max") is not None and value > meta["max"]:
        raise ValueError
    return value


def _build_section(cls: type, data: Any, where: str, source: str) -> Any:
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {where}: found {_show(data)}, expected a mapping of keys")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"{source}: {where}.{_name(key)}: found an unknown key, expected "
                              f"one of: {known}")
        meta = dict(fields[key].metadata)
        try:
            values[key] = _coerce(value, hints[key], meta)
        except ValueError:
            raise ConfigError(f"{source}: {where}.{key}: found {_show(value)}, expected "
                              f"{_expectation(hints[key], meta)}") from None
    return cls(**values)


_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxtuple = 2, 4, 4, 4
_REPR.maxstring, _REPR.maxlong, _REPR.maxother = 50, 30, 50


def _show(value: Any) -> str:
    """A value as the message shows it: its repr cut short (never the whole of a huge one)."""
    text = _REPR.repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def _name(key: Any) -> str:
    """A key as the message shows it."""
    text = str(key) if isinstance(key, str) else _REPR.repr(key)
    return text if len(text) <= 40 else text[:37] + "..."


def config_from_dict(data: Any, source: str = "<config>") -> Config:
    """Validate a parsed YAML document and return the frozen Config."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: (top level): found {_show(data)}, expected a mapping "
                          "of sections")
    hints = typing.get_type_hints(Config)
    sections = {}
    for name, value in data.items():
        if name not in hints:
            known = ", ".join(f.name for f in dataclasses.fields(Config))
            raise ConfigError(f"{source}: {_name(name)}: found an unknown section, expected "
                              f"one of: {known}")
        sections[name] = _build_section(hints[name], value, name, source)
    return check_config(Config(**sections), source)


def load_config(path: str | Path | None) -> Config:
    """Load and validate a YAML configuration file; None gives the defaults.

    The file must be a regular file of at most :data:`MAX_CONFIG_BYTES`; its
    YAML is read within the bounds of :mod:`tracker.yaml_bounded` (YAML 1.2
    scalars, duplicate keys refused), then every key is checked against its
    declaration and the keys against each other (:func:`check_config`).
    """
    if path is None:
        return Config()
    path = Path(path)
    try:
        text = read_regular_file(path, MAX_CONFIG_BYTES).decode("utf-8")
    except FileRefused as exc:
        raise ConfigError(f"{path}: cannot read the file: {exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: found bytes that are not UTF-8, expected a YAML text "
                          "file") from None
    try:
        data = parse_yaml(text)
    except YamlError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return config_from_dict(data, str(path))


# The largest configuration file read, in bytes (a full one with comments is ~20 KB).
MAX_CONFIG_BYTES = 1 << 20

# The largest sensor, width x height in pixels (2**25, e.g. 6144 x 5461): the
# default detector needs about 40 bytes per pixel (1.3 GB here), and image
# files are decoded only up to the configured camera's size.
MAX_SENSOR_PIXELS = 1 << 25

# Keys whose values must not decrease along each chain: a configuration where
# they do cannot work (an empty exposure range, a backoff that starts above its
# ceiling, a match count that the stars checked can never reach).
ORDERED_KEYS = (
    ("capture", ("exposure_min_us", "exposure_us", "exposure_max_us")),
    ("capture", ("gain", "gain_max")),
    ("service", ("retry_initial_s", "retry_max_s")),
    ("link", ("reopen_backoff_s", "reopen_backoff_max_s")),
    ("identify", ("pattern_stars", "verify_stars")),
    ("identify", ("min_matched", "verify_stars")),
)


def check_config(cfg: Config, source: str = "<config>") -> Config:
    """The checks across keys: :data:`ORDERED_KEYS`, the sensor size and principal point.

    Returns ``cfg``; raises :class:`ConfigError` naming the first key at fault.
    """
    for section, chain in ORDERED_KEYS:
        values = getattr(cfg, section)
        # the widest pair first: min > max is named as such, not as min > start
        pairs = sorted(((i, j) for i in range(len(chain)) for j in range(i + 1, len(chain))),
                       key=lambda ij: ij[0] - ij[1])
        for i, j in pairs:
            low, high = chain[i], chain[j]
            a, b = getattr(values, low), getattr(values, high)
            if a > b:
                raise ConfigError(
                    f"{source}: {section}.{low}: found {a:g}, more than {section}.{high} "
                    f"({b:g}), expected {low} <= {high}")
    cam = cfg.camera
    if cam.width * cam.height > MAX_SENSOR_PIXELS:
        raise ConfigError(
            f"{source}: camera.width x camera.height: found {cam.width} x {cam.height} = "
            f"{cam.width * cam.height:,} pixels, expected at most {MAX_SENSOR_PIXELS:,}")
    for key, size in (("cx", cam.width), ("cy", cam.height)):
        value = getattr(cam, key)
        if value is not None and not -0.5 <= value <= size - 0.5:
            raise ConfigError(f"{source}: camera.{key}: found {value:g}, expected a pixel "
                              f"inside the image, in [-0.5, {size - 0.5:g}]")
    return cfg


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------


def _yaml_scalar(value: Any) -> str:
    if isinstance(value, tuple):
        return "[" + ", ".join(_yaml_scalar(v) for v in value) + "]"
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("\n...")


def render_yaml(config: Config, comments: bool = True) -> str:
    """The configuration as YAML, each key preceded by its description and unit."""
    lines: list[str] = []
    for section in dataclasses.fields(config):
        obj = getattr(config, section.name)
        if comments:
            lines.append(f"# {(type(obj).__doc__ or '').strip().splitlines()[0]}")
        lines.append(f"{section.name}:")
        for f in dataclasses.fields(obj):
            if comments:
                unit = f" [{f.metadata['unit']}]" if f.metadata.get("unit") else ""
                lines.append(f"  # {f.metadata['doc']}{unit}")
            lines.append(f"  {f.name}: {_yaml_scalar(getattr(obj, f.name))}")
        lines.append("")
    return "\n".join(lines)


def config_checksum(config: Config) -> int:
    """CRC-32-sized digest (first 4 bytes of SHA-256) of the effective configuration."""
    digest = hashlib.sha256(render_yaml(config, comments=False).encode()).digest()
    return int.from_bytes(digest[:4], "big")


def iter_knobs():
    """Yield (section, key, default, unit, doc) for every key of the configuration."""
    hints = typing.get_type_hints(Config)
    for section in dataclasses.fields(Config):
        for f in dataclasses.fields(hints[section.name]):
            yield section.name, f.name, f.default, f.metadata.get("unit", ""), f.metadata["doc"]


def render_markdown_table() -> str:
    """Every key as a Markdown table: the README's configuration reference."""
    rows = ["| key | default | unit | what it does |", "|---|---|---|---|"]
    for section, key, default, unit, doc in iter_knobs():
        shown = _yaml_scalar(default).replace("|", "\\|")
        rows.append(f"| `{section}.{key}` | `{shown}` | {unit} | {doc.replace('|', '/')} |")
    return "\n".join(rows) + "\n"
