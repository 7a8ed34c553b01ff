"""The fixed-size star table a detector owns and the results it hands out."""

from __future__ import annotations

import math

import numpy as np

from tracker.detect.result import STAR_DTYPE, Detections

__all__ = ["StarTable"]


class StarTable:
    """``capacity`` rows of :data:`STAR_DTYPE`, reused frame after frame."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        self.stars = np.zeros(self.capacity, STAR_DTYPE)

    def result(self, count: int, reason: str | None, counters: dict,
               stages_ms: dict, psf=None) -> Detections:
        """Detections viewing the first ``count`` rows (valid until the next frame).

        ``psf``: the frame's tracker.detect.psf.PsfEstimate, if the method has one.
        """
        if psf is None:
            return Detections(self.stars[:count], reason, counters, stages_ms)
        return Detections(self.stars[:count], reason, counters, stages_ms,
                          psf_sigma_px=psf.sigma_px, psf_ellipticity=psf.ellipticity,
                          psf_angle_deg=math.degrees(psf.angle_rad), psf_stars=psf.stars)
