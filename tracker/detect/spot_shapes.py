"""The shape judgement of the centroided spots: sharp spots and broad ones, against the PSF.

Given the windowed moments of every candidate (tracker.detect.windowed's
``v``: flux, peak, size = weighted Mxx + Myy in px^2, ellipticity, pixel-scale
roughness, SNR) and the PSF they were measured under:

* :func:`sharp_spots`: spots much narrower than the PSF, or rougher at the
  pixel scale than a star of their flux (cosmic-ray clusters that survived
  the impulse stages; tracker.detect.roughness), are sharp (fainter ones when
  narrower than a star beyond their noise); so are saturated spots holding
  less light than the PSF's area times their clipped peak (judged at any
  SNR: on glare a track's SNR is low, its shape still plain). The test of a
  faint spot's 3 x 3 for a point (tracker.detect.point_spot) needs the
  frame's pixels and stays with the detector.
* :func:`broad_spots`: flux/peak (a spot's effective area) well above the
  frame's median is EXTENDED (a nebula, a lit branch) or a body (a ghost's
  disc, a planet, lit ground).
* :func:`common_elongation`: how much the frame's significant spots are
  elongated alike (a trailed frame), for the surroundings' line test.

A spot's width is its second moment across its narrowest axis over a round
star's of the PSF (1 for a star; tracker.detect.star_width's convention).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from tracker.config import DetectConfig
from tracker.detect.order import median
from tracker.detect.psf import PsfEstimate
from tracker.detect.roughness import StarRoughness
from tracker.detect.star_width import sharper_than_stars

__all__ = ["STAR_ELLIPTICITY", "STAR_WIDTH", "broad_spots", "common_elongation", "sharp_spots"]

_ROUGH_REFERENCE_SNR = 30.0    # spots this bright set the frame's roughness scale
_ROUGH_SPREADS = 4.0           # rougher than a star by this many of its noise's spreads
STAR_WIDTH = math.log(1.25)    # a spot whose width is within 25 % of the PSF's ...
STAR_ELLIPTICITY = 0.2         # ... and this round looks like a star
_TRACK_WIDTH = 0.6             # a spot this narrow across (PSF = 1) and ...
_TRACK_ELLIPTICITY = 0.3       # ... this elongated is a particle's track
_TRACK_EXCESS = 0.35           # a spot this much more elongated than the frame's PSF ...
_SATURATED_TRACK_EXCESS = 0.2  # ... or, saturated, this much, is a particle's track
_SHARP_WIDTH_SPREADS = 4.0     # narrower than the frame's stars by this many spreads: sharp
_STAR_WIDTH_SNR = 30.0         # star-like spots this significant set the frame's star width
_CLIPPED_AREA = 0.6            # a saturated spot's flux/peak under this x the PSF's is sharp
_WIDTH_SPREADS = 4.0           # below sharp_min_snr: narrower than a star by this many spreads,
_MEASURED_WIDTH_SPREADS = 3.0  # ... or this many when the frame's stars measured its PSF
_REMNANT_WIDTH = 0.85          # a spot this narrow and ...
_REMNANT_ROUGH = 3.0           # ... this rough (x a star's of its flux) is a track's remnant
_ELONGATION_SNR = 20.0         # spots this significant tell a trailed frame


def sharp_spots(v: dict, noise: np.ndarray, known: np.ndarray, judged: np.ndarray,
                saturated: np.ndarray, clipped: np.ndarray, cfg: DetectConfig,
                psf: PsfEstimate, expected_size: float, phase_low: float,
                roughness: StarRoughness, multiplicative: bool) -> np.ndarray:
    """The spots sharper than the optics deliver (a particle's charge or track, a hot
    pixel): (n,) bool.

    ``noise``: each spot's pixel noise (ADU); ``known``: its SNR with its own
    shot noise (tracker.detect.significance); ``judged``: the spots whose shape
    is known (``known >= sharp_min_snr``, or clipped); ``saturated``: a pixel at
    full scale; ``clipped``: saturated by light, not noise; ``psf``: the PSF
    searched with (``stars`` > 0: measured on this frame); ``expected_size``: a
    round star's weighted Mxx + Myy under it (px^2); ``phase_low``: the lowest
    pixel phase's width (tracker.detect.star_width); ``multiplicative``: noise
    proportional to the light, under which a star's pixels are spiky and only
    ``judged`` (then all false) applies.
    """
    # Second moment across the spot's narrowest axis: a PSF's is half its size,
    # and a star streaked by motion keeps it, while a cosmic-ray hit or track
    # is a pixel or so wide. Moments of no positive spot (what impulse
    # rejection leaves of a track) count as narrow.
    narrowest = 0.5 * v["size"] * (1.0 - v["ellipticity"])
    spot = (v["weighted"] > 0) & (v["size"] > 0) & (v["ellipticity"] <= 1.0)
    width = narrowest / (0.5 * expected_size)     # 1 for a star of this PSF
    star_like = judged & spot & (np.abs(np.log(np.maximum(width, 1e-6))) < STAR_WIDTH) & (
        v["ellipticity"] < STAR_ELLIPTICITY)
    rougher = _rougher_than_a_star(v, noise, star_like, roughness)
    # a line narrower than the PSF (a track; a trailed star keeps the PSF's width), or
    # a narrow spot rough at the pixel scale (a track's remnant)
    track = ((width < _TRACK_WIDTH) & (v["ellipticity"] > _TRACK_ELLIPTICITY)) | (
        (width < _REMNANT_WIDTH) & rougher(_REMNANT_ROUGH))
    if psf.stars:
        # against a PSF measured on this frame: a spot far more elongated than its
        # stars is a particle's track, whatever its width (a charge cloud diffused
        # over two pixels is as wide as a sharp PSF), a saturated one the more so (a
        # saturated star's clipped top is as round as its PSF)
        excess = v["ellipticity"] - psf.ellipticity
        track |= (excess > _TRACK_EXCESS) | (saturated & (excess > _SATURATED_TRACK_EXCESS))
        # a spot narrower than the frame's stars across their narrowest axis (a
        # trailed frame's stars are narrow across the trail) by more than its width's
        # noise, the lens's field and its pixel phase allow: a particle's charge
        # diffused over a pixel or two, as wide as a sharp PSF (0.45 px against
        # 0.6-0.8) but not as the frame's own (tracker.detect.star_width)
        track |= ~saturated & sharper_than_stars(
            width, known, _star_width(v, star_like, saturated, expected_size, psf),
            phase_low, _SHARP_WIDTH_SPREADS)
    # clipping only widens a star (its flux over its clipped peak grows), so a
    # saturated spot holding less light than the PSF's area times its clipped peak
    # is sharper than the optics: a particle's charge
    track |= clipped & (v["flux"] < _CLIPPED_AREA * 2.0 * math.pi * expected_size * v["peak"])
    narrow = ~spot | (width < cfg.sharp_size_ratio) | track
    sharp = judged & (narrow | rougher(cfg.rough_ratio))
    # Fainter, a spot's width is known to about sqrt(2) / SNR of a star's (the spread
    # of a second moment under the matched Gaussian weight, from the weighted noise,
    # whatever the spot's own width): one narrower than ``sharp_size_ratio``, and
    # than a star by more than _WIDTH_SPREADS of that spread, is a hot pixel or a
    # particle's hit the impulse stage left (its noisy 3x3 median or neighbours
    # made it look like a star's light). Against a PSF this frame's stars measured
    # a star's width is known, and 3 spreads suffice (a faint star is lost 1 time
    # in 700); against one from elsewhere the frame's stars may be sharper than it
    if not multiplicative:
        sharp |= spot & (width < cfg.sharp_size_ratio) & (
            (1.0 - width) * known > math.sqrt(2.0) * (
                _MEASURED_WIDTH_SPREADS if psf.stars else _WIDTH_SPREADS))
    return sharp


def _star_width(v: dict, star_like: np.ndarray, saturated: np.ndarray, expected_size: float,
                psf: PsfEstimate) -> float:
    """The width of the frame's stars (tracker.detect.star_width's convention): the
    median over its unsaturated star-like spots at SNR >= ``_STAR_WIDTH_SNR``, or,
    for fewer than five, its measured PSF's across its narrowest axis."""
    bright = star_like & ~saturated & (v["snr"] >= _STAR_WIDTH_SNR)
    if np.count_nonzero(bright) >= 5:
        narrowest = 0.5 * v["size"][bright] * (1.0 - v["ellipticity"][bright])
        return float(median(narrowest)) / (0.5 * expected_size)
    return 1.0 - psf.ellipticity


