"""The project's detector: robust background, impulse rejection, the PSF measured, matched filter.

Per frame, with every buffer made at construction for one frame shape and
``detect.max_stars`` (PSF-dependent parts are rebuilt only when the PSF
moves by more than a few per cent, and never grow beyond the widest PSF
handled, sigma 3.5 px):

1. ``input``: check the frame and copy it into a zero-bordered uint16
   buffer (tracker.detect.frame_input; bad frames give a reason code; other
   dtypes are clipped to 0..full scale and rounded to whole ADU). Integer
   images halve the memory traffic of the full-frame passes up to the
   filter (the detector is memory-bound), and OpenCV's median is faster on
   them.
2. ``background``: per-tile median and low-side noise on a coarse grid,
   3x3-median-filtered and interpolated to full size (tracker.detect.background).
   Tiles across a body's edge (or with a sliver of it in their brightest
   tenth, or with a strip of sky beside saturated ground) take the sky's
   statistics from their sky pixels (tracker.detect.sky_split), and sky tiles
   beside a saturated one (lit ground, the Earth) keep their own level and
   threshold rather than a blend with full scale. Where such a tile (across the
   edge or beside a saturated one) is at the sky's level, the 3x3 median of its
   filtered statistics (step 5) is taken over its sky neighbours only, not over
   the ground's tiles below it. A smooth tile (its pixel and filtered noise within
   1.6 times the smooth sky's at its level) beside a body's tile that is not smooth
   keeps its own threshold over the background, not one interpolated towards the
   spread the body's edge gives that tile's filtered statistics.
3. ``impulses``: hot pixels, cosmic-ray tracks and salt-and-pepper pixels,
   recognised by being much sharper than the sharpest PSF the detector
   handles (sigma 0.45 px), are replaced by their 3x3 median and counted
   (tracker.detect.impulse).
4. ``psf``: the PSF's width and ellipticity measured from the frame's
   brightest isolated, unsaturated stars and smoothed across frames
   (tracker.detect.psf); ``detect.psf_sigma_px`` is only the start. The
   impulse candidates are then tested again against this PSF (a sharper
   cut now that the stars' own sharpness is known), each replaced pixel
   taking the median of its cleaned neighbourhood. A frame with too few
   bright stars for it (a wide PSF's peaks are low) measures it on the
   brightest spots of the frame binned 4 x 4 (tracker.detect.binned: a wide
   star's light summed against a quarter of the noise), on the sky only,
   through the same tests and meter; particles' tracks and sharp hits
   measured among them do not vote in a second try. A PSF measured as
   sharp as a particle's charge is checked there too: round near-normal
   hits of a particle event can outnumber the bright stars and agree on
   it, and where the binned frame's stars agree on one 1.5 times wider,
   theirs is the frame's (the optics never blur a particle's charge, and
   blur every star alike); where only 3-4 binned stars agree on one that
   much wider, beyond their error, the sharp spots were charge all the
   same, and the frame goes unmeasured rather than measured on them. The
   frame is then
   searched once (steps 5-7) with that PSF, the impulses' second pass
   judged against the sharpest PSF handled, and the lone impulse candidates
   (no track beside them) judged against the measured one after the search,
   the stars that were mostly such a pixel dropped (cleared before, a
   particle's hit would leave its wings as a spot). With no measurement the
   frame keeps the estimate of earlier frames (or the configured start),
   and ``psf_stars`` says 0; three agreeing stars, too few to measure it,
   still bound it from below for the lone impulses, and check the estimate
   carried over: when they agree on a PSF over 25 % wider, beyond their
   error (the focus jumped; wider stars are no particles' charge), the frame
   is searched with theirs (``psf_stars`` 3-4), the estimate carried on
   unchanged. The impulses' second pass and the lone ones' test after the
   search are timed as ``impulse_refine``, not as ``psf`` or ``centroid``. A spot
   found on the wings of a particle's hit whose core the second pass replaced alone
   (its neighbours hold a diffused charge's wings, the spot is centred on it, holds
   no more light than they do, and the core stood 2.5 times the spot's peak above
   them) is dropped after the search.
5. ``filter``: Gaussian of the PSF's sigma (the matched filter), on a
   float32 copy (OpenCV's Gaussian is fastest on float32). The background is
   not subtracted from the whole image: the threshold image carries it
   (background + filtered level left + k times the filtered noise, one
   interpolation of one grid), and the filtered statistics and every
   sparse read subtract it where they look. k comes from the false-alarm
   budget ``detect.false_alarms_per_frame`` for this frame's size and PSF,
   moved to the same tail probability for the frame's own noise
   distribution (tracker.detect.threshold: a saddlepoint of its background
   pixels' histogram; Cornish-Fisher from the skewness when too few tiles
   are free of stars or neighbouring pixels are correlated). Where an integer
   sky is flat to within its rounding (no noise the lattice sees, e.g. an 8-bit
   sky without noise) the threshold is that of the sparse noise such a sky may
   hide, not of white rounding noise. Where the sky's
   own noise reaches full scale (within 4 of its sigmas: 8-bit noise of a
   third of full scale), the filter is 1.5 times the PSF's width, for the
   saturated stars that are then most of those at the threshold.
6. ``peaks``: local maxima above that threshold; close pairs split where the
   profile dips between them (tracker.detect.peaks).
7. ``centroid``: iterative Gaussian-windowed centroid, then a fit of the
   pixel-integrated PSF for the centre (no pixel-phase bias; saturated
   pixels censored where light, not the sky's noise, clipped them; where the
   sky's noise clips at full scale, saturated stars centred on the peak of
   the widened filter; tracker.detect.fit), flux, SNR and shape
   (tracker.detect.windowed); the flux reported is the PSF-weighted sum's
   (tracker.detect.weighted_flux: the noise and background error of the
   PSF's effective area, not of the whole window), a saturated star's its
   window's sum. Spots sharper than the optics deliver
   (cosmic-ray clusters that survived steps 3-4, hot pixels) are rejected
   and counted, broad ones flagged EXTENDED or masked as bodies
   (tracker.detect.spot_shapes); so are fainter spots whose 3 x 3 holds a
   point beyond a star's noise, against a PSF the frame's stars measured
   (else the sharpest the test is made for) and the pixel noise measured on
   those spots (tracker.detect.point_spot), and spots whose 5 x 5 light is a
   particle's short track, elongated beyond the frame's stars and narrower across
   than they are at its own pixel phase, or a round hit narrower overall than the
   stars the PSF was measured on (tracker.detect.line_spot: under a sharp PSF a track
   1-4 px long is as wide overall as a star; a saturated spot is fitted on its
   unclipped pixels). Maxima on a
   bright body are masked (tracker.detect.surroundings): too few sky sectors
   around them, light along a line with sky across it (a crescent, a ghost's ring), or a
   clipped plateau shared with another saturated candidate (the Earth's lit
   edge); a star beside the body keeps the sky on its side. So are spots whose filtered
   peak clears the threshold only with light under it that the background grid does
   not hold (tracker.detect.ring_light): the halo of a star at least ten times
   brighter (its Airy rings, its wings), from the window's radius to 24 PSF sigmas
   out, read as the median of the filtered image on the ring through the spot around
   that star (a companion's light is its own), or the local sky the grid lags (glare's
   curvature, a ghost's ring), read on a ring 5 PSF sigmas around the spot. With
   ``detect.centroid_noise: multiplicative`` a maximum-likelihood fit for
   noise proportional to the light (tracker.detect.multiplicative) gives
   every centre instead, from the frame as delivered, which step 5 then
   filters too (a faint speckled star's spikes over a dark sky are what the
   impulse stage clears); the shape tests (sharp spots, ELONGATED, EXTENDED
   and bodies by flux/peak) are off, a speckled star's pixels being spiky,
   and candidates that end within 2 PSF sigma of a brighter one are
   dropped as its duplicates. A star the frame's edge cuts
   (tracker.detect.edge) starts its window where the star is (the
   reflected filter may put its peak on the border pixel), is fitted on the
   pixels inside the frame at any SNR, is judged by its shape along the
   edge, and is dropped when its centre lies beyond the frame.

The Gaussian of step 5 and the threshold tests of steps 4 and 6 run in
``detect.threads`` horizontal slabs at once (tracker.detect.slabs; the
result does not depend on the thread count); each slab of step 6 raises
the threshold's border strips on its own rows just before comparing them,
and marks the words of its mask holding a candidate. With more than one thread
full-frame passes also run on worker threads beside Python work that does
not need them: the frame's copy of step 1 in two slabs; the median of step 3
while step 2 works out the background and the impulse limit (the median
needs only the frame), the background's interpolation to full size on the
other worker beside the impulse limit's and step 3's first cut (the pixels
far from their median, which needs no background); the float copy of
step 5, with the background read at the filtered statistics' samples, while
step 4 measures the PSF (the impulses' second pass then rewrites the pixels
it changes in both copies). The tiles' samples of step 5's filtered statistics
are read and sorted in slabs, and so is the frame binned 4 x 4 where step 4
needs it (step 2's samples are not: there the median holds a worker).

``Detections.counters``: impulse_pixels, hot_pixels, cosmic_rays (tracks
found in steps 3-4 plus sharp spots from step 7), sharp_spots, masked,
beyond_edge (centres beyond the frame), candidates, left_out (stars beyond
``detect.max_stars``). ``Detections.psf_*``: the PSF
used. Stars are ordered most significant first (by SNR); beyond
``detect.max_stars`` the least significant are left out.
"""

from __future__ import annotations

import math
from dataclasses import fields

import cv2
import numpy as np

from tracker.config import DetectConfig
from tracker.detect.background import QUANTISATION_NOISE_ADU, BackgroundGrid
from tracker.detect.binned import BinnedPeaks
from tracker.detect.edge import beyond_frame, cut_axes, inward_starts, judge_whole
from tracker.detect.fit import PixelGaussianFit
from tracker.detect.frame_input import FrameInput, Reason
from tracker.detect.impulse import ImpulseFilter, psf_contrast, psf_ring
from tracker.detect.layout import PaddedLayout
from tracker.detect.line_spot import (
    LINE_RADIUS,
    LINE_REFERENCE_SNR,
    LINE_REFERENCE_SPOTS,
    LINE_USABLE,
    floor_fit,
    line_fit,
    track_spots,
)
from tracker.detect.multiplicative import MultiplicativeFit
from tracker.detect.peaks import PeakFinder
from tracker.detect.point_spot import (
    POINT_OFFSETS,
    Z_STAR_LOSS,
    pixel_noise_model,
    point_significance,
)
from tracker.detect.psf import (
    CHARGE_SIGMA_PX,
    OPTICS_WIDER,
    SIGMA_MAX_PX,
    SIGMA_MIN_PX,
    PsfEstimate,
    PsfMeter,
    PsfTracker,
    combine_stars,
    pixel_tensor_to_optics,
)
from tracker.detect.result import Detections, StarFlag
from tracker.detect.ring_light import (
    HALO_CONTRAST,
    HALO_ERRORS,
    LOCAL_ERRORS,
    LOCAL_SKY_SIGMAS,
    SPOT_SIGMAS,
    LightRings,
    light_over_sky,
)
from tracker.detect.roughness import StarRoughness
from tracker.detect.sigma_steps import SigmaSteps
from tracker.detect.significance import SHOT_ADU, shot_noise_snr
from tracker.detect.slabs import SlabRunner
from tracker.detect.spot_shapes import (
    STAR_ELLIPTICITY,
    STAR_WIDTH,
    broad_spots,
    common_elongation,
    sharp_spots,
)
from tracker.detect.star_width import lowest_phase_width
from tracker.detect.stars import StarTable
from tracker.detect.surroundings import Surroundings, across_a_line, sky_noise_model
from tracker.detect.threshold import (
    NoiseTail,
    constant_sky_rate,
    gaussian_peak_threshold,
    skewed_threshold,
)
from tracker.detect.weighted_flux import weighted_capture
from tracker.detect.windowed import WindowedCentroider
from tracker.timing import StageTimer

__all__ = ["DefaultDetector", "effective_sigma", "PSF_STAR_DTYPE"]

PSF_STAR_DTYPE = np.dtype([("x", np.float64), ("y", np.float64), ("sigma_px", np.float64),
                           ("ellipticity", np.float64)])

_SIGMA_STEP = math.log(1.03)   # PSF sigmas are used in steps of 3 %
_PSF_STARS = 48                # brightest stars examined for the PSF ...
_PSF_PEAKS = 512               # ... among this many brightest peaks, impulses set aside
_PSF_POOL = 8192               # spared impulse candidates looked at for those peaks
_PSF_IMPULSE_CONTRAST = 0.95   # a peak this far above its 3x3 median is an impulse
_PSF_PIXELS = 32768            # pixels above the PSF stage's threshold examined
_PSF_RING_SIGMAS = 4.5         # tracker.detect.psf's isolation ring reaches this far
_PSF_ROUND = 0.5               # a PSF candidate's 5x5 light is rounder than this
_PLATEAU_STARS = 64            # saturated stars centred on their clipped core, at most
_PLATEAU_FILL = 0.7            # ... when its radius is this much of the window's
_PLATEAU_PAIRS = 65536         # pairs of saturated candidates judged for sharing a plateau
_CHUNK = 512                   # stars centroided at a time (bounds the window buffers)
_LINE_CHUNK = 96               # spots fitted at a time by the short-track test
_CLIP_SIGMAS = 4.0             # full scale this many pixel noises above the background
_SATURATED_TILE = 0.9          # a tile this close to saturation is lit ground, not sky
_IMPULSE_PSF_MARGIN = 0.9      # impulses are judged against a PSF this much sharper
# a particle's charge (0.45 px) centred within 0.2 px of a pixel's centre stands 2.5-5 x
# its brightest neighbour: the hits replaced alone, their wings a spot of that peak
_REMNANT_PEAKS = 2.5
_REMNANT_FLUX = 1.5            # ... and they hold up to 1.1 x its excess (noise: 1.5)
_SHARPEST_RING = 0.5 * psf_ring(SIGMA_MIN_PX)
_FIRST_PASS_SIGMA_PX = 0.55    # ... and before it is measured, against this one
_BINNED_SNR = 4.0              # too few bright peaks: 4x4 bins this significant measure it,
_LONE_STARS = 3                # ... or, this many, bound it for the impulses
_BOUND_AGREE = math.log(1.15)  # ... by the sharpest within 15 % of their PSF
_CONTRADICT_SE = 3.0           # ... and their PSF replaces an earlier frame's this many
                               # standard errors and STAR_WIDTH away from it
