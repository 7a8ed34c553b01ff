"""Exposure control: saturation cuts light fast, faint fields get more, a dead band holds."""

import dataclasses

import numpy as np
import pytest

from tracker.config import CaptureConfig
from tracker.daemon.exposure import ExposureControl
from tracker.detect import STAR_DTYPE, Detections, StarFlag

FULL = 1023.0


def detections(peaks, flags=0, reason=None):
    stars = np.zeros(len(peaks), STAR_DTYPE)
    stars["peak"] = peaks
    stars["flags"] = flags
    return Detections(stars, reason=reason)


def control(**keys):
    cfg = dataclasses.replace(CaptureConfig(), exposure_us=10000.0, gain=2.0,
                              exposure_max_us=40000.0, gain_max=8.0, target_peak=0.5, **keys)
    return ExposureControl(cfg, settle_frames=0)


def test_saturated_bright_star_halves_gain_first():
    c = control()
    assert c.update(detections([300, 400, 500], flags=[0, 0, StarFlag.SATURATED]), 10)
    assert (c.exposure_us, c.gain) == (10000.0, 1.0)       # gain 2 -> 1, exposure kept
    assert c.update(detections([300, 400, 1000], flags=[0, 0, StarFlag.SATURATED]), 10)
    assert c.gain == 1.0 and c.exposure_us == 5000.0       # gain at 1: exposure halves


def test_faint_reference_does_not_push_the_second_star_into_saturation():
    """Reference 100 asks for 2x, but the 2nd-brightest (950) is already past 0.9 x 1023."""
    c = control()
    assert not c.update(detections([100, 950, 1000]), 10)
    assert (c.exposure_us, c.gain) == (10000.0, 2.0)


def test_reference_is_the_third_brightest_star():
    """One very bright star (a planet) among faint ones does not cut the exposure."""
    c = control()
    ratio = c._ratio(detections([50, 500, 520, 900]), 10)
    assert ratio == pytest.approx(1.0)                      # 500/511.5 inside the dead band


def test_too_few_stars_doubles_exposure_then_gain_at_the_limit():
    c = control()
    c.update(detections([200]), 10)
    assert (c.exposure_us, c.gain) == (20000.0, 2.0)
    c.update(detections([]), 10)
    c.update(detections([]), 10)
    assert (c.exposure_us, c.gain) == (40000.0, 4.0)       # exposure capped, gain takes over
    for _ in range(5):
        c.update(detections([]), 10)
    assert (c.exposure_us, c.gain) == (40000.0, 8.0)


def test_faint_reference_is_scaled_to_the_target_within_a_factor_two():
    c = control()
    c.update(detections([150, 160, 170.5]), 10)           # 511.5 / 150 = 3.41 -> capped 2
    assert c.exposure_us == 20000.0
    c = control()
    c.update(detections([300, 310, 320]), 10)             # 511.5 / 300 = 1.705
    assert c.exposure_us == pytest.approx(10000.0 * 511.5 / 300)


def test_settling_and_manual_override():
    c = ExposureControl(dataclasses.replace(CaptureConfig()), settle_frames=2)
    assert c.update(detections([]), 10)
    assert not c.update(detections([]), 10) and not c.update(detections([]), 10)
    assert c.update(detections([]), 10)
    c.set_manual(exposure_us=1234.0)
    assert not c.update(detections([]), 10) and c.exposure_us == 1234.0


def test_detector_saturated_reason_cuts_light():
    c = control()
    c.update(detections([], reason="saturated"), 10)
    assert c.gain == 1.0
