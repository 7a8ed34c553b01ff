"""One frame through the stages: detect -> identify -> attitude.

Shared by ``tracker replay`` and the service so both compute the same thing.
A detector is made once per (shape, bit depth) and reused; the solver keeps
its tracking state between frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from tracker.config import Config
from tracker.detect import Detections, Detector, make_detector

__all__ = ["Pipeline", "FrameResult"]


@dataclass
class FrameResult:
    """What one frame produced. ``solution`` is None when identification is off."""

    detections: Detections
    solution: object | None
    time_ms: float
    stages_ms: dict


class Pipeline:
    """Processes frames with the configured methods; see the module docstring."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self._detectors: dict[tuple, Detector] = {}

    def detector_for(self, shape: tuple[int, int], bit_depth: int) -> Detector:
        """The (cached) detector for frames of this shape and depth."""
        key = (tuple(shape), bit_depth)
        if key not in self._detectors:
            self._detectors[key] = make_detector(self.cfg.detect, key[0], bit_depth)
        return self._detectors[key]

    def process(self, image: np.ndarray, bit_depth: int, t_ns: int) -> FrameResult:
        """Detect (and later identify) the stars of one frame."""
        t0 = time.perf_counter_ns()
        shape = image.shape[:2] if image.ndim >= 2 else (0, 0)
        detections = self.detector_for(shape, bit_depth).detect(image)
        stages = {f"detect.{k}": v for k, v in detections.stages_ms.items()}
        elapsed = (time.perf_counter_ns() - t0) / 1e6
        return FrameResult(detections, None, elapsed, stages)
