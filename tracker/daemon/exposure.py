"""Exposure control: keep stars unsaturated and detectable.

The controlled quantity is the peak (background-subtracted, ADU) of the
third-brightest star, so that a single planet or hot pixel does not set the
exposure. Each update compares it with ``target_peak`` x full scale:

- any saturated star among the brightest three, or the reference peak
  above 0.9 x full scale: shorten by half (fast, saturation ruins centroids);
- fewer than three stars: lengthen by 2x (nothing to measure yet);
- otherwise scale by target / reference, limited to 0.5 .. 2x and so that
  the second-brightest star stays below 0.9 x full scale, and only if the
  ratio leaves a dead band of 0.7 .. 1.4 (no hunting on noise).

Exposure changes first; gain rises only when the exposure is at its
maximum and falls first when light must be cut. After a change the
controller waits ``settle_frames`` frames (the camera applies controls about
two frames late) before judging again. Units: exposure in us, gain a factor.
"""

from __future__ import annotations

import numpy as np

from tracker.config import CaptureConfig
from tracker.detect import Detections, StarFlag

__all__ = ["ExposureControl"]

_REF_RANK = 3        # the n-th brightest star is the reference
_HIGH = 0.9          # fraction of full scale that counts as nearly saturated
_DEADBAND = (0.7, 1.4)
_STEP = (0.5, 2.0)


class ExposureControl:
    """Holds the wanted exposure and gain; :meth:`update` after each frame."""

    def __init__(self, cfg: CaptureConfig, settle_frames: int = 3):
        self.cfg = cfg
        self.exposure_us = float(cfg.exposure_us)
        self.gain = float(cfg.gain)
        self.auto = cfg.auto_exposure
        self.settle_frames = settle_frames
        self._wait = 0

    def set_manual(self, exposure_us: float | None = None, gain: float | None = None) -> None:
        """Fix exposure and/or gain (a flight-computer command); auto control stops.

        Values are clamped to the configured limits: exposure to
        ``exposure_min_us .. exposure_max_us``, gain to ``1 .. gain_max``.
        """
        self.auto = False
        if exposure_us is not None:
            self.exposure_us = min(max(float(exposure_us), self.cfg.exposure_min_us),
                                   self.cfg.exposure_max_us)
        if gain is not None:
            self.gain = min(max(float(gain), 1.0), self.cfg.gain_max)

    def _ratio(self, det: Detections, bit_depth: int) -> float:
        stars = det.stars
        if det.reason == "saturated":
            return _STEP[0]
        if len(stars) < _REF_RANK:
            return _STEP[1]
        full = float((1 << bit_depth) - 1)
        top = np.sort(stars["peak"])[-_REF_RANK:]          # ascending; top[0] = reference
        bright = np.argsort(stars["peak"])[-_REF_RANK:]
        if np.any(stars["flags"][bright] & StarFlag.SATURATED) or top[0] > _HIGH * full:
            return _STEP[0]
        ratio = self.cfg.target_peak * full / max(float(top[0]), 1.0)
        ratio = min(ratio, _HIGH * full / max(float(top[1]), 1.0))  # keep the 2nd unsaturated
        if _DEADBAND[0] <= ratio <= _DEADBAND[1]:
            return 1.0
        return min(max(ratio, _STEP[0]), _STEP[1])

    def update(self, det: Detections, bit_depth: int) -> bool:
        """Judge one frame's detections; True when exposure or gain changed."""
        if not self.auto:
            return False
        if self._wait > 0:
            self._wait -= 1
            return False
        ratio = self._ratio(det, bit_depth)
        if ratio == 1.0:
            return False
        cfg = self.cfg
        light = self.exposure_us * self.gain * ratio        # wanted exposure x gain
        if ratio > 1.0:
            exposure = min(light / self.gain, cfg.exposure_max_us)
            gain = min(max(light / exposure, self.gain), cfg.gain_max)
        else:
            gain = max(min(light / self.exposure_us, self.gain), 1.0)
            exposure = max(light / gain, cfg.exposure_min_us)
        if np.isclose(exposure, self.exposure_us) and np.isclose(gain, self.gain):
            return False
        self.exposure_us, self.gain = exposure, gain
        self._wait = self.settle_frames
        return True