_SKY_RING_SIGMAS = 3.5         # a candidate's surroundings: from this many PSF sigmas ...
_SKY_RING_WIDTH = 2            # ... outward by this many pixels
_TEXTURE_NOISE = 1.6           # a tile this much noisier than the smooth sky is textured,
_TEXTURED_SKY_SECTORS = 6      # ... and its candidates need this many sky sectors
_TILE_NEIGHBOURS = np.ones((3, 3), np.uint8)
_SKY_SIDE_OWN = 3.0            # a sky tile beside a body reading this x its sky neighbours holds
                               # a sliver of the body (or a bright star): not smoothed over them
_BROAD_SKY_SECTORS = 4         # a broad candidate needs this many sky sectors
_LINE_MAX_ELLIPTICITY = 0.25   # a frame's PSF and spots rounder than this: a line is light
_WING_LEVEL = 0.5              # a saturated star's wings are under this much of saturation
_DARK_SIDE_SIGMAS = 10.0       # a tile this much brighter than its darker part holds an edge,
_BODY_TOP = 0.9                # ... or whose 90th percentile is that much above its level
_STEP_OVER_SLOPE = 4.0         # ... and 4 x as far as its level above its darker part
_TAIL_SKEWNESS = 0.1           # filtered noise more skewed than this has its tail modelled
_CLIPPED_NOISE_WIDTH = 1.5     # where noise clips at full scale, the filter this much wider
_RATE_STEP = math.log(1.05)    # a flat sky's rate of pixels above its level, in steps of 5 %,
_RATE_LOW = 1e-5               # ... from this (a lower rate counts as this)
_RATE_HIGH = 0.05              # ... to this (a higher one's level is over the floor's)
_HALO_REACH_SIGMAS = 24.0      # a star's halo is judged this many PSF sigmas out,
_HALO_STARS = 64               # ... around this many of the brightest stars at most,
_HALO_PAIRS = 4096             # ... for this many spots beside them at most
_LIGHT_CHUNK = 128             # spots whose rings are read at a time (bounds the temporaries)
_FLOOR_ROUNDING = 1e-6         # a ring's floor (_light_floor) lies this part of its terms low


def effective_sigma(psf_sigma_px: float) -> float:
    """Sigma of a Gaussian PSF after integration over a square pixel, px."""
    return math.sqrt(psf_sigma_px ** 2 + 1.0 / 12.0)


def _impulse_cut(sigma_px: float) -> tuple[float, float]:
    """(contrast, ring) of tracker.detect.impulse's tests for a PSF of ``sigma_px``.

    The contrast is halfway between an impulse's over its 3x3 median and that
    of a centred star a tenth sharper than the PSF at its sharpest sub-pixel
    phase; the ring is half the light a star a tenth sharper, at its sharpest
    phase, puts in the eight neighbours of its peak (a hot pixel's hold noise).
    """
    sharper = _IMPULSE_PSF_MARGIN * sigma_px
    return 0.5 * (1.0 + psf_contrast(sharper, worst_phase=True)), 0.5 * psf_ring(sharper)


def _sigma_step_of(sigma_px: float) -> int:
    """The step (of ``_SIGMA_STEP``) a PSF sigma of ``sigma_px`` is used at."""
    return int(round(math.log(sigma_px) / _SIGMA_STEP))