def _rougher_than_a_star(v: dict, noise: np.ndarray, star_like: np.ndarray,
                         model: StarRoughness) -> Callable[[float], np.ndarray]:
    """A test of the spots' pixel-scale roughness (tracker.detect.windowed) against a
    star's of the same flux on the same noise (tracker.detect.roughness).

    ``rougher(k)`` is true of a spot rougher than k times what such a star
    reads, and by more than ``_ROUGH_SPREADS`` of its noise's spread (a
    faint star's roughness is mostly its own shot noise's and the
    background's, and spreads by a third of itself at SNR 35). Both are
    scaled by the median over the frame's bright spots that look like its
    stars (``star_like``: width within 25 % of the PSF's, round) of their
    roughness over a star's, if above one: noise that scales with the
    light (speckle, a fraction of a photon per pixel) or optics sharper
    at the core than a Gaussian roughen every star alike, and a star is
    not rejected for it, while cosmic-ray clusters, narrower or
    elongated, do not set the scale.
    """
    flux = v["flux"]
    expected = model.expected(flux)
    margin = expected + _ROUGH_SPREADS * model.spread(flux, noise)
    bright = star_like & (v["snr"] >= _ROUGH_REFERENCE_SNR)
    scale = 1.0
    if np.count_nonzero(bright) >= 5:
        scale = max(scale, median(v["rough"][bright] / expected[bright]))
    rough = v["rough"] / scale

    def rougher(k: float) -> np.ndarray:
        return (rough > k * expected) & (rough > margin)

    return rougher


