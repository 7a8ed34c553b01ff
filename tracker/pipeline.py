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
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.config import Config
from tracker.detect import Detections, Detector, make_detector
from tracker.frame_array import to_grey
from tracker.identify import Solution, Solver, make_solver

__all__ = ["Pipeline", "FrameResult", "DETECTORS_KEPT"]

# Detectors kept for frame sizes seen lately: the camera's and one other.
DETECTORS_KEPT = 2


@dataclass
class FrameResult:
    """What one frame produced.

    ``solution`` is None when identification is off or was not attempted;
    ``solve_reason`` then says why (``"disabled"``, ``"frame_size"``).
    """

    detections: Detections
    solution: Solution | None
    time_ms: float
    stages_ms: dict
    solve_reason: str | None = None


class Pipeline:
    """Processes frames with the configured methods; see the module docstring."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.camera = CameraModel.from_config(cfg.camera)
        self._detectors: OrderedDict[tuple, Detector] = OrderedDict()
        self._solver: Solver | None = None
        self._catalogue: Catalogue | None = None

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

    def process(self, image: np.ndarray, bit_depth: int, t_ns: int) -> FrameResult:
        """Detect, identify and solve one frame; never raises on bad pixels.

        ``image`` is 2-D (or colour: rows x cols x 3 or 4, BGR(A), made grey
        first), uint8 or uint16 holding ``bit_depth``-bit values; ``t_ns`` the
        exposure mid-point (monotonic clock), used by tracking.
        """
        t0 = time.perf_counter_ns()
        if isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[2] in (1, 3, 4):
            image = to_grey(image)
        shape = image.shape[:2] if image.ndim >= 2 else (0, 0)
        detections = self.detector_for(shape, bit_depth).detect(image)
        stages = {f"detect.{k}": v for k, v in detections.stages_ms.items()}
        solution, reason = None, None
        if not self.cfg.identify.enabled:
            reason = "disabled"
        elif tuple(shape) != (self.camera.height, self.camera.width):
            reason = "frame_size"
        else:
            solution = self.solver.solve(detections.stars, t_ns)
            stages.update({f"identify.{k}": v for k, v in solution.stages_ms.items()})
        elapsed = (time.perf_counter_ns() - t0) / 1e6
        return FrameResult(detections, solution, elapsed, stages, reason)
