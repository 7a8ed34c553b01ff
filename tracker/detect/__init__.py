"""Star detection and centroiding.

One :class:`Detector` is made per frame shape and bit depth with
:func:`make_detector`; its ``detect(image)`` returns
:class:`~tracker.detect.result.Detections`. Methods are chosen by name in
the ``detect.method`` configuration key (see :data:`METHODS`):

* ``default`` (tracker.detect.default): fixed-memory detector with tile
  background, impulse (hot pixel, cosmic ray) rejection, matched filter,
  noise-scaled threshold, deblending and a Gaussian-windowed centroid;
* ``seed`` (tracker.detect.seed): the dissertation's pipeline;
* ``com``, ``gaussian_fit``, ``gaussian_fit_fast``, ``sieve``
  (tracker.detect.baselines): its baselines on the seed's blobs.

Bad frames never raise: the result is empty with a reason code
(tracker.detect.frame_input.Reason).
"""

from __future__ import annotations

import importlib
from typing import Protocol

import numpy as np

from tracker.config import DetectConfig
from tracker.detect.result import STAR_DTYPE, Detections, StarFlag
from tracker.detect.slabs import set_opencv_threads

__all__ = ["Detector", "make_detector", "METHODS", "Detections", "STAR_DTYPE", "StarFlag"]

# method name -> "module:class"; each class takes (cfg, shape, bit_depth).
METHODS = {
    "default": "tracker.detect.default:DefaultDetector",
    "seed": "tracker.detect.seed:SeedDetector",
    "com": "tracker.detect.baselines:ComDetector",
    "gaussian_fit": "tracker.detect.baselines:GaussianFitDetector",
    "gaussian_fit_fast": "tracker.detect.baselines:FastGaussianFitDetector",
    "sieve": "tracker.detect.baselines:SieveDetector",
}


class Detector(Protocol):
    """Finds stars in frames of one shape and bit depth."""

    def detect(self, image: np.ndarray) -> Detections: ...


def make_detector(cfg: DetectConfig, shape: tuple[int, int], bit_depth: int) -> Detector:
    """The detector named by ``cfg.method`` for frames of ``shape`` (rows, cols).

    Sets OpenCV's thread count for the process (``cfg.opencv_threads``).
    """
    set_opencv_threads(cfg.opencv_threads)
    module, cls = METHODS[cfg.method].split(":")
    return getattr(importlib.import_module(module), cls)(cfg, tuple(shape), bit_depth)
