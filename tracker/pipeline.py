"""One frame through the stages: detect -> identify -> attitude.

Shared by ``tracker replay`` and the service so both compute the same thing.
A detector is made once per (shape, bit depth) and reused; the solver (made
on first use: it loads the catalogue and the pattern database) keeps its
tracking state between frames. Identification runs only on frames whose
size matches the configured camera, since the camera model is what maps
pixels to directions.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.config import Config
from tracker.detect import Detections, Detector, make_detector
from tracker.identify import Solution, Solver, make_solver

__all__ = ["Pipeline", "FrameResult"]


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
        self._detectors: dict[tuple, Detector] = {}
        self._solver: Solver | None = None

    def detector_for(self, shape: tuple[int, int], bit_depth: int) -> Detector:
        """The (cached) detector for frames of this shape and depth."""
        key = (tuple(shape), bit_depth)
        if key not in self._detectors:
            self._detectors[key] = make_detector(self.cfg.detect, key[0], bit_depth)
        return self._detectors[key]

    @property
    def solver(self) -> Solver:
        """The solver, made on first use (raises the database's ConfigError)."""
        if self._solver is None:
            catalogue = Catalogue.from_config(self.cfg.catalogue)
            self._solver = make_solver(self.cfg.identify, self.camera, catalogue)
        return self._solver

    def reset(self) -> None:
        """Forget the tracking state: the next frame is solved lost in space."""
        if self._solver is not None:
            self._solver.reset()

    def process(self, image: np.ndarray, bit_depth: int, t_ns: int) -> FrameResult:
        """Detect, identify and solve one frame; never raises on bad pixels."""
        t0 = time.perf_counter_ns()
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
