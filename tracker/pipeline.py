"""One frame through the stages: detect -> identify -> attitude.

Shared by ``tracker replay``, :func:`tracker.solve` and the service so all
compute the same thing. A detector is made per (shape, bit depth) and reused;
the :data:`DETECTORS_KEPT` most recently used are kept (a detector holds
buffers of about 40 bytes per pixel, so frames of ever new sizes must not
keep theirs). The solver (made on first use: it loads the catalogue and the
pattern database) keeps its tracking state between frames. Colour frames are
converted to grey as replay converts them (tracker.frame_array).
Identification runs only on frames whose size matches the configured camera,
since the camera model is what maps pixels to directions.

Windowed tracking (``identify.track_windows``): when the solver has a lock
and a rate, the frame is detected only in windows around the stars it
predicts plus a sweeping slice of the frame (tracker.identify.windows,
tracker.detect.windows) and solved from those; if they do not verify (or
the prediction is too uncertain for the largest window) the whole frame is
detected and solved as without a lock. With ``identify.track_stamps`` the
windows go to the lean stacked-window detector (tracker.detect.stamps; one
kept per window size, the :data:`DETECTORS_KEPT` last used) with the PSF
the full frames measured, except on one windowed frame in
``identify.track_lens_every``, which measures the PSF in its windows: that
frame (and every windowed frame without ``track_stamps``, or with another
detection method) goes through the full detector over a mosaic of the
windows (tracker.detect.windows). A mosaic detector is kept per window size
(the :data:`DETECTORS_KEPT` last used), each made by ``make_detector`` for
its mosaic of windows, with one slab thread (a mosaic is too small to cut),
buffers for pixels above threshold and impulses no larger than the mosaic
(about 40 MiB a detector instead of 70) and background tiles of a third of
the window: the star sits in the middle
tile, whose 3 x 3 median then takes the window's own sky around it. It
takes the PSF the full frames measured as given, and measures it in
the windows (folded into the same running estimate: tracker.detect.shared_psf).
A windowed frame's ``stages_ms``: ``track.plan`` (from the frame's start to
its windows: prediction and planning), ``windows.<stage>`` (the window
detector's stages), ``windows.gather`` (what the window detector does
outside its stages), ``trail``, ``identify.<stage>``.

Trailed stars: with a rate known, stars whose travel over the exposure
(from the rate: tracker.identify.predict) is long are re-centred by a
line-spread fit (tracker.detect.trail), whole frame or windows, and
detections of one trail that end on one centre are merged. In the stamp
detector's windows such stars are not point-fitted first (its ``refitted``:
the fit's centre would be replaced).

Each frame may come with its :class:`~tracker.astrometry.observer.Observer`
(absolute time, the observer's velocity), which the solver uses to correct
aberration. Its time also sets the proper-motion epoch: when it is further
than ``catalogue.epoch_step_years`` from the loaded catalogue's epoch, the
catalogue is propagated to it anew and the solver rebuilt (its tracking
state is lost: that frame is solved lost in space). Without an absolute
time the catalogue stays at ``catalogue.epoch_year`` (null: the time it was
loaded).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from tracker.astrometry.observer import Observer
from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.config import Config
from tracker.detect import Detections, Detector, make_detector
from tracker.detect.default import DefaultDetector, effective_sigma
from tracker.detect.shared_psf import SharedPsf
from tracker.detect.stamps import StampDetector
from tracker.detect.trail import TrailFit
from tracker.detect.windowed import later_within
from tracker.detect.windows import WindowDetector
from tracker.frame_array import to_grey
from tracker.identify import Solution, Solver, make_solver
from tracker.identify.windows import WindowPlanner

__all__ = ["Pipeline", "FrameResult", "DETECTORS_KEPT"]

log = logging.getLogger(__name__)

# Detectors kept for frame sizes seen lately: the camera's and one other.
DETECTORS_KEPT = 2


@dataclass
class FrameResult:
    """What one frame produced.

    ``solution`` is None when identification is off or was not attempted;
    ``solve_reason`` then says why (``"disabled"``, ``"frame_size"``).
    ``observer`` is the context the frame was processed with (what the
    solver corrected: ``observer.corrections``). ``windows``: how many
    windows the frame was detected in (0: the whole frame). ``time_ms`` is
    wall time; ``cpu_ms`` the process's CPU time over the frame and, on a
    frame detected whole, ``detect_cpu_ms`` over the full-frame detector's
    call (None on a windowed frame: each CPU clock read is a system call,
    and on a loaded machine a system call is a chance to be preempted and
    come back to cold caches, so the windowed path reads the clock only at
    its start and end), ms: every thread's, so the full-frame detector's
    slab threads count, and so would another thread of the process running
    meanwhile (benchmarks read them: a loaded machine inflates wall time
    far more than CPU time).
    """

    detections: Detections
    solution: Solution | None
    time_ms: float
    stages_ms: dict
    solve_reason: str | None = None
    observer: Observer = Observer()
    windows: int = 0
    cpu_ms: float = 0.0
    detect_cpu_ms: float | None = None


def _cpu_ms_since(c0: int) -> float:
    """The process's CPU time (ns, time.process_time_ns) since ``c0``, in ms."""
    return (time.process_time_ns() - c0) / 1e6