def broad_spots(v: dict, sharp: np.ndarray, saturation: float,
                cfg: DetectConfig) -> tuple[np.ndarray, np.ndarray]:
    """(EXTENDED, body): flux/peak above ``extended_ratio`` / ``body_ratio`` x the median.

    A point source's flux/peak (its effective area) is fixed by the PSF
    (2 pi sigma^2 for a Gaussian) whatever its brightness; a nebula,
    comet or lit branch spreads its flux wider (EXTENDED, reported), and
    a maximum on a ghost's disc, a planet or lit ground is as wide as the
    window itself (a body: masked). The frame's own median is the
    reference, so an unknown or field-varying PSF needs no configuration.
    Saturated spots (``raw_peak`` at ``saturation``, ADU: flat tops) and
    rejected ``sharp`` ones are neither judged nor part of the median; fewer
    than five such sources give no reference. Under multiplicative noise
    nothing is judged (the caller's part: a spot's peak is one speckle).
    """
    n = len(sharp)
    unsat = (v["raw_peak"] < saturation) & ~sharp
    none = np.zeros(n, bool)
    if np.count_nonzero(unsat) < 5:
        return none, none
    area = v["flux"] / np.maximum(v["peak"], 1e-12)
    reference = median(area[unsat])
    return (unsat & (area > cfg.extended_ratio * reference),
            unsat & (area > cfg.body_ratio * reference))


def common_elongation(v: dict, n: int, saturation: float, blended: np.ndarray) -> float:
    """How elongated the frame's significant spots are in one direction: the length of
    their mean ellipticity vector ((Mxx - Myy, 2 Mxy) / (Mxx + Myy) of the windowed
    moments), over the first ``n`` candidates' unsaturated (``raw_peak`` under
    ``saturation``, ADU), unblended ones at SNR >= 20; 0 for fewer than 5.

    A slewing camera trails every star alike (the PSF meter, which takes round
    stars, does not see it); particle tracks and a crescent's pieces point every
    way, and round stars not at all.
    """
    use = (v["snr"][:n] >= _ELONGATION_SNR) & (v["raw_peak"][:n] < saturation) & ~blended[:n]
    if np.count_nonzero(use) < 5:
        return 0.0
    mxx, myy, mxy = v["mxx"][:n][use], v["myy"][:n][use], v["mxy"][:n][use]
    size = np.maximum(mxx + myy, 1e-12)
    return float(np.hypot(np.mean((mxx - myy) / size), np.mean(2.0 * mxy / size)))