def _far_ring(sigma_px: float) -> int:
    """Outer radius (px) of the furthest sky ring (tracker.detect.surroundings) for an
    optical PSF sigma of ``sigma_px``."""
    inner = int(math.ceil(_SKY_RING_SIGMAS * effective_sigma(sigma_px)))
    return inner + _SKY_RING_WIDTH + max(_SKY_RING_WIDTH, inner // 2)


def _window_radius(psf_sigma_px: float) -> int:
    """Centroid window radius, px: 3 sigma of the pixel-integrated PSF."""
    return int(math.ceil(3.0 * effective_sigma(psf_sigma_px)))


def _kernel_half(psf_sigma_px: float) -> int:
    """Matched filter's half-width, px: round(2 sigma) of the pixel-integrated PSF.

    The cut-off kernel keeps >= 99 % of the matched filter's SNR (its square
    holds >= 99.5 % of the PSF's squared mass per axis) and costs two thirds
    of a 2.5-sigma one (5x5 instead of 7x7 at sigma 1.2).
    """
    return max(1, int(round(2.0 * effective_sigma(psf_sigma_px))))


def _contradicts(few: PsfEstimate, carried: PsfEstimate) -> bool:
    """Whether a few stars' PSF (``few``) says the one carried from earlier frames is not
    this frame's: over 25 % wider in sigma (where the shape tests stop taking this
    frame's stars for stars of the carried PSF: a wide star's wings fill the sky ring
    and it is masked as embedded), and beyond ``_CONTRADICT_SE`` of their standard
    errors combined (the configured start has none). Only wider: three or four
    particle hits of an event agree on a sharp "PSF" as often as stars do (lunar
    study frames: 0.58 and 0.63 px from hits on frames of 1.3 and 2.5 px, 31 and 33
    false detections), while a particle's charge is never wider than the optics."""
    error = math.hypot(few.sigma_error_px, carried.sigma_error_px
                       if math.isfinite(carried.sigma_error_px) else 0.0)
    return (math.log(few.sigma_px / carried.sigma_px) > STAR_WIDTH
            and few.sigma_px - carried.sigma_px > _CONTRADICT_SE * error
            and few.ellipticity < STAR_ELLIPTICITY)   # a slew's trails are no PSF


def _reflected_noise_gain(kernel: np.ndarray, rows: int,
                         cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Noise gain of the filter at the first rows and columns, relative to the interior.

    OpenCV's BORDER_REFLECT folds the kernel onto itself at the border, so
    a pixel there sums some inputs twice and its filtered noise grows by
    sqrt(sum(folded^2) / sum(kernel^2)) per axis. Returns that factor for
    the first ``len(kernel) // 2`` rows and columns (the last ones mirror
    them); frames narrower than the kernel get factors of 1.
    """
    half = len(kernel) // 2
    gains = []
    for length in (rows, cols):
        g = np.ones(half, np.float32)
        if length > 2 * half:
            for i in range(half):
                folded = np.zeros(2 * half)   # the taps land at rows 0 .. 2 half - 1
                for t, k in zip(range(-half, half + 1), kernel, strict=True):
                    j = i + t
                    folded[-j - 1 if j < 0 else j] += k
                g[i] = np.sqrt(np.sum(folded ** 2) / np.sum(kernel ** 2))
        gains.append(g)
    return gains[0], gains[1]


class DefaultDetector:
    """Fixed-memory star detector; see the module docstring for the stages."""

    def __init__(self, cfg: DetectConfig, shape: tuple[int, int], bit_depth: int) -> None:
        self.cfg = cfg
        max_radius = _window_radius(SIGMA_MAX_PX)
        max_blend = 2 * max_radius if cfg.blend_radius_px is None else int(cfg.blend_radius_px)
        psf_radius = int(math.ceil(_PSF_RING_SIGMAS * effective_sigma(SIGMA_MAX_PX)))
        sky_radius = _far_ring(SIGMA_MAX_PX)
        layout = PaddedLayout(shape, max(max_radius, max_blend, psf_radius, sky_radius) + 1)
        self.layout = layout
        self.input = FrameInput(shape, bit_depth, min_size=3, layout=layout, dtype=np.uint16)
        self.saturation = (self.input.full_scale if cfg.saturation_adu is None
                           else float(cfg.saturation_adu))
        self.table = StarTable(cfg.max_stars)
        self.timer = StageTimer()
        self.grid = BackgroundGrid(layout, cfg.background_tile_px, cfg.background_step_px,
                                   cfg.max_candidates)
        grid_shape = self.grid.grid_shape
        self.level = np.zeros(grid_shape, np.float32)        # raw background, ADU
        self.noise = np.zeros(grid_shape, np.float32)        # raw pixel noise, ADU
        self.residual = np.zeros(grid_shape, np.float32)     # filtered level left, ADU
        self.noise_f = np.zeros(grid_shape, np.float32)      # filtered noise, ADU
        # NoiseTail.constant_sky per step of the rate, for the filter and u of _rate_key
        self._low_step = int(math.ceil(math.log(_RATE_LOW) / _RATE_STEP))
        self.rate_levels = np.full(int(math.ceil(math.log(_RATE_HIGH) / _RATE_STEP))
                                   - self._low_step + 1, np.nan)
        self._rate_key = None
        self.sky_levels = np.zeros(grid_shape, np.float64)   # _constant_sky's, ADU
        self.float_grid = np.zeros(grid_shape, np.float32)
        self.int_grid = np.zeros(grid_shape, np.uint16)
        self.bg_pad, self.bg = layout.buffer(np.float32)
        # impulse_sigma times the pixel noise in whole ADU, like the differences it bounds
        self.limit_pad, self.impulse_limit = layout.buffer(np.uint16)
        self.bright_pad, self.bright_threshold = layout.buffer(np.uint16)  # the PSF stage's
        self.float_pad, self.work_float = layout.buffer(np.float32)  # the filter's input
        self.filt_pad, self.filt = layout.buffer(np.float32)
        self.threshold = np.zeros(self.input.shape, np.float32)  # background included, ADU
        half = _kernel_half(SIGMA_MAX_PX)    # the border strips' gains (_edge_gains)
        self.row_gains = np.zeros((2, half, layout.cols), np.float32)
        self.col_gains = np.zeros((2, layout.rows, half), np.float32)
        # An impulse is sharper than the sharpest PSF the detector is made for (0.55 px,
        # at its sharpest sub-pixel phase), whatever this frame's PSF turns out to be.
        contrast = (cfg.impulse_contrast if cfg.impulse_contrast is not None
                    else 0.5 * (1.0 + psf_contrast(_FIRST_PASS_SIGMA_PX, worst_phase=True)))
        self.impulses = ImpulseFilter(layout, contrast, cfg.max_impulses, np.uint16,
                                      cfg.threads, full_scale=self.saturation)
        self.filter_slabs = SlabRunner(layout.rows, layout.cols, _kernel_half(SIGMA_MAX_PX),
                                       cfg.threads, np.float32)
        self.peaks = PeakFinder(layout, 1, cfg.deblend_dip_sigma, cfg.max_pixels_above,
                                cfg.max_candidates, slabs=self.filter_slabs)
        self.bright = PeakFinder(layout, psf_radius, cfg.deblend_dip_sigma, _PSF_PIXELS,
                                 _PSF_PEAKS, slabs=self.filter_slabs, dtype=np.uint16)
        self.psf_values = np.zeros(_PSF_PEAKS, np.float32)
        self.psf_reads = np.zeros(_PSF_PEAKS, np.uint16)
        self.psf_contrast = np.zeros(_PSF_PEAKS, np.float32)
        dy, dx = (a.ravel() for a in np.mgrid[-max_radius:max_radius + 1,
                                              -max_radius:max_radius + 1])
        self.plateau_offsets = (dy * layout.stride + dx).astype(np.intp)
        self.plateau_reach = float(max_radius)   # px: one plateau's pieces lie this close
        self.plateau_xy = np.stack([dx, dy], axis=1).astype(np.float64)
        self.plateau_index = np.zeros((_PLATEAU_STARS, dx.size), np.intp)
        self.plateau_reads = np.zeros((_PLATEAU_STARS, dx.size), np.uint16)
        self.plateau_full = np.zeros((_PLATEAU_STARS, dx.size), np.bool_)
        side = 2 * max_radius + 1
        self.plateau_core = np.zeros((_PLATEAU_STARS, side, side), np.bool_)
        self.plateau_grow = np.zeros((_PLATEAU_STARS, side, side), np.bool_)
        dy, dx = (a.ravel() for a in np.mgrid[-2:3, -2:3])
        self.round_offsets = (dy * layout.stride + dx).astype(np.intp)
        self.round_moments = np.stack([np.ones(25), dx, dy, dx * dx, dy * dy, dx * dy],
                                      axis=1).astype(np.float32)
        self.round_index = np.zeros((_PSF_PEAKS, 25), np.intp)
        self.round_reads = np.zeros((_PSF_PEAKS, 25), np.uint16)
        self.round_values = np.zeros((_PSF_PEAKS, 25), np.float32)
        self.pool_height = np.zeros(_PSF_POOL, np.float32)
        self.pool_reads = np.zeros(_PSF_POOL, np.uint16)
        self.pool_noise = np.zeros(_PSF_POOL, np.float32)
        self.pool_cand = np.zeros(_PSF_PEAKS, np.intp)
        self.pool_cand_noise = np.zeros(_PSF_PEAKS, np.float32)
        self.psf_cand = np.zeros(_PSF_STARS, np.intp)
        self.psf_noise = np.zeros(_PSF_STARS, np.float32)
        self.psf_meter = PsfMeter(layout.stride, psf_radius, _PSF_STARS, cfg.psf_min_stars)
        self.binned = BinnedPeaks(layout, _PSF_PEAKS, slabs=self.filter_slabs)
        self.psf_tracker = PsfTracker(cfg.psf_sigma_px, cfg.psf_memory_frames)
        self.measure_psf = cfg.psf_measure   # a caller given the PSF may skip step 4's meter
        self.psf = self.psf_tracker.current
        self.fit = PixelGaussianFit(_CHUNK, 2 * max_radius + 1)
        self.centroider = WindowedCentroider(
            layout.stride, max_radius, gain=2.0, iterations=cfg.centroid_iterations,
            tolerance=cfg.centroid_tolerance_px, max_shift=1.5, capacity=cfg.max_candidates,
            dtype=np.uint16, chunk=_CHUNK, layout=layout,
            fit=None if cfg.centroid_noise == "multiplicative" else self.fit)
        # multiplicative noise: the likelihood fit reads the frame as delivered, since
        # the impulse filter takes the spikes of speckle for hot pixels
        self.speckle_fit = None
        if cfg.centroid_noise == "multiplicative":
            self.delivered_pad = np.zeros_like(self.input.padded)
            pad = layout.pad
            self.delivered = self.delivered_pad[pad:pad + layout.rows, pad:pad + layout.cols]
        self.cand_noise = np.zeros(cfg.max_candidates, np.float32)
        self.cand_level = np.zeros(cfg.max_candidates, np.float32)
        self.cand_censor = np.zeros(cfg.max_candidates, np.float32)
        self.edge_px = np.zeros(_PSF_STARS, np.float64)
        self.tail = NoiseTail(self.grid.index)
        self.textured = np.zeros(grid_shape, np.bool_)
        self.dark_side = np.zeros(grid_shape, np.bool_)
        self.beside_body = np.zeros(grid_shape, np.bool_)   # sky tiles beside a body's
        self.near_body = np.zeros(grid_shape, np.bool_)     # bodies' tiles and their neighbours
        self.sky_edge = np.zeros(grid_shape, np.bool_)   # tiles beside a body at the sky's level
        self.sky_split = np.zeros(grid_shape, np.bool_)  # edge tiles mostly of a body
        self.sky_pad = np.zeros((grid_shape[0] + 2, grid_shape[1] + 2), np.float32)
        self.sky_pad_offsets = (np.arange(-1, 2)[:, None] * self.sky_pad.shape[1]
                                + np.arange(-1, 2)[None, :]).ravel()
        self.sky_model = (0.0, 0.0, 0.0)   # the frame's sky noise model (_mark_dark_side)
        self.noise_clips = False           # the sky's noise reaches full scale (_set_filter)
        self.near_texture = np.zeros(grid_shape, np.bool_)
        self.body_tiles = np.zeros(grid_shape, np.bool_)      # _mark_own_threshold's ...
        self.own_threshold = np.zeros(grid_shape, np.bool_)   # ... and its smooth tiles
        self.term_grid = np.zeros(grid_shape, np.float32)     # threshold over background
        self.off_sky = np.zeros(grid_shape, np.bool_)
        self.cand_near = np.zeros(cfg.max_candidates, np.uint8)
        self.surroundings = Surroundings(layout.stride, sky_radius, cfg.max_candidates, _CHUNK,
                                         _SKY_RING_WIDTH)
        self.rings = LightRings(_HALO_REACH_SIGMAS * effective_sigma(SIGMA_MAX_PX))
        self.counters = {"impulse_pixels": 0, "hot_pixels": 0, "cosmic_rays": 0,
                         "sharp_spots": 0, "masked": 0, "beyond_edge": 0, "candidates": 0,
                         "left_out": 0}
        self._sigma_step = None
        self.steps = SigmaSteps(_sigma_step_of(SIGMA_MIN_PX), _sigma_step_of(SIGMA_MAX_PX),
                                6 + len(fields(StarRoughness)),
                                _kernel_half(SIGMA_MAX_PX))
        self.steps.fill(self._step_constants)
        self._configure(cfg.psf_sigma_px)

    def _configure(self, sigma_px: float) -> None:
        """Set every PSF-dependent part for an optical PSF sigma of ``sigma_px``.

        Sigma is rounded to steps of 3 % (a matched filter 3 % too wide or
        narrow keeps 99.96 % of the SNR), and the parts are rebuilt only when
        the PSF has moved more than one and a half steps from the one they
        were built for: a PSF wandering by a few per cent from frame to
        frame leaves the kernels, windows and their buffers as they are.
        The constants that take some arithmetic (thresholds, contrasts, the
        roughness of a star and its spread, a star's lowest width over its pixel
        phase, the weighted flux's capture, the filter's gain at the borders) come
        from ``self.steps``, computed once per step.
        """
        position = math.log(sigma_px) / _SIGMA_STEP
        if self._sigma_step is not None and abs(position - self._sigma_step) <= 1.5:
            return
        step = _sigma_step_of(sigma_px)
        self._sigma_step = step
        sigma_px = math.exp(step * _SIGMA_STEP)
        self.psf_sigma_used = sigma_px
        sigma = effective_sigma(sigma_px)
        self.sigma = sigma
        self.radius = _window_radius(sigma_px)
        blend = 2 * self.radius if self.cfg.blend_radius_px is None else int(
            self.cfg.blend_radius_px)
        kernel = self._gaussian_kernel(sigma_px)
        self.peaks.configure(blend)
        self.centroider.configure(self.radius, sigma)
        self.fit.configure(self.radius, sigma_px)
        if self.cfg.centroid_noise == "multiplicative":
            self.speckle_fit = MultiplicativeFit(self.radius, sigma_px, self.input.full_scale)
        self.expected_size = sigma ** 2  # weighted Mxx + Myy of a Gaussian star, px^2
        self.surroundings.configure(int(math.ceil(_SKY_RING_SIGMAS * sigma)))
        self.local_ring = self.rings.offsets(LOCAL_SKY_SIGMAS * sigma, self.layout.stride)
        scalars, self.edge_gain = self.steps.get(step, lambda: self._step_constants(step))
        self.psf_filter = (kernel, scalars[0], scalars[1], self.edge_gain)
        self._filter_key = None
        self._set_filter(False)
        self.impulse_contrast, self.impulse_ring, self.phase_low, self.capture = scalars[2:6]
        self.star_roughness = StarRoughness.from_values(scalars[6:])

    @staticmethod
    def _gaussian_kernel(sigma_px: float) -> np.ndarray:
        """The 1-D matched filter for an optical PSF sigma of ``sigma_px``: the pixel-
        integrated Gaussian's, ``_kernel_half`` each side."""
        k = 2 * _kernel_half(sigma_px) + 1
        return cv2.getGaussianKernel(k, effective_sigma(sigma_px), cv2.CV_64F).ravel()

    def _set_filter(self, wide: bool) -> None:
        """The matched filter of the search: the PSF's, or, ``wide``, the Gaussian of a
        star's clipped core in a frame whose noise clips at full scale (:meth:`_light_clips`
        false at the sky's level): ``_CLIPPED_NOISE_WIDTH`` times the PSF's sigma, at most
        the widest PSF handled, with its own false-alarm threshold and border gains.

        There (8-bit noise of a third of full scale, the seed's written
        Gaussian+Poisson) a star saturates at a low SNR, and the stars at the
        threshold are mostly saturated: the change their light makes to the
        delivered pixels' mean is flat over a clipped core wider than the PSF, and
        over a bright sky it is small (full scale is near). The wider filter reads
        0.95-1.17 of what the PSF's reads of such stars (flux 15-60 times full
        scale, black sky to 0.3 of full scale), and its threshold is lower: it sums
        more pixels of noise clipped at both ends, whose tail the PSF's leaves heavy
        (on a black sky 6.2 filtered sigmas for the budget against 6.6; 5.4 against
        5.6 at 0.35). An unclipped star loses 8 % of its SNR to it, but under such
        noise a star faint enough not to saturate is below the threshold anyway.
        Rebuilt only when the PSF's step or the choice changes.
        """
        key = (self._sigma_step, wide)
        if key == self._filter_key:
            return
        self._filter_key = key
        if wide:
            sigma_px = min(_CLIPPED_NOISE_WIDTH * self.psf_sigma_used, SIGMA_MAX_PX)
            kernel = self._gaussian_kernel(sigma_px)
            gain = float(np.sum(kernel ** 2))
            threshold = gaussian_peak_threshold(self.cfg.false_alarms_per_frame,
                                                self.layout.rows * self.layout.cols, kernel)
            edge = _reflected_noise_gain(kernel, self.layout.rows, self.layout.cols)
        else:
            sigma_px = self.psf_sigma_used
            kernel, gain, threshold, edge = self.psf_filter
        self.filter_sigma = effective_sigma(sigma_px)
        self.ksize = (len(kernel), len(kernel))
        self.kernel = kernel       # the noise tail's, configured when a frame needs it
        self._tail_kernel = None
        self.filter_gain, self.peak_threshold = gain, threshold
        self._edge_gains(*edge)

    def _step_constants(self, step: int) -> tuple[tuple, tuple[np.ndarray, np.ndarray]]:
        """The PSF's constants for ``_configure`` at sigma step ``step``: (filter gain,
        Gaussian peak threshold, impulse contrast, impulse ring, the lowest width over
        the pixel phase (tracker.detect.star_width), the weighted flux's capture of the
        PSF (tracker.detect.weighted_flux), then the StarRoughness values of its
        centroid window), (edge gains)."""
        sigma_px = math.exp(step * _SIGMA_STEP)
        kernel = self._gaussian_kernel(sigma_px)
        # filtered / pixel noise for white noise: sqrt of the 2-D kernel's sum of squares
        filter_gain = float(np.sum(kernel ** 2))
        peak_threshold = gaussian_peak_threshold(
            self.cfg.false_alarms_per_frame, self.layout.rows * self.layout.cols, kernel)
        impulse_contrast, impulse_ring = _impulse_cut(sigma_px)
        roughness = StarRoughness.of(_window_radius(sigma_px), sigma_px)
        capture = weighted_capture(sigma_px, effective_sigma(sigma_px),
                                   _window_radius(sigma_px))
        return ((filter_gain, peak_threshold, impulse_contrast, impulse_ring,
                 lowest_phase_width(sigma_px), capture, *roughness.values()),
                _reflected_noise_gain(kernel, self.layout.rows, self.layout.cols))

    def _noise_f_at(self, flat: np.ndarray, out: np.ndarray) -> np.ndarray:
        return self.grid.at(self.noise_f, flat, out)

    def detect(self, image: np.ndarray) -> Detections:
        """Stars in ``image`` (pixel convention: tracker.detect.result)."""
        timer = self.timer
        timer.reset()
        for key in self.counters:
            self.counters[key] = 0
        timer.start("input")
        reason = self.input.load(image, rows=self.impulses.slabs.rows)
        if reason is not None:
            timer.stop()
            return self.table.result(0, reason, self.counters, timer.ms)
        if self.speckle_fit is not None:
            np.copyto(self.delivered_pad, self.input.padded)
        self.impulses.start_median(self.input.work)   # step 3's median, beside step 2
        timer.start("background")
        grid = self.grid
        grid.stats(self.input.padded, self.level, self.noise, QUANTISATION_NOISE_ADU,
                   upper=True)
        if self._mark_dark_side():
            grid.stats(self.input.padded, self.level, self.noise, QUANTISATION_NOISE_ADU,
                       upper=True, dark_side=self.dark_side, sky_split=self.sky_split,
                       resample=False)
            self.sky_model = sky_noise_model(self.level, self.noise, self.saturation)
        # the background's interpolation on the filter's worker (idle until step 4; the
        # impulse stage's is still busy with the median), while the impulse limit's is
        # made here
        bg_wait = self.filter_slabs.start(grid.upsample, self.level, self.bg)
        self.noise_clips = not self._light_clips(self.sky_model[0])
        np.multiply(self.noise, self.cfg.impulse_sigma, out=self.float_grid)
        np.clip(self.float_grid, 0.0, 65535.0, out=self.float_grid)
        np.rint(self.float_grid, out=self.float_grid)
        np.copyto(self.int_grid, self.float_grid, casting="unsafe")
        grid.upsample(self.int_grid, self.impulse_limit)
        timer.start("impulses")
        self.impulses.cut(self.input.work, self.impulse_limit)   # needs no background
        timer.start("background")
        bg_wait()
        grid.cap_in_tiles(self.level, self.bg, self.beside_body)
        timer.start("impulses")
        # hot pixels and tracks are told apart by the second pass (_refine_impulses)
        self.counters.update(self.impulses.test(self.input.padded, self.bg_pad, self.limit_pad,
                                                split=False))
        # the filter's float copy and the background at the filtered statistics' samples,
        # beside the PSF's measurement; the second impulse pass then rewrites the pixels
        # it changes in both copies
        self._float_wait = self.filter_slabs.start(self._filter_inputs, self.input.work,
                                                   self.work_float)
        timer.start("psf")
        measured, bound, binned, few = None, None, False, None
        if self.measure_psf:
            measured = self._measure_psf()
            if self._too_few(measured):
                few, measured = measured, None
            if measured is None:
                measured, bound, binned_few = self._binned_psf()
                binned = measured is not None
                few = binned_few or few
            elif measured.sigma_px < CHARGE_SIGMA_PX:
                measured, bound, binned, few = self._confirm_sharp(measured)
        self.psf = self.psf_tracker.update(measured)
        if few is not None and _contradicts(few, self.psf):
            # the estimate of earlier frames (or the configured start) is not this frame's:
            # its few stars agree on another width (the focus jumped, another camera's
            # frames); they set this frame's PSF, not the estimate carried on
            self.psf = few
        self._configure(self.psf.sigma_px)
        timer.start("impulse_refine")
        self._refine_impulses(self.psf.stars > 0 and not binned and self.psf is not few)
        count = self._search()
        # a particle's hit whose core the impulse stage replaced leaves its wings: a spot
        # made of them is dropped
        count = self._drop_remnants(count, *self.impulses.particle_hits(self.input.padded,
                                                                        self.bg_pad))
        if binned or bound is not None:
            timer.start("impulse_refine")
            count = self._retest_lone(count, self.psf_sigma_used if binned else bound)
        timer.stop()
        reason = (Reason.CROWDED if self.peaks.crowded
                  else Reason.TOO_MANY if self.counters["left_out"] else None)
        return self.table.result(count, reason, self.counters, timer.ms, self.psf)

    def _refine_impulses(self, measured: bool) -> None:
        """The impulse stage's second pass, judged against the PSF in use if the frame's
        bright stars measured it (``measured``); else against the sharpest PSF the
        detector handles (a PSF from elsewhere may be wider than the frame's stars, and
        a pass for it would take a sharper star's pixels for impulses and clear them as
        a track; one measured on the binned frame's fainter spots judges the lone
        impulses after the search, :meth:`_retest_lone`)."""
        contrast = (self.cfg.impulse_contrast if self.cfg.impulse_contrast is not None
                    else self.impulse_contrast if measured else self.impulses.contrast)
        ring = self.impulse_ring if measured else _SHARPEST_RING
        self._float_wait()
        self.counters.update(self.impulses.refine(self.input.padded, self.bg_pad,
                                                  self.limit_pad, contrast, ring,
                                                  mirror_pad=self.float_pad))

    def _filter_inputs(self, work: np.ndarray, work_float: np.ndarray) -> None:
        """The filter's float copy of the frame; the background at the grid's samples
        (the same for every search of the frame)."""
        np.copyto(work_float, work)
        self.grid.sample_minus(self.bg_pad)

    def _mark_dark_side(self) -> bool:
        """Mark the tiles that straddle the edge of a bright body; whether there are any.

        Such a tile is far brighter (in its interquartile mean) than its
        darker part (6th-37th percentile), by more than ten times the sky's
        noise: sky and ground (or glare) in one tile. Its statistics then come
        from its sky pixels (tracker.detect.background), so the stars on the
        sky side meet the sky's background and threshold. A tile whose mean
        is the body's (more than ten sky noises above the sky) while its
        darkest samples (its 6th percentile) are the sky's, a strip of sky
        beside ground, saturated or not, is also marked in ``sky_split``: its
        sky pixels are the darker class of a split of its samples
        (tracker.detect.sky_split), not its darker part. Keeps the sky's noise model
        (tracker.detect.surroundings.sky_noise_model) in ``sky_model``.
        """
        self.sky_model = sky_noise_model(self.level, self.noise, self.saturation)
        level0, var0, slope = self.sky_model
        grid = self.grid
        m = grid.samples.shape[-1]
        dark = grid.samples[..., m // 16: 3 * m // 8].mean(axis=-1)
        sky_noise = np.sqrt(var0 + slope * np.maximum(dark - level0, 0.0))
        # a tile mostly of ground (its mean the ground's, saturated or not) holds sky too
        # when its darkest samples are the sky's: a split of its samples finds them
        # (tracker.detect.sky_split), where its darker part would reach into the ground
        sky_scale = _DARK_SIDE_SIGMAS * math.sqrt(var0)
        np.less(grid.samples[..., m // 16] - level0, sky_scale, out=self.sky_split)
        self.sky_split &= grid.level_raw - level0 > sky_scale
        unclipped = (grid.level_raw < 0.9 * self.saturation) | self.sky_split
        np.logical_and(grid.level_raw - dark > _DARK_SIDE_SIGMAS * sky_noise, unclipped,
                       out=self.dark_side)
        # a body in a tile's brightest tenth only (a sliver of ground or the Earth at its
        # edge): its middle is sky, its top far above it, unlike a slope's, whose top
        # stands above its middle no further than its middle above its darker part
        top = grid.samples[..., int(round(_BODY_TOP * (m - 1)))] - grid.level_raw
        self.dark_side |= ((top > _DARK_SIDE_SIGMAS * sky_noise)
                           & (top > _STEP_OVER_SLOPE * (grid.level_raw - dark))
                           & unclipped)
        # sky tiles beside a saturated one (lit ground, the Earth) and the dark side of an
        # edge: their pixels keep the tile's own level and threshold, not a blend with
        # the saturated level beyond the edge (beside glare's core the tiles are bright
        # themselves, and its gradient is followed)
        bright = (grid.level_raw >= _SATURATED_TILE * self.saturation).view(np.uint8)
        cv2.dilate(bright, _TILE_NEIGHBOURS, dst=self.near_body.view(np.uint8))
        np.copyto(self.beside_body, self.near_body)
        self.beside_body &= grid.level_raw - level0 < _DARK_SIDE_SIGMAS * math.sqrt(var0)
        self.beside_body |= self.dark_side
        self.sky_split &= self.dark_side
        return bool(self.dark_side.any())

    def psf_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The PSF of the last frame's stars near (x, y) px, one by one (for a focus map).

        Returns the usable ones (isolated, unsaturated, round; at most 48 per
        call, the first given first) as a structured array of x, y (px),
        sigma_px and ellipticity (tracker.detect.psf's measure, star by star;
        its windows are sized for the widest of the brightest few given, so
        stars of very different widths are best measured in separate calls).
        """
        n = min(len(x), _PSF_STARS)
        rows = np.clip(np.rint(np.asarray(y[:n])), 0, self.layout.rows - 1).astype(np.intp)
        cols = np.clip(np.rint(np.asarray(x[:n])), 0, self.layout.cols - 1).astype(np.intp)
        self.psf_cand[:n] = self.layout.flat_index(rows, cols)
        self.grid.at(self.noise, self.psf_cand[:n], self.psf_noise[:n])
        self.psf_meter.measure(n, self.input.padded, self.bg_pad, self.psf_cand,
                               self.psf_noise, self.saturation, self.psf.sigma_px,
                               self._edge_distance(rows, cols), min_stars=1)
        return self.psf_stars()

    def psf_stars(self) -> np.ndarray:
        """The stars of the last PSF measurement (the frame's or :meth:`psf_of`'s).

        A structured array (a copy) of x, y (px), sigma_px and ellipticity.
        Empty when the PSF was not measured on the frame's bright stars (too
        few; ``detect.psf_measure`` false).
        """
        flat, sigma, ellipticity, offset = self.psf_meter.last_stars()
        rows, cols = self.layout.frame_position(flat)
        out = np.zeros(len(flat), PSF_STAR_DTYPE)
        out["x"], out["y"] = cols + offset[:, 0], rows + offset[:, 1]
        out["sigma_px"], out["ellipticity"] = sigma, ellipticity
        return out

    def _search(self) -> int:
        """Filter, threshold, peaks and centroids with the PSF configured; star count."""
        timer, grid = self.timer, self.grid
        timer.start("filter")
        self._set_filter(self.noise_clips)
        if self.speckle_fit is not None:
            # under multiplicative noise a faint star's own pixels are spikes over a
            # dark sky, which the impulse stage clears (a 3x3 median of a speckled star
            # holding a few lit pixels is the sky): the filter sums the frame as delivered
            np.copyto(self.work_float, self.delivered)
        self.filter_slabs.run(self._matched_filter, self.work_float, self.filt)
        grid.stats(self.filt_pad, self.residual, self.noise_f,
                   QUANTISATION_NOISE_ADU * self.filter_gain, upper=True, minus=True,
                   dark_side=self.dark_side if self.dark_side.any() else None,
                   slabs=self.filter_slabs)
        np.subtract(self.level, self.sky_model[0], out=self.float_grid)
        np.less(self.float_grid, _DARK_SIDE_SIGMAS * math.sqrt(self.sky_model[1]),
                out=self.sky_edge)
        self.sky_edge &= self.beside_body
        if self.sky_edge.any():
            self._sky_side_median(((grid.level_raw, self.residual), (grid.raw, self.noise_f)))
        self._mark_own_threshold()
        self._tail_threshold()
        self._constant_sky()
        self._make_threshold(1.0)
        timer.start("peaks")
        n = self.peaks.find(self.filt_pad, self.filt, self.threshold, self.bg_pad,
                            self._make_threshold, self._noise_f_at, finish=self._raise_edges)
        self.counters["candidates"] = n
        timer.start("centroid")
        return self._measure(n)

    def _binned_psf(self):
        """Too few bright peaks for step 4: the PSF measured on the brightest spots of the
        frame binned 4 x 4 (tracker.detect.binned), which a wide PSF's stars reach where
        their peaks do not, through the same tests and meter as the bright peaks.
        Returns (the measurement or None, a lower bound on the PSF's sigma or None,
        a few stars' estimate or None).

        Fewer agreeing stars than ``psf_min_stars``, but at least ``_LONE_STARS``, do
        not measure the PSF but say the frame's stars are no sharper than the sharpest
        of them: that sigma is the bound, for the impulses' second pass; their
        estimate is returned third, to check the estimate carried from earlier
        frames (None otherwise).
        """
        n = self.binned.find(self.input.padded, self.input.work, self.level, self.noise,
                             _BINNED_SNR)
        if n == 0:
            return None, None, None
        # on the sky only: lit ground, a body's edge and the tiles beside them hold bright
        # compact spots (boulders, crater rims) wider or sharper than the stars
        self._mark_texture()
        np.logical_or(self.near_texture, self.beside_body, out=self.off_sky)
        off = self.cand_near[:n]
        self.grid.at(self.off_sky.view(np.uint8), self.binned.start[:n], off)
        sky = np.flatnonzero(off == 0)
        min_stars = min(_LONE_STARS, self.cfg.psf_min_stars)
        measured = self._meter_binned(sky, min_stars)
        if measured is None or measured.stars < self.cfg.psf_min_stars:
            # particles' tracks and sharp hits among the brightest spots (a particle
            # event's outnumber the stars), measured as such, do not vote again: as the
            # meter's scouts they had sized its windows too small for a wide PSF's stars
            spots = self._measured_stars(sky)
            if 0 < len(spots) < len(sky):
                measured = self._meter_binned(spots, min_stars)
        if measured is None:
            return None, None, None
        if measured.stars < self.cfg.psf_min_stars:
            sigma = self.psf_meter.last_stars()[1]
            near = sigma[np.abs(np.log(sigma / measured.sigma_px)) <= _BOUND_AGREE]
            return None, float(near.min()) if len(near) else measured.sigma_px, measured
        return measured, None, None

    def _confirm_sharp(self, sharp: PsfEstimate):
        """A PSF measured as sharp as a particle's charge (``sharp``), checked against the
        frame binned 4 x 4 (:meth:`_binned_psf`). Near-normal particle hits are round and
        that sharp, and where they outnumber the bright stars they agree on a PSF of
        their own. The optics blur every star of a frame alike and never a particle's
        charge: if the binned frame's stars (fainter ones, their light summed; a sharp
        PSF's are single binned pixels there, too sharp to be measured) agree on a PSF
        ``OPTICS_WIDER`` times wider, the sharp spots were charge, and the binned
        measurement is the frame's. Fewer than ``psf_min_stars`` binned stars do not
        measure the PSF (three faint stars of a sharp PSF, undersampled, can read twice
        its width), but where they agree on one that much wider and beyond their
        standard errors (:func:`_contradicts`), the sample is bimodal: a sharp
        population beside stars the optics blurred, which a particle event's hits make
        and a sharp PSF's stars do not. The sharp spots then set nothing: the frame is
        unmeasured (the estimate carried on, or the few stars' if they contradict it,
        as in :meth:`detect`), with the few's sharpest star bounding the PSF for the
        lone impulses. Returns (measured, bound, binned, few) as in :meth:`detect`.
        """
        wide, bound, few = self._binned_psf()
        if wide is not None and wide.sigma_px >= OPTICS_WIDER * sharp.sigma_px:
            return wide, None, True, None
        if (few is not None and few.sigma_px >= OPTICS_WIDER * sharp.sigma_px
                and _contradicts(few, sharp)):
            return None, bound, False, few
        return sharp, None, False, None

    def _retest_lone(self, count: int, sigma_px: float) -> int:
        """Judge the lone impulse candidates again against a PSF of ``sigma_px``
        (tracker.detect.impulse.ImpulseFilter.retest_lone) and drop the stars that were
        mostly such a pixel; returns the new star count."""
        if self.cfg.impulse_contrast is not None:
            return count
        contrast, ring = _impulse_cut(sigma_px)
        hit, excess = self.impulses.retest_lone(self.input.padded, contrast, ring,
                                                mirror_pad=self.float_pad)
        self.counters["impulse_pixels"] += len(hit)
        self.counters["hot_pixels"] += len(hit)
        return self._drop_impulses(count, hit, excess)

    def _drop_impulses(self, count: int, hit: np.ndarray, excess: np.ndarray) -> int:
        """Drop the stars of the table (its first ``count``) that were mostly a pixel
        found an impulse since: one of ``hit`` (padded flat indices) in the 3x3 around
        the star's centre, standing above its median (``excess``, ADU) by at least half
        the star's peak. Returns the new count."""
        if len(hit) == 0 or count == 0:
            return count
        s = self.table.stars
        centre = self.layout.flat_index(np.rint(s["y"][:count]).astype(np.intp),
                                        np.rint(s["x"][:count]).astype(np.intp))
        near = centre[:, None] + self.impulses.window_offsets[None, :]
        which = np.searchsorted(hit, near)        # hit is sorted (raster order)
        which = np.minimum(which, len(hit) - 1)
        on = (hit[which] == near) & (excess[which] >= 0.5 * s["peak"][:count, None])
        keep = np.flatnonzero(~on.any(axis=1))
        if len(keep) == count:
            return count
        s[:len(keep)] = s[keep]
        return len(keep)

    def _drop_remnants(self, count: int, hit: np.ndarray, excess: np.ndarray) -> int:
        """Drop the stars of the table (its first ``count``) that are a particle's hit's
        wings: the pixel nearest the star's centre is one of ``hit`` (padded flat
        indices, ascending: tracker.detect.impulse.ImpulseFilter.particle_hits), which
        stood above its median by ``excess`` (ADU) of at least ``_REMNANT_PEAKS`` times
        the star's peak, and the star's flux is no more than ``_REMNANT_FLUX`` times
        that excess. Returns the new count.

        The wings of a charge diffused by 0.45 px about a point within 0.2 px of a
        pixel's centre (one the contrast test replaces alone) are centred on that
        pixel, hold 0.9-1.1 times its excess, and peak at 0.2-0.4 of it; a star a
        particle hit has its own light besides, and the hit is anywhere on it.
        """
        if len(hit) == 0 or count == 0:
            return count
        s = self.table.stars
        centre = self.layout.flat_index(np.rint(s["y"][:count]).astype(np.intp),
                                        np.rint(s["x"][:count]).astype(np.intp))
        which = np.minimum(np.searchsorted(hit, centre), len(hit) - 1)
        wings = ((hit[which] == centre) & (excess[which] >= _REMNANT_PEAKS * s["peak"][:count])
                 & (s["flux"][:count] <= _REMNANT_FLUX * excess[which]))
        keep = np.flatnonzero(~wings)
        if len(keep) == count:
            return count
        s[:len(keep)] = s[keep]
        return len(keep)

    def _meter_binned(self, which: np.ndarray, min_stars: int):
        """The PSF meter (:meth:`_meter`) on the binned candidates ``which``."""
        start = self.binned.start[which]
        noise = self.pool_cand_noise[:len(which)]
        self.grid.at(self.noise, start, noise)
        return self._meter(start, self.binned.brightest[which], noise, min_stars)

    def _measured_stars(self, which: np.ndarray) -> np.ndarray:
        """Those of the binned candidates ``which`` that the last :meth:`_meter_binned`
        call did not measure as a particle's (sharper than any PSF handled, ellipticity
        0.5 or more, or no spot at all); unmeasured ones stay."""
        meter = self.psf_meter
        n = meter.last_n
        if n == 0:
            return which
        p = meter.per_star
        sigma, ellipticity, _ = pixel_tensor_to_optics(p["cxx"][:n], p["cyy"][:n],
                                                       p["cxy"][:n])
        particle = ~((sigma >= SIGMA_MIN_PX) & (ellipticity < _PSF_ROUND))
        measured = set(meter.last_cand[:n][particle].tolist())
        return np.array([i for i in which if self.binned.start[i] not in measured],
                        np.intp)

    def _bright_peaks(self) -> tuple[np.ndarray, np.ndarray]:
        """The brightest local maxima (padded flat indices, pixel noise), brightest first.

        From the impulse stage's spared candidates when it kept a list (no
        further pass over the frame), else by a threshold search of the frame
        (tracker.detect.peaks); at least ``psf_min_peak_sigma`` pixel noise
        above the background, at most ``_PSF_PEAKS`` of them.
        """
        spared = self.impulses.spared_maxima(self.input.padded, self.bg_pad)
        if spared is None:
            self._bright_threshold(1.0)
            n = self.bright.find(self.input.padded, self.input.work, self.bright_threshold,
                                 self.bg_pad, self._bright_threshold, self._noise_at)
            return self.bright.cand[:n], self.bright.cand_noise[:n]
        m = min(len(spared), _PSF_POOL)
        spared = spared[:m]
        height = self.pool_height[:m]
        np.take(self.input.padded.ravel(), spared, out=self.pool_reads[:m], mode="clip")
        np.copyto(height, self.pool_reads[:m])
        np.subtract(height, np.take(self.bg_pad.ravel(), spared, mode="clip"), out=height)
        noise = self.pool_noise[:m]
        self.grid.at(self.noise, spared, noise)
        bright = np.flatnonzero(height > self.cfg.psf_min_peak_sigma * noise)
        order = bright[np.argsort(-height[bright], kind="stable")][:_PSF_PEAKS]
        k = len(order)
        self.pool_cand[:k] = spared[order]
        self.pool_cand_noise[:k] = noise[order]
        return self.pool_cand[:k], self.pool_cand_noise[:k]

    def _measure_psf(self):
        """This frame's PSF from its brightest stars (tracker.detect.psf), or None; from
        fewer than ``psf_min_stars`` (at least ``_LONE_STARS``) an estimate that only
        checks the one carried from earlier frames (:func:`_contradicts`)."""
        cand, noise = self._bright_peaks()
        return self._meter(cand, cand, noise, min(_LONE_STARS, self.cfg.psf_min_stars))

    def _too_few(self, estimate) -> bool:
        """Whether the last meter call's ``estimate`` (at ``_LONE_STARS``) came from fewer
        agreeing stars than ``psf_min_stars`` would measure the PSF with."""
        if estimate is None or estimate.stars >= self.cfg.psf_min_stars:
            return False
        meter = self.psf_meter
        n, good = meter.last_n, meter.last_good
        _, sigma, ellipticity, _ = meter.last_stars()
        p = meter.per_star
        return combine_stars(sigma, ellipticity, p["cxx"][:n][good], p["cyy"][:n][good],
                             p["cxy"][:n][good], meter.last_snr[good],
                             self.cfg.psf_min_stars) is None

    def _meter(self, cand: np.ndarray, peak: np.ndarray, noise: np.ndarray,
               min_stars: int | None = None):
        """The PSF meter on the candidates that pass for stars: ``cand`` (padded flat
        indices, brightest first) where each is measured from, ``peak`` its brightest
        pixel, ``noise`` the pixel noise there; ``min_stars`` as the meter's."""
        n = len(cand)
        if n == 0:
            return None
        # Hot pixels and one-pixel hits the first impulse pass left (it spares anything
        # a sharp star could be) stand above their 3x3 median by nearly their whole
        # height: they do not take the stars' places. The median is the impulse
        # stage's, of the frame as it arrived.
        value = self.psf_values[:n]
        np.take(self.input.padded.ravel(), peak, out=self.psf_reads[:n], mode="clip")
        np.copyto(value, self.psf_reads[:n])
        unsaturated = value < self.saturation
        np.take(self.impulses.median_pad.ravel(), peak, out=self.psf_reads[:n], mode="clip")
        np.subtract(value, self.psf_reads[:n], out=self.psf_contrast[:n])
        np.subtract(value, np.take(self.bg_pad.ravel(), peak, mode="clip"), out=value)
        np.divide(self.psf_contrast[:n], np.maximum(value, 1e-6), out=self.psf_contrast[:n])
        # saturated peaks cannot be measured, and the bright pieces of particle tracks
        # (dozens in an event) are not round: neither takes a star's place
        star = np.flatnonzero((self.psf_contrast[:n] < _PSF_IMPULSE_CONTRAST) & unsaturated
                              & self._round(cand, n))[:_PSF_STARS]
        m = len(star)
        if m == 0:
            return None
        self.psf_cand[:m] = cand[star]
        self.psf_noise[:m] = noise[star]
        rows, cols = self.layout.frame_position(self.psf_cand[:m])
        # under multiplicative noise the impulse filter clips the speckles of star cores:
        # their shape is measured on the frame as delivered
        frame = self.input.padded if self.speckle_fit is None else self.delivered_pad
        return self.psf_meter.measure(m, frame, self.bg_pad, self.psf_cand, self.psf_noise,
                                      self.saturation, self.psf.sigma_px,
                                      self._edge_distance(rows, cols), min_stars=min_stars)

    def _edge_distance(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Pixels from each (row, col) to the frame's nearest edge (a view of a buffer)."""
        h, w = self.input.shape
        out = self.edge_px[:len(rows)]
        np.minimum(rows, cols, out=out, casting="unsafe")
        np.minimum(out, h - 1 - rows, out=out)
        np.minimum(out, w - 1 - cols, out=out)
        return out

    def _round(self, cand: np.ndarray, n: int) -> np.ndarray:
        """Whether the light in the 5x5 pixels around each of ``cand[:n]`` is round: the
        ellipticity of its central second moments (above the background) under
        ``_PSF_ROUND``. A star's is (at any sub-pixel phase); a track's is not."""
        idx = self.round_index[:n]
        np.add(cand[:n, None], self.round_offsets[None, :], out=idx)
        win = self.round_values[:n]
        np.take(self.input.padded.ravel(), idx, out=self.round_reads[:n], mode="clip")
        np.copyto(win, self.round_reads[:n])
        np.subtract(win, np.take(self.bg_pad.ravel(), cand[:n], mode="clip")[:, None],
                    out=win)
        np.maximum(win, 0.0, out=win)
        m = win @ self.round_moments                    # (n, 6): 1, x, y, x^2, y^2, xy
        with np.errstate(invalid="ignore", divide="ignore"):
            s0 = m[:, 0]
            mx, my = m[:, 1] / s0, m[:, 2] / s0
            mxx, myy = m[:, 3] / s0 - mx * mx, m[:, 4] / s0 - my * my
            mxy = m[:, 5] / s0 - mx * my
            e = np.hypot(mxx - myy, 2.0 * mxy) / (mxx + myy)
        return e < _PSF_ROUND

    def _bright_threshold(self, factor: float = 1.0) -> None:
        """The PSF stage's threshold (uint16): background + factor * psf_min_peak_sigma *
        pixel noise, in whole ADU."""
        np.multiply(self.noise, factor * self.cfg.psf_min_peak_sigma, out=self.float_grid)
        np.add(self.float_grid, self.level, out=self.float_grid)
        np.clip(self.float_grid, 0.0, 65535.0, out=self.float_grid)
        np.rint(self.float_grid, out=self.float_grid)
        np.copyto(self.int_grid, self.float_grid, casting="unsafe")
        self.grid.upsample(self.int_grid, self.bright_threshold)

    def _noise_at(self, flat: np.ndarray, out: np.ndarray) -> np.ndarray:
        return self.grid.at(self.noise, flat, out)

    def _matched_filter(self, src: np.ndarray, dst: np.ndarray) -> None:
        cv2.GaussianBlur(src, self.ksize, self.filter_sigma, dst=dst,
                         borderType=cv2.BORDER_REFLECT)

    def _tail_threshold(self) -> None:
        """threshold_k for this frame (tracker.detect.threshold).

        The Gaussian level of the false-alarm budget (or ``threshold_sigma``
        if set), moved to the same tail probability for the frame's own
        noise distribution: by the saddlepoint of its background pixels, or,
        when too few tiles are free of stars for that, by Cornish-Fisher
        from the filtered background's skewness.
        """
        u = (self.peak_threshold if self.cfg.threshold_sigma is None
             else float(self.cfg.threshold_sigma))
        self.threshold_u = u
        skewness = self.grid.skewness()
        k = None
        if skewness > _TAIL_SKEWNESS:   # noise near Gaussian needs no histogram
            self._configure_tail()
            self.tail.sample(self.input.padded, self.level, self.noise)
            k = self.tail.threshold(u, self.noise_f, self.filter_gain)
        self.threshold_k = max(u, k) if k is not None else skewed_threshold(u, skewness)
        self.skewed = skewness > _TAIL_SKEWNESS

    def _configure_tail(self) -> None:
        if self._tail_kernel is not self.kernel:
            self.tail.configure(self.kernel)
            self._tail_kernel = self.kernel

    def _constant_sky(self) -> None:
        """Where the sky is flat to within its rounding, its threshold from the noise it
        may have, not from rounding noise that is not there.

        A tile of an integer frame whose sky's pixels nearly all read its level (a
        noiseless 8-bit sky such as the seed's glare model away from the glare, or
        sparse photon counts on a black one) measures no noise, and its filtered
        noise sits at the floor of white rounding noise, 1/12 ADU^2 a pixel: k times
        that floor asks a star for about five pixels one ADU above the sky. Its
        rounding is a constant the level holds; the noise it may have reads one
        above the level at a rate bounded by its 3x3 neighbourhood's lattice
        samples (tracker.detect.background.BackgroundGrid.above_nearby,
        tracker.detect.threshold.constant_sky_rate), and the false-alarm budget's
        tail probability for that sparse noise (NoiseTail.constant_sky) is the
        threshold where it is below the floor's: the filtered noise becomes that
        level over k, where the tile's own measurement is not above the floor. A
        frame whose filtered background is skewed has noise its lattice sees (sparse
        photon counts of one, two or more ADU), its tail modelled from that
        (:meth:`_tail_threshold`), and keeps its threshold.
        """
        if self.skewed:   # a tail the filtered background shows, modelled as such
            return
        floor = np.float32(QUANTISATION_NOISE_ADU * self.filter_gain)
        at_floor = self.noise_f <= floor
        if not at_floor.any():
            return
        above, samples = self.grid.above_nearby(), self.grid.samples_near
        # the frame's own rate over the tiles at the floor: a bound from one tile's
        # neighbourhood is low by chance in some of a thousand
        frame_rate = (float(np.sum(self.grid.above[at_floor]))
                      / (np.count_nonzero(at_floor) * self.grid.samples.shape[-1]))
        rate = np.maximum(constant_sky_rate(above, samples), frame_rate)
        # rates rounded up to steps of 5 % from _RATE_LOW (a lower one taken as that),
        # each step's level computed once per filter; above _RATE_HIGH none is lower
        # than the floor's
        steps = np.ceil(np.log(np.maximum(rate[at_floor], _RATE_LOW))
                        / _RATE_STEP).astype(np.int64) - self._low_step
        levels = self.sky_levels
        levels.fill(np.inf)
        table = self.rate_levels
        if self._rate_key != (self._filter_key, self.threshold_u):
            self._rate_key = (self._filter_key, self.threshold_u)
            table.fill(np.nan)
        for step in np.unique(steps[steps < len(table)]):
            if np.isnan(table[step]):
                self._configure_tail()
                table[step] = self.tail.constant_sky(
                    self.threshold_u, math.exp((step + self._low_step) * _RATE_STEP),
                    self.filter_gain)
            levels.ravel()[np.flatnonzero(at_floor)[steps == step]] = table[step]
        lower = levels < self.threshold_k * floor
        self.noise_f[lower] = levels[lower] / self.threshold_k

    def _sky_side_median(self, grids: tuple[tuple[np.ndarray, np.ndarray], ...]) -> None:
        """Each (raw, out) of ``grids`` (one value a tile, unsmoothed; the 3x3 median of
        the grid stats): at the tiles beside a body (``beside_body``: across its edge, or
        beside a saturated tile) at the sky's level (``sky_edge``), ``out`` the median of
        ``raw`` over those of its 3x3 neighbours that are sky too (beside a body or away
        from every body, not the body's own tiles). The last pair is the noise:
        a tile whose own noise is over ``_SKY_SIDE_OWN`` times that median holds a
        sliver of the body or a bright star, and keeps the plain median in every grid.

        The plain 3x3 median takes a sky tile beside lit ground as much from the
        ground's tiles as from the sky's: under a horizon the filtered frame less
        its interpolated background spreads by some 200 ADU where the sky's spreads
        by 0.5, and a row of such tiles below a sky tile, with one straddling the
        edge beside it, is the median's majority; the threshold there rose out of
        reach of stars well above the horizon. A sky tile beside a saturated one that
        does not straddle its edge is no different: its own samples are sky, but the
        ground's tiles below it and slivers of ground in its sky neighbours (hills too
        small to mark their tiles as an edge) made five of its nine (lunar design seeds:
        2 stars of 1288 more found, 4 false detections fewer). Of an even count of sky
        neighbours (common) the upper middle value is taken: with three or four of them
        the lower one sets the threshold low often enough to let noise peaks through.
        """
        pad = self.sky_pad
        where = np.flatnonzero(self.sky_edge)
        rows, cols = np.divmod(where, self.sky_edge.shape[1])
        around = (((rows + 1) * pad.shape[1] + cols + 1)[:, None]
                  + self.sky_pad_offsets[None, :])
        body = self.near_body & ~self.beside_body
        medians = []
        for raw, _ in grids:
            pad.fill(np.nan)
            inner = pad[1:-1, 1:-1]
            np.copyto(inner, raw)
            inner[body] = np.nan
            values = pad.ravel()[around]
            values.sort(axis=1)                       # not a number (a body's tile) last
            count = np.count_nonzero(~np.isnan(values), axis=1)
            medians.append(values[np.arange(len(where)), count // 2])
        sky = grids[-1][0].ravel()[where] <= _SKY_SIDE_OWN * medians[-1]
        for (_, out), middle in zip(grids, medians, strict=True):
            out.ravel()[where[sky]] = middle[sky]

    def _make_threshold(self, factor: float) -> None:
        """Threshold image: background + level left + factor * threshold_k * noise; its
        height is raised near the borders by :meth:`_raise_edges`, which the peak search
        calls on each slab of rows it compares. In the ``own_threshold`` tiles the height
        over the background is at most the tile's own (:meth:`_mark_own_threshold`)."""
        np.multiply(self.noise_f, factor * self.threshold_k, out=self.term_grid)
        np.add(self.term_grid, self.residual, out=self.term_grid)
        np.add(self.term_grid, self.level, out=self.float_grid)
        self.grid.upsample(self.float_grid, self.threshold)
        self.grid.cap_in_tiles(self.float_grid, self.threshold, self.beside_body)
        self.grid.cap_over_in_tiles(self.term_grid, self.threshold, self.bg,
                                    self.own_threshold)

    def _light_clips(self, bg: np.ndarray) -> np.ndarray:
        """Whether full scale lies far above each background ``bg`` (ADU): by
        ``_CLIP_SIGMAS`` of the noise of a smooth sky at that level (the frame's sky
        noise model), so that a pixel there was clipped by light, not by noise.

        8-bit frames with noise of a third of full scale (the seed's written
        Gaussian+Poisson) clip the sky's own pixels at full scale, a few per cent
        of them: such a pixel says nothing about a star, and a fit that took it
        for one's clipped core would be pulled to it.
        """
        level0, var0, slope = self.sky_model
        return (self.saturation - bg) ** 2 > _CLIP_SIGMAS ** 2 * (
            var0 + slope * np.maximum(bg - level0, 0.0))

    def _centre_plateaus(self, n: int, cand: np.ndarray, v: dict, light: np.ndarray) -> None:
        """Centre the stars whose clipped core nearly fills the centroid's window on that
        core (the clipped pixels joined to its peak, :meth:`_own_core`): the clipped
        pixels are those inside the PSF's contour at full scale,
        symmetric about the star's centre, and their mean position is it (to about a
        tenth of a pixel), where the window has too few unclipped pixels left to fit.
        At most ``_PLATEAU_STARS`` of them (the first candidates), in boxes as wide
        as the widest window; only where light clipped them (``light`` (n,),
        :meth:`_light_clips`)."""
        clipped = np.flatnonzero((v["raw_peak"][:n] >= self.saturation)
                                 & light)[:_PLATEAU_STARS]
        k = len(clipped)
        if k == 0:
            return
        idx = self.plateau_index[:k]
        np.add(cand[clipped, None], self.plateau_offsets[None, :], out=idx)
        reads = self.plateau_reads[:k]
        np.take(self.input.padded.ravel(), idx, out=reads, mode="clip")
        full = self.plateau_full[:k]
        np.greater_equal(reads, self.saturation, out=full)
        least = math.pi * (_PLATEAU_FILL * self.radius) ** 2
        wide = np.flatnonzero(full.sum(axis=1) >= least)   # the own core is no larger
        if len(wide) == 0:
            return
        core = self._own_core(full[wide])
        count = core.sum(axis=1)
        fills = count >= least
        wide = wide[fills]
        mean = (core[fills] @ self.plateau_xy) / count[fills, None]
        v["x0"][clipped[wide]] = mean[:, 0]
        v["y0"][clipped[wide]] = mean[:, 1]

    def _own_core(self, full: np.ndarray) -> np.ndarray:
        """Of ``full`` ((k, box) bool: the clipped pixels of :meth:`_centre_plateaus`'
        boxes), each star's own core as (k, box) bool: those joined through clipped pixels
        (4-connected) to the clipped ones of the candidate's 3 x 3 at the box's centre
        (the filter's peak may sit just beside them). A body clipped beside a star (lit
        ground 7 px below a star of peak SNR 46, lunar bench) is no part of its core, and
        its pixels in the box pulled the core's mean 8 px onto the ground."""
        k = len(full)
        side = self.plateau_core.shape[1]
        clipped = full.reshape(k, side, side)
        core, grow = self.plateau_core[:k], self.plateau_grow[:k]
        core.fill(False)
        middle = np.s_[:, side // 2 - 1:side // 2 + 2, side // 2 - 1:side // 2 + 2]
        core[middle] = clipped[middle]
        for _ in range(side * side):
            np.copyto(grow, core)
            grow[:, 1:] |= core[:, :-1]
            grow[:, :-1] |= core[:, 1:]
            grow[:, :, 1:] |= core[:, :, :-1]
            grow[:, :, :-1] |= core[:, :, 1:]
            grow &= clipped
            if np.array_equal(grow, core):
                break
            np.copyto(core, grow)
        return core.reshape(k, side * side)

    def _centre_on_filter(self, n: int, cand: np.ndarray, v: dict, light: np.ndarray) -> None:
        """Centre the saturated stars of a frame whose noise clips at full scale on the
        peak of the search's filtered image, by a parabola through it and its
        neighbours along each axis.

        There (:meth:`_set_filter`) the filter is the Gaussian of a saturated star's
        clipped core, and its peak is where that core matches best against every
        pixel of the window; the fit of the PSF's Gaussian (tracker.detect.fit) has
        no pixels to leave out (full scale is the noise's as often as the light's)
        and fits a bell to a flat top. Saturated stars at MF SNR 7-11 under the
        seed's written Gaussian+Poisson (tests/test_detect_clipped_noise.py): RMS
        error 1.00 -> 0.55 px, 5 -> 0 of 397 detections over 2 px off.
        """
        which = np.flatnonzero((v["raw_peak"][:n] >= self.saturation) & ~light)
        if len(which) == 0:
            return
        at = cand[which]
        flat = self.filt_pad.ravel()
        centre = flat[at].astype(np.float64)
        for key, step in (("x0", 1), ("y0", self.layout.stride)):
            lo = flat[at - step].astype(np.float64)
            hi = flat[at + step].astype(np.float64)
            curve = lo - 2.0 * centre + hi
            offset = np.divide(0.5 * (lo - hi), curve, out=np.zeros_like(curve),
                               where=curve < 0)
            v[key][which] = np.clip(offset, -0.5, 0.5)

    def _edge_gains(self, top: np.ndarray, left: np.ndarray) -> None:
        """Spread the filter's noise gains at the first rows (``top``) and columns
        (``left``; the last ones mirror them) over the four border strips they scale."""
        r, c = len(top), len(left)
        self.edge_rows, self.edge_cols = r, c
        self.edge_gain_strips = (self.row_gains[0, :r], self.row_gains[1, :r],
                           self.col_gains[0, :, :c], self.col_gains[1, :, :c])
        for gain, profile in zip(self.edge_gain_strips, (top[:, None], top[::-1, None],
                                                   left[None, :], left[None, ::-1]),
                                 strict=True):
            np.copyto(gain, profile)

    def _raise_edges(self, first: int, end: int) -> None:
        """Scale the threshold's height above the background near the borders, on frame
        rows [first, end).

        There the reflected filter has more noise (``_reflected_noise_gain``).
        The peak search calls this on each slab of rows just before comparing
        it (tracker.detect.peaks), in that slab's thread, while the rows come
        into its cache. Each pixel meets the strips in one order (top, bottom,
        left, right), the same float32 operations as over the whole frame at
        once. The strips in OpenCV's arithmetic, which runs along their rows in
        one call (numpy's would step a loop of a few pixels per row down the
        side strips): a quarter of the time.
        """
        t, b = self.threshold, self.bg
        r, c = self.edge_rows, self.edge_cols
        parts = []
        for start, gain in ((0, self.row_gains[0]), (self.layout.rows - r, self.row_gains[1])):
            lo, hi = max(first, start), min(end, start + r)
            if lo < hi:
                parts.append((np.s_[lo:hi], gain[lo - start:hi - start]))
        parts.append((np.s_[first:end, :c], self.col_gains[0, first:end, :c]))
        parts.append((np.s_[first:end, -c:], self.col_gains[1, first:end, :c]))
        for sl, gain in parts:
            strip, under = t[sl], b[sl]
            cv2.subtract(strip, under, dst=strip)
            cv2.multiply(strip, gain, dst=strip)
            cv2.add(strip, under, dst=strip)

    def _measure(self, n: int) -> int:
        """Centroid the candidates, reject sharp spots, fill the star table."""
        if n == 0:
            return 0
        cand = self.peaks.cand[:n]
        noise, level = self.cand_noise[:n], self.cand_level[:n]
        self.grid.at(self.noise, cand, noise)
        self.grid.at(self.residual, cand, level)
        rows, cols = self.layout.frame_position(cand)
        inward_starts(cand, rows, cols, self.input.shape, self.input.padded, self.bg_pad,
                      self.layout.stride, self.sigma)
        bg = np.take(self.bg_pad.ravel(), cand, mode="clip")
        light = self._light_clips(bg)
        censor = self.cand_censor[:n]
        censor.fill(np.inf)
        censor[light] = self.saturation
        v = self.centroider.measure(n, self.input.padded, self.bg_pad, cand, noise, level,
                                    censor, self.peaks.blended[:n])
        across_x, across_y = cut_axes(rows, cols, self.input.shape, self.radius)
        judge_whole(v, across_x, across_y)
        if self.speckle_fit is None:
            self._centre_plateaus(n, cand, v, light)
            if self.noise_clips:
                self._centre_on_filter(n, cand, v, light)
        if self.speckle_fit is not None:  # its likelihood handles saturated stars too
            merged = self.centroider.refine_multiplicative(
                n, self.speckle_fit, cand, self.delivered_pad, self.bg_pad, level,
                2.0 * self.sigma)
        else:
            merged = False
        # Shape tests against the PSF, for spots whose shape is known (their SNR with
        # their own shot noise, tracker.detect.significance); under multiplicative
        # noise a star's own pixels are spiky, so none applies.
        # A spot with a pixel at full scale far above its background (light, not noise,
        # reached it) is judged at any SNR: on glare a faint one's noise is high, but a
        # star that bright has its shape
        saturated = v["raw_peak"] >= self.saturation
        clipped = saturated & light
        known = shot_noise_snr(v["weighted"], v["snr"])
        multiplicative = self.speckle_fit is not None
        judged = ((known >= self.cfg.sharp_min_snr) | clipped) & (not multiplicative)
        sharp = sharp_spots(v, noise, known, judged, saturated, clipped, self.cfg, self.psf,
                            self.expected_size, self.phase_low, self.star_roughness,
                            multiplicative)
        if not multiplicative:
            # fainter than the shape tests judge: a hot pixel or a particle's charge the
            # impulse stage spared is a point on its 3 x 3, beyond a star's noise
            sharp |= self._point_like(cand, v, noise, level, ~(judged | saturated | sharp))
            # a short track under a sharp PSF: elongated and narrower across than the
            # frame's stars at its own pixel phase, or a round hit narrower overall
            # (tracker.detect.line_spot)
            sharp |= self._track_like(cand, v, noise, level, saturated & ~clipped, sharp)
        n_sharp = int(np.count_nonzero(sharp))
        self.counters["sharp_spots"] = n_sharp
        self.counters["cosmic_rays"] += n_sharp
        if multiplicative:   # a spot's peak is one speckle: its flux/peak says nothing
            broad = body = np.zeros(n, bool)
        else:
            broad, body = broad_spots(v, sharp, self.saturation, self.cfg)
        embedded = self._embedded(n, cand, v) & ~sharp
        # a broad maximum with a body on most sides is part of it (a ghost's rim); a star
        # merely wider than the frame's PSF (a corner of a lens out of focus) has its own
        # wings on some sides
        on_body = broad & (self.surroundings.sky_sectors[:n] < _BROAD_SKY_SECTORS)
        masked = (body | embedded | on_body) & ~sharp
        masked |= self._on_light(n, cand, v, ~(sharp | merged | masked), saturated)
        self.counters["masked"] = int(np.count_nonzero(masked))
        # a star centred beyond the frame shows less than half its light: no centre
        off = beyond_frame(cols + v["x0"], rows + v["y0"], self.input.shape)
        self.counters["beyond_edge"] = int(np.count_nonzero(off))
        keep = np.flatnonzero(~(sharp | merged | masked | off))
        # most significant first: a bright bump in a noisy patch (glare, foliage) ranks
        # below a star of the same height on dark sky
        keep = keep[np.argsort(-v["snr"][keep], kind="stable")]
        self.counters["left_out"] = max(0, len(keep) - self.table.capacity)
        keep = keep[: self.table.capacity]
        count = len(keep)
        rows, cols = rows[keep], cols[keep]
        s = self.table.stars
        s["x"][:count] = cols + v["x0"][keep]
        s["y"][:count] = rows + v["y0"][keep]
        # the PSF-weighted flux (tracker.detect.weighted_flux); a saturated star's plain sum
        s["flux"][:count] = np.where(saturated[keep], v["flux"][keep],
                                     v["weighted"][keep] / self.capture)
        s["peak"][:count] = v["peak"][keep]
        s["snr"][:count] = v["snr"][keep]
        s["npix"][:count] = v["npix"][keep]
        flags = np.zeros(count, np.uint16)
        h, w = self.input.shape
        r = self.radius
        flags[(cols < r) | (rows < r) | (cols > w - 1 - r) | (rows > h - 1 - r)] |= StarFlag.EDGE
        flags[v["raw_peak"][keep] >= self.saturation] |= StarFlag.SATURATED
        flags[(v["ellipticity"][keep] > self.cfg.elongation_max)
              & judged[keep]] |= StarFlag.ELONGATED
        flags[self.peaks.blended[:n][keep]] |= StarFlag.BLENDED
        flags[broad[keep]] |= StarFlag.EXTENDED
        s["flags"][:count] = flags
        return count

    def _point_like(self, cand: np.ndarray, v: dict, noise: np.ndarray, level: np.ndarray,
                    which: np.ndarray) -> np.ndarray:
        """Those of the spots ``which`` whose 3 x 3 holds a point (a hot pixel, a particle's
        charge) beyond a star's noise (tracker.detect.point_spot): (n,) bool.

        Made against a PSF this frame's stars measured, at least ``CHARGE_SIGMA_PX``
        wide (a sharper star is as sharp as a particle's charge); on a frame whose
        stars did not measure it (one carried from elsewhere may be wider than its
        stars), against ``CHARGE_SIGMA_PX``, the sharpest PSF the test is made for: a
        hot pixel's light is in one pixel whatever the PSF, and a star of a wider PSF
        than the one tested against reads a point component below zero. Only on spots
        fainter than ``sharp_min_snr`` (brighter, a PSF that is no Gaussian, a Moffat's
        core, reads as a point component growing with the flux, and the shape tests
        judge them). The pixels' noise model is measured on all of them together
        (tracker.detect.point_spot.pixel_noise_model), and a spot it makes brighter
        than ``sharp_min_snr`` is judged against the background's noise and 1 ADU^2
        per ADU as before (a spot that bright is past the test's reach: on a nearly
        noiseless sky of salt and pepper the stars' light measures nearly noiseless
        too, and a PSF that is no Gaussian and the impulses replaced on it are all
        their residual). The noise is never taken below the rounding's.
        """
        out = np.zeros(len(cand), bool)
        sigma_px = self.psf.sigma_px if self.psf.stars else CHARGE_SIGMA_PX
        spots = np.flatnonzero(which)
        if sigma_px < CHARGE_SIGMA_PX or len(spots) == 0:
            return out
        padded, bg = self.input.padded.ravel(), self.bg_pad.ravel()
        offsets = (POINT_OFFSETS[:, 0] * self.layout.stride + POINT_OFFSETS[:, 1])[None, :]
        ox, oy = np.rint(v["x0"][spots]), np.rint(v["y0"][spots])
        at = (cand[spots] + oy.astype(np.intp) * self.layout.stride
              + ox.astype(np.intp))[:, None] + offsets
        light = np.take(padded, at, mode="clip").astype(np.float64)
        light -= np.take(bg, at, mode="clip")
        light -= level[spots, None]
        phase_x, phase_y = v["x0"][spots] - ox, v["y0"][spots] - oy
        scale, shot_adu = pixel_noise_model(light, phase_x, phase_y, noise[spots], sigma_px)
        measured = np.maximum(math.sqrt(scale) * noise[spots], QUANTISATION_NOISE_ADU)
        faint = shot_noise_snr(v["weighted"][spots], v["snr"][spots] * noise[spots] / measured,
                               shot_adu) < self.cfg.sharp_min_snr
        z = point_significance(light, phase_x, phase_y,
                               np.where(faint, measured, noise[spots]), sigma_px,
                               np.where(faint, shot_adu, SHOT_ADU))
        out[spots] = z > Z_STAR_LOSS
        return out

    def _on_light(self, n: int, cand: np.ndarray, v: dict, stars: np.ndarray,
                  saturated: np.ndarray) -> np.ndarray:
        """Those of the unsaturated ``stars`` whose filtered peak clears the threshold only
        with light under it that the background grid does not hold (tracker.detect.
        ring_light): the local sky on a ring ``LOCAL_SKY_SIGMAS`` PSF sigmas around the
        spot, or the halo of a star at least ``HALO_CONTRAST`` times brighter, from the
        window's radius to ``_HALO_REACH_SIGMAS`` PSF sigmas out: (n,) bool."""
        out = np.zeros(n, bool)
        value = self.peaks.cand_values[:n]
        faint = np.flatnonzero(stars & ~saturated)
        if len(faint) == 0:
            return out
        rows, cols = self.layout.frame_position(cand)
        # candidates are ranked by their filtered peak, brightest first
        bright = np.flatnonzero(stars & (value >= HALO_CONTRAST * value[faint].min()))
        bright = bright[:_HALO_STARS]
        x, y = cols + v["x0"], rows + v["y0"]
        h, w = self.input.shape
        reach = int(math.ceil(LOCAL_SKY_SIGMAS * self.sigma + 0.5))   # the ring in the frame
        pairs = 0
        for first in range(0, len(faint), _LIGHT_CHUNK):
            some = faint[first:first + _LIGHT_CHUNK]
            level, clear, floor = self._light_floor(some, rows, cols)
            px, py = cols[some].astype(np.float64), rows[some].astype(np.float64)
            inside = ((rows[some] >= reach) & (cols[some] >= reach) & (rows[some] < h - reach)
                      & (cols[some] < w - reach))
            median = np.empty(len(some))
            pixels = np.full(len(some), len(self.local_ring))
            median[inside] = self.rings.around(self.filt_pad.ravel(), self.bg_pad.ravel(),
                                               cand[some[inside]], self.local_ring,
                                               floor[inside])
            cut = np.flatnonzero(~inside)
            if len(cut):
                median[cut], pixels[cut] = self.rings.light(
                    self.filt, self.bg, px[cut], py[cut],
                    np.full(len(cut), LOCAL_SKY_SIGMAS * self.sigma), px[cut], py[cut], 0.0,
                    floor[cut])
            out[some[self._under_light(some, level, clear, median, pixels, LOCAL_ERRORS)]] = True
            # the contrast first: the pairs' distances only for the stars bright enough
            b, f = np.nonzero(value[bright][:, None] >= HALO_CONTRAST * value[some][None, :])
            radius = np.hypot(px[f] - x[bright[b]], py[f] - y[bright[b]])
            near = (radius >= self.radius) & (radius <= _HALO_REACH_SIGMAS * self.sigma)
            b, f, radius = b[near], f[near], radius[near]
            b, f = b[:_HALO_PAIRS - pairs], f[:_HALO_PAIRS - pairs]
            radius = radius[:len(b)]
            pairs += len(b)
            if len(b) == 0:
                continue
            star, spot = bright[b], some[f]
            ring = self.rings.light(self.filt, self.bg, x[star], y[star], radius, x[spot],
                                    y[spot], SPOT_SIGMAS * math.sqrt(2.0) * self.filter_sigma,
                                    floor[f])
            out[spot[self._under_light(spot, level[f], clear[f], *ring, HALO_ERRORS)]] = True
        return out

    def _light_floor(self, spot: np.ndarray, rows: np.ndarray,
                     cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the sky's filtered level, the threshold over the background, the floor) at each
        candidate ``spot`` (indices into the candidates at frame pixels ``rows``,
        ``cols``), ADU, (p,) each. The floor is the ring's light (its median over the
        background) below which it cannot take the spot away (:meth:`_under_light`): the
        sky's level and the spot's filtered peak over the threshold, lowered by a part in
        a million of the sum of their sizes (the rounding of the sums, parts in 1e16, and
        the level an ulp of float32 off, stays far within it); -inf where the spot does
        not clear the threshold."""
        level = self.grid.at(self.residual, self.peaks.cand[spot],
                             np.zeros(len(spot), np.float32))
        clear = self.threshold[rows[spot], cols[spot]] - self.bg[rows[spot], cols[spot]]
        value = self.peaks.cand_values[spot].astype(np.float64)
        over = value - clear
        floor = level + over - _FLOOR_ROUNDING * (np.abs(level) + np.abs(value)
                                                  + np.abs(clear) + 1.0)
        return level, clear, np.where(over > 0.0, floor, -np.inf)

    def _under_light(self, spot: np.ndarray, level: np.ndarray, clear: np.ndarray,
                     median: np.ndarray, pixels: np.ndarray, errors: float) -> np.ndarray:
        """Whether each candidate ``spot`` falls short of the threshold over the background
        ``clear`` once the light of its ring (``median``, ``pixels``: tracker.detect.
        ring_light.LightRings.light) is taken from its filtered peak, that light counted
        ``errors`` standard errors above the sky's filtered level ``level``
        (:meth:`_light_floor`)."""
        light = light_over_sky(median, pixels, level, self.peaks.cand_noise[spot],
                               self.filter_sigma, errors)
        return self.peaks.cand_values[spot] - light <= clear

    def _track_like(self, cand: np.ndarray, v: dict, noise: np.ndarray, level: np.ndarray,
                    untested: np.ndarray, sharp: np.ndarray) -> np.ndarray:
        """The spots not yet found sharp whose 5 x 5 light is a particle's short track,
        against the frame's bright unsaturated spots' shape under the PSF searched with
        (tracker.detect.line_spot): (n,) bool. The pixels light clipped (at or above
        ``cand_censor``, :meth:`_measure`) are left out of the fit, and a saturated spot is
        tested when at least ``LINE_USABLE`` of its 5 x 5 are left (a track's clipped core
        is as elongated as its light, a star's round). A spot whose 5 x 5 reaches beyond
        the frame is fitted on its pixels inside it, as tracker.detect.edge centroids it
        (at least ``LINE_USABLE``), and sets no reference. Spots ``untested`` (saturated
        where the sky's noise, not light, reaches full scale) are not tested."""
        out = np.zeros(len(cand), bool)
        rows, cols = self.layout.frame_position(cand)
        ox, oy = np.rint(v["x0"]), np.rint(v["y0"])
        r = LINE_RADIUS
        h, w = self.input.shape
        inside = (cols + ox >= 0) & (rows + oy >= 0) & (cols + ox < w) & (rows + oy < h)
        spots = np.flatnonzero(inside & ~untested & ~sharp & (v["weighted"] > 0))
        if len(spots) < LINE_REFERENCE_SPOTS:
            return out
        saturated = v["raw_peak"][spots] >= self.saturation
        padded, bg = self.input.padded.ravel(), self.bg_pad.ravel()
        axis = np.arange(-r, r + 1)
        offsets = (axis[:, None] * self.layout.stride + axis[None, :]).ravel()[None, :]
        centre = (cand[spots] + oy[spots].astype(np.intp) * self.layout.stride
                  + ox[spots].astype(np.intp))
        phase_x, phase_y = v["x0"][spots] - ox[spots], v["y0"][spots] - oy[spots]
        # each spot's 5 x 5 pixels within the frame, row by row
        across_cols = (cols[spots] + ox[spots])[:, None] + axis
        across_rows = (rows[spots] + oy[spots])[:, None] + axis
        in_frame = (((across_rows >= 0) & (across_rows < h))[:, :, None]
                    & ((across_cols >= 0) & (across_cols < w))[:, None, :]).reshape(len(spots), -1)
        whole = in_frame.all(axis=1)
        coef = np.zeros((len(spots), 6))
        cov = np.zeros((len(spots), 3, 3))
        enough = np.ones(len(spots), bool)
        clipped = np.zeros((len(spots), offsets.size), bool)
        # _LINE_CHUNK spots at a time: the fit's (m, 6, 25) basis stays small
        for first in range(0, len(spots), _LINE_CHUNK):
            part = slice(first, first + _LINE_CHUNK)
            at = centre[part, None] + offsets
            raw = np.take(padded, at, mode="clip")
            usable = raw < self.cand_censor[spots[part], None]
            usable &= in_frame[part]
            if usable.all():
                usable = None        # nothing clipped: every pixel fitted, no weights
            else:
                np.logical_not(usable, out=clipped[part])
                clipped[part] &= in_frame[part]
                enough[part] = np.count_nonzero(usable, axis=1) >= LINE_USABLE
                usable |= ~enough[part, None]   # fitted whole, not tested
            light = raw.astype(np.float64)
            light -= np.take(bg, at, mode="clip")
            light -= level[spots[part], None]
            coef[part], cov[part] = line_fit(light, phase_x[part], phase_y[part],
                                             noise[spots[part]], self.psf.sigma_px,
                                             usable=usable)
        clipped[~saturated | ~whole] = False   # a core the frame's edge cuts is no shape
        floor = self._floor_fit(spots, centre, offsets, phase_x, phase_y, noise, level,
                                np.flatnonzero(enough & whole
                                               & (np.count_nonzero(clipped, axis=1) == 1)),
                                clipped)
        psf = self.psf
        # the PSF measured on this frame's stars: its own shear about the round sigma^2
        psf_shear = (psf.ellipticity * psf.sigma_px ** 2
                     * np.array([math.cos(2.0 * psf.angle_rad), math.sin(2.0 * psf.angle_rad)])
                     if psf.stars else None)
        reference = (v["snr"][spots] >= LINE_REFERENCE_SNR) & ~saturated & whole
        out[spots] = track_spots(coef, cov, reference,
                                 psf.sigma_px, self._measured_spots(centre), fitted=enough,
                                 clipped=clipped, ellipticity=psf.ellipticity,
                                 psf_shear=psf_shear, floor=floor)
        return out

    def _floor_fit(self, spots: np.ndarray, centre: np.ndarray, offsets: np.ndarray,
                   phase_x: np.ndarray, phase_y: np.ndarray, noise: np.ndarray,
                   level: np.ndarray, single: np.ndarray, clipped: np.ndarray):
        """tracker.detect.line_spot.floor_fit of the saturated spots ``single`` (indices
        among ``spots``, of one clipped pixel each): their fits with that pixel at its
        floor, those whose trace there bounds theirs, and the indices; None if none."""
        if len(single) == 0:
            return None
        at = centre[single, None] + offsets
        light = np.take(self.input.padded.ravel(), at, mode="clip").astype(np.float64)
        light -= np.take(self.bg_pad.ravel(), at, mode="clip")
        light -= level[spots[single], None]
        coef, cov, bounded = floor_fit(light, clipped[single], phase_x[single], phase_y[single],
                                       noise[spots[single]], self.psf.sigma_px)
        return coef[bounded], cov[bounded], single[bounded]

    def _measured_spots(self, centre: np.ndarray) -> np.ndarray | None:
        """Which of the spots (their central pixels ``centre``, padded flat indices) this
        frame's PSF was measured on (tracker.detect.psf: isolated, round, unsaturated
        stars, the impulses set aside), or None when it was not measured on the frame's
        stars. They set the stars' width for the short-track test's narrow spots: the
        bright spots at large may be broad bumps beside the Moon (the stars read 2
        sigma^2 narrower than their median: lunar bench, seed 1) or hits."""
        meter = self.psf_meter
        n = meter.last_n
        if not self.psf.stars or n == 0:
            return None
        good = meter.last_good
        rows, cols = self.layout.frame_position(meter.last_cand[:n][good])
        measured_at = np.sort(self.layout.flat_index(
            np.rint(rows + meter.per_star["y"][:n][good]).astype(np.intp),
            np.rint(cols + meter.per_star["x"][:n][good]).astype(np.intp)))
        if len(measured_at) == 0:
            return None
        which = np.minimum(np.searchsorted(measured_at, centre), len(measured_at) - 1)
        return measured_at[which] == centre

    def _embedded(self, n: int, cand: np.ndarray, v: dict) -> np.ndarray:
        """Candidates with fewer than ``min_sky_sectors`` sky sectors around them
        (tracker.detect.surroundings)."""
        if self.cfg.min_sky_sectors == 0:
            return np.zeros(n, bool)
        level0, var0, slope = self.sky_model          # of the background stage's grids
        bg = self.cand_level[:n]                    # scratch: the background at each
        np.take(self.bg_pad.ravel(), cand, out=bg, mode="clip")
        sky = self.cand_noise[:n]                   # scratch from here on
        np.subtract(bg, level0, out=sky)
        np.maximum(sky, 0.0, out=sky)
        np.multiply(sky, slope, out=sky)
        np.add(sky, var0, out=sky)
        np.sqrt(sky, out=sky)
        sectors = self.surroundings.sky_sectors_of(n, self.input.padded, self.bg_pad, cand,
                                                   sky, v["peak"])
        # in or beside a textured tile (its noise well above the smooth sky's at its level)
        # a candidate must have sky on most sides: the edge of lit terrain or foliage is
        # ragged, and its twigs and boulders have sky on one side
        self._mark_texture()
        near = self.cand_near[:n]
        self.grid.at(self.near_texture.view(np.uint8), cand, near)
        need = np.where(near > 0, max(self.cfg.min_sky_sectors, _TEXTURED_SKY_SECTORS),
                        self.cfg.min_sky_sectors)
        # a thin line of light (a crescent, a ghost's ring) has sky across it, not along
        # it; a trailed frame's stars have their own light along the trail
        trail = common_elongation(v, n, self.saturation, self.peaks.blended)
        line = max(self.psf.ellipticity, trail) < _LINE_MAX_ELLIPTICITY
        embedded = (sectors < need) | (line & across_a_line(self.surroundings.light[:n],
                                                             self.surroundings.sky[:n]))
        # a saturated star's wings fall away from its centroid on every side (a body on
        # one side takes no more sectors from it than from an unsaturated star)
        clipped = embedded & (v["raw_peak"][:n] >= self.saturation)
        rows, cols = self.layout.frame_position(cand)
        reach = self.surroundings.max_outer + 1         # its rings stay inside the frame
        h, w = self.input.shape
        clipped &= (rows >= reach) & (cols >= reach) & (rows < h - reach) & (cols < w - reach)
        clipped = np.flatnonzero(clipped)
        if len(clipped):
            centre = (cand[clipped] + np.rint(v["y0"][clipped]).astype(np.intp)
                      * self.layout.stride + np.rint(v["x0"][clipped]).astype(np.intp))
            falling = self.surroundings.falling_sectors(
                self.input.padded, self.bg_pad, centre, sky[clipped], v["peak"][clipped],
                _WING_LEVEL * (self.saturation - bg[clipped]))
            embedded[clipped] = (np.sum(falling, axis=1) < need[clipped]) | (
                line & across_a_line(~falling, falling))
        embedded |= self._one_plateau(n, cand, v)
        return embedded

    def _smooth_sky_variance(self) -> np.ndarray:
        """The smooth sky's pixel variance at each tile's level (ADU^2, grid shape; the
        frame's sky noise model, tracker.detect.surroundings.sky_noise_model) in
        ``float_grid``, which is returned."""
        level0, var0, slope = self.sky_model
        np.subtract(self.level, level0, out=self.float_grid)
        np.maximum(self.float_grid, 0.0, out=self.float_grid)
        np.multiply(self.float_grid, slope, out=self.float_grid)
        np.add(self.float_grid, var0, out=self.float_grid)
        return self.float_grid

    def _mark_own_threshold(self) -> None:
        """Mark in ``own_threshold`` the smooth tiles beside a body's tile that is not: the
        threshold over the background there is the tile's own (:meth:`_make_threshold`),
        not interpolated towards that neighbour's.

        A tile is smooth when its pixel noise is within ``_TEXTURE_NOISE`` of the
        smooth sky's at its level (not ``textured``) and so is its own filtered
        noise, against that sky's filtered noise (its pixel noise times the
        filter's gain for white noise): its pixels are sky, glare or a ghost's
        flat disc with the photon noise of their light, and its own figure is
        theirs. A body's tile (textured, across an edge, or beside a saturated
        one) that is not smooth holds the filtered frame less the background
        spread by the body's light the filter carries over its edge and by the
        background's ramp towards it, not by noise: interpolated from its centre
        into the smooth tile beside it, that spread raised the threshold over
        stars a tile away from the body (issue 12).
        """
        self._mark_texture()
        smooth = self.own_threshold                       # scratch until the last step
        np.sqrt(self._smooth_sky_variance(), out=self.float_grid)
        np.multiply(self.float_grid, _TEXTURE_NOISE * self.filter_gain, out=self.float_grid)
        np.less_equal(self.grid.raw, self.float_grid, out=smooth)
        smooth &= ~self.textured
        body = self.body_tiles
        np.logical_or(self.textured, self.dark_side, out=body)
        body |= self.near_body
        body &= ~smooth
        np.copyto(self.float_grid, smooth)               # the smooth tiles, kept ...
        cv2.dilate(body.view(np.uint8), _TILE_NEIGHBOURS, dst=smooth.view(np.uint8))
        smooth &= self.float_grid > 0.0                  # ... beside a body's tile

    def _mark_texture(self) -> None:
        """Mark the textured tiles (noise well above the smooth sky's at their level, or
        lit ground at saturation) in ``textured``, and them and their neighbours in
        ``near_texture``."""
        np.multiply(self._smooth_sky_variance(), _TEXTURE_NOISE ** 2, out=self.float_grid)
        np.greater(np.square(self.noise), self.float_grid, out=self.textured)
        self.textured |= self.level >= _SATURATED_TILE * self.saturation   # flat, but ground
        cv2.dilate(self.textured.view(np.uint8), _TILE_NEIGHBOURS,
                   dst=self.near_texture.view(np.uint8))

    def _one_plateau(self, n: int, cand: np.ndarray, v: dict) -> np.ndarray:
        """Saturated candidates that share their clipped plateau with another: (n,) bool.

        A star's clipped core has one maximum, so two saturated candidates
        within the widest centroid window of each other, with the pixel
        halfway between them at full scale too, are pieces of one body (the
        lit edge of the Earth, a saturated crescent), or two stars whose
        cores have merged, neither of which can be centred. The pairs come
        from a sweep along x (each candidate against those up to the window
        to its right), at most ``_PLATEAU_PAIRS`` of them.
        """
        out = np.zeros(n, bool)
        sat = np.flatnonzero(v["raw_peak"][:n] >= self.saturation)
        if len(sat) < 2:
            return out
        rows, cols = self.layout.frame_position(cand[sat])
        order = np.argsort(cols + v["x0"][sat], kind="stable")
        sat = sat[order]
        x = (cols[order] + v["x0"][sat]).astype(np.float64)
        y = (rows[order] + v["y0"][sat]).astype(np.float64)
        m = len(sat)
        after = np.searchsorted(x, x + self.plateau_reach, side="right") - np.arange(1, m + 1)
        total = min(int(after.sum()), _PLATEAU_PAIRS)
        if total == 0:
            return out
        i = np.repeat(np.arange(m), after)[:total]
        j = i + 1 + np.arange(total) - np.repeat(np.cumsum(after) - after, after)[:total]
        near = np.hypot(x[i] - x[j], y[i] - y[j]) <= self.plateau_reach
        i, j = i[near], j[near]
        mid = self.layout.flat_index(np.rint(0.5 * (y[i] + y[j])).astype(np.intp),
                                     np.rint(0.5 * (x[i] + x[j])).astype(np.intp))
        joined = np.take(self.input.padded.ravel(), mid, mode="clip") >= self.saturation
        out[sat[i[joined]]] = True
        out[sat[j[joined]]] = True
        return out