class _RefitPlan:
    """The stamp detector's ``refitted`` (tracker.detect.stamps) on one frame: the mask (n,)
    of the stars at frame positions ``xy`` (n, 2) px that the trail fit will re-centre
    (``trail``, tracker.detect.trail.TrailFit.fitted) in a frame of ``shape`` whose
    trails ``longest`` px bounds, from ``solver``'s smears at ``t_ns`` over
    ``exposure_s``; those smears (n, 2) px are kept in ``smear``, so that the frame's
    stars, found at these positions (or within the point fit's 1.5 px of them: their
    smears differ by a few parts in 10^4), are not reckoned again (a frame's cost here is
    numpy's calls, not its stars)."""

    def __init__(self, trail: TrailFit, solver: Solver, shape: tuple[int, int], t_ns: int,
                 exposure_s: float, longest: float) -> None:
        self.trail, self.solver, self.shape = trail, solver, shape
        self.t_ns, self.exposure_s, self.longest = t_ns, exposure_s, longest
        self.smear: np.ndarray | None = None

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        self.smear = self.solver.smear_px(xy, self.t_ns, self.exposure_s)
        return self.trail.fitted(self.shape, xy, self.smear, self.longest)


class Pipeline:
    """Processes frames with the configured methods; see the module docstring."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.camera = CameraModel.from_config(cfg.camera)
        self._detectors: OrderedDict[tuple, Detector] = OrderedDict()
        self._solver: Solver | None = None
        self._catalogue: Catalogue | None = None
        self._window_detectors: OrderedDict[tuple, WindowDetector] = OrderedDict()
        self._stamp_detectors: OrderedDict[tuple, StampDetector] = OrderedDict()
        self._trail = TrailFit(effective_sigma(cfg.detect.psf_sigma_px))
        self._windowed = 0   # windowed frames so far (the PSF meter's turn in the windows)
        idf = cfg.identify
        self._planner = WindowPlanner(
            self.camera.width, self.camera.height,
            idf.track_window_stars + idf.track_window_unknown + idf.track_sweep_windows,
            idf.track_sweep_windows, idf.track_window_sigma,
            math.ceil(3.0 * effective_sigma(cfg.detect.psf_sigma_px)), idf.track_window_max_px)

    def detector_for(self, shape: tuple[int, int], bit_depth: int) -> Detector:
        """The detector for frames of this shape and depth (one of the last used, or new)."""
        key = (tuple(shape), bit_depth)
        detector = self._detectors.pop(key, None)
        if detector is None:
            while len(self._detectors) >= DETECTORS_KEPT:
                self._detectors.popitem(last=False)     # free before allocating anew
            detector = make_detector(self.cfg.detect, key[0], bit_depth)
        self._detectors[key] = detector
        return detector

    @property
    def catalogue(self) -> Catalogue:
        """The configured catalogue, loaded on first use (raises CatalogueError)."""
        if self._catalogue is None:
            self._catalogue = Catalogue.from_config(self.cfg.catalogue)
        return self._catalogue

    @property
    def solver(self) -> Solver:
        """The solver, made on first use (raises the database's ConfigError)."""
        if self._solver is None:
            self._solver = make_solver(self.cfg.identify, self.camera, self.catalogue)
        return self._solver

    def reset(self, lens: bool = False) -> None:
        """Forget the tracking state: the next frame is solved lost in space.

        ``lens`` also forgets the solver's running focal-length estimate
        (tracker.identify.solver.Solver.reset).
        """
        if self._solver is not None:
            self._solver.reset(lens=lens)

    def solve_stars(self, stars, t_ns: int, observer: Observer | None = None,
                    exposure_s: float | None = None,
                    smear_px: np.ndarray | None = None) -> Solution:
        """Identify stars and solve the attitude, the catalogue at the observer's epoch.

        ``stars``: STAR_DTYPE rows (x, y, flux) in the camera's pixels;
        ``t_ns``, ``observer`` and ``exposure_s`` as in :meth:`process`
        (None: the stars' trails unknown, not weighed); ``smear_px`` their
        trails if known (tracker.identify.solver.Solver.solve).
        """
        observer = observer or Observer()
        self._follow_epoch(observer)
        return self.solver.solve(stars, t_ns, observer, exposure_s=exposure_s,
                                 smear_px=smear_px)

    def _follow_epoch(self, observer: Observer) -> None:
        """Propagate the catalogue to the observer's epoch if it moved too far (module doc)."""
        epoch = observer.epoch_year
        loaded = self._catalogue
        if epoch is None or (loaded is not None and abs(epoch - loaded.epoch_year)
                             <= self.cfg.catalogue.epoch_step_years):
            return
        if loaded is not None:
            log.info("catalogue propagated from epoch %.4f to %.4f, the frames' time "
                     "(tracking starts again)", loaded.epoch_year, epoch)
        self._catalogue = Catalogue.from_config(dataclasses.replace(self.cfg.catalogue,
                                                                    epoch_year=epoch))
        self._solver = None

    @property
    def window_cells(self) -> list[int]:
        """Window sides (px) of the window detectors held, oldest first."""
        return [key[0] for key in self._window_detectors]

    def window_detector_for(self, cell: int, image: np.ndarray, bit_depth: int,
                            measure_psf: bool = False) -> WindowDetector:
        """The window detector for windows of ``cell`` px of frames like ``image``.

        The default detector takes the PSF the full-frame detector of such
        frames has measured as given (tracker.detect.shared_psf) and measures
        it in the windows only with ``measure_psf`` (and ``detect.psf_measure``).
        """
        key = (cell, image.dtype.str, bit_depth)
        found = self._window_detectors.pop(key, None)
        if found is None:
            while len(self._window_detectors) >= DETECTORS_KEPT:
                self._window_detectors.popitem(last=False)
            rows, cols = WindowDetector.mosaic_shape(cell, self._planner.capacity)
            pixels = rows * cols            # no more pixels above threshold or impulses
            detect_cfg = dataclasses.replace(
                self.cfg.detect, threads=1, background_tile_px=cell // 3,
                background_step_px=max(1, cell // 24),
                max_pixels_above=min(self.cfg.detect.max_pixels_above, pixels),
                max_impulses=min(self.cfg.detect.max_impulses, pixels))
            found = WindowDetector(
                lambda shape: make_detector(detect_cfg, shape, bit_depth), image.shape, cell,
                self._planner.capacity, self._planner.reach, self.cfg.detect.max_stars,
                image.dtype)
        self._window_detectors[key] = found
        inner = found.detector
        if isinstance(inner, DefaultDetector):
            full = self.detector_for(image.shape, bit_depth)
            if not isinstance(inner.psf_tracker, SharedPsf):
                inner.psf_tracker = SharedPsf(full.psf_tracker)
            inner.psf_tracker.tracker = full.psf_tracker
            inner.measure_psf = measure_psf and self.cfg.detect.psf_measure
        return found

    def stamp_detector_for(self, cell: int, image: np.ndarray,
                           bit_depth: int) -> StampDetector:
        """The lean window detector (tracker.detect.stamps) for windows of ``cell`` px of
        frames like ``image`` (the :data:`DETECTORS_KEPT` last used sizes kept)."""
        key = (cell, image.dtype.str, bit_depth)
        found = self._stamp_detectors.pop(key, None)
        if found is None:
            while len(self._stamp_detectors) >= DETECTORS_KEPT:
                self._stamp_detectors.popitem(last=False)
            found = StampDetector(self.cfg.detect, image.shape, cell, self._planner.capacity,
                                  self._planner.reach, bit_depth, image.dtype)
        self._stamp_detectors[key] = found
        return found

    def process(self, image: np.ndarray, bit_depth: int, t_ns: int,
                observer: Observer | None = None,
                exposure_s: float | None = None) -> FrameResult:
        """Detect, identify and solve one frame; never raises on bad pixels.

        ``image`` is 2-D (or colour: rows x cols x 3 or 4, BGR(A), made grey
        first), uint8 or uint16 holding ``bit_depth``-bit values; ``t_ns`` the
        exposure mid-point (monotonic clock), used by tracking; ``observer``
        the frame's absolute time and velocity (None: unknown, no aberration
        corrected); ``exposure_s`` its exposure time (None: the configured
        ``capture.exposure_us``), which sizes the windows for the smear and
        weighs trailed stars in the solve.
        """
        observer = observer or Observer()
        t0 = time.perf_counter_ns()
        c0 = time.process_time_ns()
        if isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[2] in (1, 3, 4):
            image = to_grey(image)
        shape = image.shape[:2] if image.ndim >= 2 else (0, 0)
        identify = self.cfg.identify.enabled and tuple(shape) == (self.camera.height,
                                                                  self.camera.width)
        exposure = self.cfg.capture.exposure_us / 1e6 if exposure_s is None else exposure_s
        if identify and self.cfg.identify.track_windows:
            windowed = self._process_windows(image, bit_depth, t_ns, observer, exposure, t0, c0)
            if windowed is not None:
                return windowed
        c1 = time.process_time_ns()
        detections = self.detector_for(shape, bit_depth).detect(image)
        detect_cpu = _cpu_ms_since(c1)
        stages = {f"detect.{k}": v for k, v in detections.stages_ms.items()}
        solution, reason = None, None
        if not self.cfg.identify.enabled:
            reason = "disabled"
        elif not identify:
            reason = "frame_size"
        else:
            stars, smear = self._untrailed(image, detections.stars, t_ns, exposure,
                                           self._longest_smear(t_ns, exposure), stages)
            solution = self.solve_stars(stars, t_ns, observer, exposure, smear)
            stages.update({f"identify.{k}": v for k, v in solution.stages_ms.items()})
        elapsed = (time.perf_counter_ns() - t0) / 1e6
        return FrameResult(detections, solution, elapsed, stages, reason, observer,
                           cpu_ms=_cpu_ms_since(c0), detect_cpu_ms=detect_cpu)

    def _longest_smear(self, t_ns: int, exposure_s: float) -> float | None:
        """A bound of the frame's longest trail, px (None: no rate, or no solver yet;
        tracker.identify.solver.Solver.max_smear_px)."""
        return None if self._solver is None else self._solver.max_smear_px(t_ns, exposure_s)

    def _untrailed(self, image: np.ndarray, stars: np.ndarray, t_ns: int, exposure_s: float,
                   longest: float | None, stages: dict,
                   smear: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """``stars`` with trailed ones re-centred and merged (module docstring), or as given,
        and their smears (n, 2) px at the positions detected (None: not reckoned; the
        solve weighs the stars by them, tracker.identify.predict.centroid_variance: a
        trail's centre moves it a few px, its smear by a thousandth of a pixel).

        ``longest`` bounds the frame's trails (:meth:`_longest_smear`); ``smear`` (n,
        2) px, if given, the stars' smears already reckoned (at their positions or
        within a few px: the stamp detector's peaks, :class:`_RefitPlan`).
        """
        if self._solver is None or len(stars) == 0 or image.ndim != 2:
            return stars, None
        if longest is None or longest < self._trail.min_length:
            return stars, None            # no star of the frame trails far enough
        xy = np.empty((len(stars), 2))
        xy[:, 0], xy[:, 1] = stars["x"], stars["y"]
        if smear is None:
            smear = self._solver.smear_px(xy, t_ns, exposure_s)
        if smear is None or not (np.hypot(smear[:, 0], smear[:, 1])
                                 >= self._trail.min_length).any():
            return stars, smear
        t0 = time.perf_counter_ns()
        fitted = self._trail.refine(image, xy, smear)
        stars = stars.copy()
        stars["x"], stars["y"] = fitted[:, 0], fitted[:, 1]
        distinct = ~later_within(fitted[:, 0], fitted[:, 1], self._trail.sigma)
        stages["trail"] = (time.perf_counter_ns() - t0) / 1e6
        return stars[distinct], smear[distinct]

    def _refit_plan(self, shape: tuple[int, int], t_ns: int, exposure_s: float,
                    longest: float | None) -> _RefitPlan | None:
        """The stamp detector's ``refitted`` for a frame of ``shape`` whose trails
        ``longest`` px bounds (None: no star of the frame trails far enough)."""
        if longest is None or longest < self._trail.min_length:
            return None
        return _RefitPlan(self._trail, self.solver, shape, t_ns, exposure_s, longest)

    def _process_windows(self, image: np.ndarray, bit_depth: int, t_ns: int,
                         observer: Observer, exposure_s: float, t0: int,
                         c0: int) -> FrameResult | None:
        """The frame tracked in windows (module docstring), or None to search it whole;
        ``t0`` and ``c0`` the frame's start in wall and process CPU time, ns."""
        if self._solver is None:
            return None
        self._follow_epoch(observer)
        solver = self.solver
        prediction = solver.prediction(t_ns, exposure_s, observer)
        plan = None if prediction is None else self._planner.plan(prediction)
        if plan is None or image.dtype not in (np.uint8, np.uint16) or image.ndim != 2:
            return None
        self._windowed += 1
        measure_psf = self._windowed % self.cfg.identify.track_lens_every == 0
        full = self.detector_for(image.shape, bit_depth)
        stamps = (self.cfg.identify.track_stamps and isinstance(full, DefaultDetector)
                  and not (measure_psf and self.cfg.detect.psf_measure))
        longest = solver.max_smear_px(t_ns, exposure_s)
        known = None                      # the detected stars' smears, if reckoned
        t1 = time.perf_counter_ns()
        if stamps:
            refit = self._refit_plan(image.shape, t_ns, exposure_s, longest)
            stamp_detector = self.stamp_detector_for(plan.cell, image, bit_depth)
            detections = stamp_detector.detect(image, plan.origins, full.psf_tracker.current,
                                               refit)
            if refit is not None and refit.smear is not None:
                known = refit.smear[stamp_detector.sources]
        else:
            detections = self.window_detector_for(plan.cell, image, bit_depth,
                                                  measure_psf).detect(image, plan.origins)
        t2 = time.perf_counter_ns()
        stages = {f"windows.{k}": v for k, v in detections.stages_ms.items()}
        stages["track.plan"] = (t1 - t0) / 1e6
        stages["windows.gather"] = (t2 - t1) / 1e6 - sum(detections.stages_ms.values())
        stars, smear = self._untrailed(image, detections.stars, t_ns, exposure_s, longest,
                                       stages, known)
        named = prediction.catalogue[:plan.stars] >= 0
        solution = solver.solve(stars, t_ns, observer, search_area_px=plan.area_px,
                                predicted=prediction.catalogue[:plan.stars][named],
                                predicted_xy=prediction.xy[:plan.stars][named],
                                exposure_s=exposure_s, smear_px=smear)
        if not solution.ok:
            return None
        stages.update({f"identify.{k}": v for k, v in solution.stages_ms.items()})
        elapsed = (time.perf_counter_ns() - t0) / 1e6
        return FrameResult(detections, solution, elapsed, stages, None, observer,
                           windows=len(plan.origins), cpu_ms=_cpu_ms_since(c0))
