"""Absolute time and the observer's velocity from where they come to the solver (issue 14).

The observer context, the daemon's time base (TIME_SYNC, the system clock,
SET_VELOCITY and its age), replay records (``utc``, ``observer_velocity_km_s``)
and the catalogue's proper-motion epoch following the frames' time.
"""

import dataclasses
import json
import math
import time

import cv2
import numpy as np
import pytest

from tracker.astrometry.earth import C_KM_S
from tracker.astrometry.observer import Correction, Observer, TimeSource
from tracker.astrometry.timescale import (
    TAI_NS_MAX,
    TimeError,
    julian_year_from_tai_ns,
    tai_ns_from_utc_iso,
)
from tracker.capture import ReplaySource
from tracker.capture.base import Frame
from tracker.config import Config, TimeConfig
from tracker.daemon.timebase import TimeBase
from tracker.errors import UserError
from tracker.pipeline import Pipeline
from tracker.system_clock import kernel_synchronised, tai_minus_monotonic_ns

T_2026 = tai_ns_from_utc_iso("2026-03-20T21:00:00Z")
LEO = (-6.1, 4.2, 1.3)


# -- the context --------------------------------------------------------------------------


def test_without_absolute_time_nothing_is_corrected_not_even_a_known_velocity():
    assert Observer().corrections == Correction.NONE and Observer().beta() is None
    assert Observer().epoch_year is None


def test_with_time_annual_aberration_and_with_velocity_the_observers_too():
    annual = Observer(T_2026, None, TimeSource.TIME_SYNC)
    both = Observer(T_2026, LEO, TimeSource.TIME_SYNC)
    stale = Observer(T_2026, None, TimeSource.TIME_SYNC, velocity_stale=True)
    assert annual.corrections == Correction.ANNUAL_ABERRATION
    assert both.corrections == Correction.ANNUAL_ABERRATION | Correction.OBSERVER_VELOCITY
    assert stale.corrections == Correction.ANNUAL_ABERRATION | Correction.VELOCITY_STALE
    np.testing.assert_allclose((both.beta() - annual.beta()) * C_KM_S, LEO, atol=1e-9)
    assert both.to_json() == {"utc": "2026-03-20T21:00:00.000000000Z",
                              "time_source": "time_sync", "observer_velocity_km_s": list(LEO),
                              "corrections": ["annual_aberration", "observer_velocity"]}
    assert annual.epoch_year == pytest.approx(2026.2160, abs=1e-4)   # JD 2461120.375 TT


@pytest.mark.parametrize("kwargs, error, match", [
    ({"t_tai_ns": 0, "time_source": TimeSource.RECORD}, TimeError, "outside 1972-2200"),
    ({"t_tai_ns": T_2026, "velocity_km_s": (1.0, math.nan, 0.0),
      "time_source": TimeSource.RECORD}, ValueError, "three numbers"),
    ({"t_tai_ns": T_2026, "velocity_km_s": (1.0, 2.0), "time_source": TimeSource.RECORD},
     ValueError, "three numbers"),
    ({"t_tai_ns": T_2026, "velocity_km_s": (300.0, 0, 0), "time_source": TimeSource.RECORD},
     ValueError, "within"),
    ({"t_tai_ns": T_2026}, ValueError, "needs its source"),
    ({"time_source": TimeSource.TIME_SYNC}, ValueError, "needs its source"),
])
def test_unusable_contexts_are_refused(kwargs, error, match):
    with pytest.raises(error, match=match):
        Observer(**kwargs)


# -- the daemon's time base -----------------------------------------------------------------


def _frame(t_ns, **kw):
    return Frame(0, "f", np.zeros((2, 2), np.uint8), 8, t_ns, **kw)


def _timebase(system_clock="never", synced=True, max_age_s=10.0):
    asked = []

    def synchronised():
        asked.append(1)
        return synced

    base = TimeBase(TimeConfig(system_clock=system_clock, velocity_max_age_s=max_age_s),
                    synchronised=synchronised, system_offset_ns=lambda: T_2026)
    return base, asked


def test_before_time_sync_no_absolute_time_after_it_tai_from_the_offset():
    base, _ = _timebase()
    assert base.observer_for(_frame(5 * 10**9)) == Observer()
    base.time_sync(T_2026 - 10**9)
    obs = base.observer_for(_frame(5 * 10**9))
    assert (obs.t_tai_ns, obs.time_source) == (T_2026 + 4 * 10**9, TimeSource.TIME_SYNC)
    base.time_sync(T_2026)                  # the latest one counts
    assert base.observer_for(_frame(0)).t_tai_ns == T_2026


def test_a_frames_own_record_wins_over_time_sync():
    base, _ = _timebase()
    base.time_sync(T_2026)
    recorded = _frame(7, t_tai_ns=T_2026 - 86400 * 10**9, observer_velocity_km_s=LEO)
    obs = base.observer_for(recorded)
    assert (obs.t_tai_ns, obs.velocity_km_s, obs.time_source) == (
        T_2026 - 86400 * 10**9, LEO, TimeSource.RECORD)


@pytest.mark.parametrize("policy, synced, expected", [
    ("never", True, TimeSource.NONE), ("synchronised", False, TimeSource.NONE),
    ("synchronised", None, TimeSource.NONE), ("synchronised", True, TimeSource.SYSTEM_CLOCK),
    ("always", False, TimeSource.SYSTEM_CLOCK)])
def test_the_system_clock_is_used_only_as_configured(policy, synced, expected):
    base, _ = _timebase(policy, synced)
    obs = base.observer_for(_frame(3 * 10**9))
    assert obs.time_source == expected
    if expected == TimeSource.SYSTEM_CLOCK:
        assert obs.t_tai_ns == T_2026 + 3 * 10**9
    base.time_sync(T_2026 + 10**12)             # TIME_SYNC beats the system clock
    assert base.observer_for(_frame(0)).time_source == TimeSource.TIME_SYNC


def test_the_kernel_is_asked_at_most_once_a_second_of_frames():
    base, asked = _timebase("synchronised")
    for k in range(50):                             # 50 frames at 100 Hz: 0.5 s
        base.observer_for(_frame(10**9 + k * 10**7))
    assert len(asked) == 1
    base.observer_for(_frame(10**9 + 10**9))       # a second on: asked again
    assert len(asked) == 2


def test_a_velocity_applies_within_its_age_either_side_then_is_stale():
    base, _ = _timebase(max_age_s=10.0)
    base.time_sync(T_2026)
    base.set_velocity(T_2026 + 5 * 10**9, LEO)
    for t_s, applied in ((0.0, True), (-5.0, True), (15.0, True), (15.001, False),
                         (-5.001, False)):
        obs = base.observer_for(_frame(round(t_s * 1e9)))
        assert (obs.velocity_km_s == LEO) == applied, t_s
        assert (Correction.VELOCITY_STALE in obs.corrections) == (not applied)


def test_a_frame_whose_tai_would_leave_1972_2200_has_no_absolute_time():
    base, _ = _timebase()
    base.time_sync(TAI_NS_MAX - 10**9)
    assert base.observer_for(_frame(0)).time_source == TimeSource.TIME_SYNC
    assert base.observer_for(_frame(2 * 10**9)) == Observer()


def test_system_clock_offset_is_utc_plus_the_leap_seconds_minus_monotonic():
    offset = tai_minus_monotonic_ns()
    expected = time.time_ns() + 37 * 10**9 - time.monotonic_ns()
    assert abs(offset - expected) < 50_000_000          # reads 50 ms apart at worst
    assert kernel_synchronised() in (True, False, None)


# -- replay records ---------------------------------------------------------------------------


def _folder(tmp_path, records):
    for k in range(len(records)):
        cv2.imwrite(str(tmp_path / f"f{k}.png"), np.zeros((8, 8), np.uint8))
    (tmp_path / "frames.jsonl").write_text(
        "".join(json.dumps({"file": f"f{k}.png", **r}) + "\n" for k, r in enumerate(records)))
    return tmp_path


def test_replay_records_carry_utc_and_velocity_to_the_frame(tmp_path):
    folder = _folder(tmp_path, [{"utc": "2016-12-31T23:59:60.5Z",
                                 "observer_velocity_km_s": [1, 2.5, -3]}, {}])
    first, second = list(ReplaySource([folder]))
    assert first.t_tai_ns == tai_ns_from_utc_iso("2017-01-01T00:00:00Z") - 5 * 10**8
    assert first.observer_velocity_km_s == (1.0, 2.5, -3.0)
    assert first.recorded_observer().corrections == (Correction.ANNUAL_ABERRATION
                                                     | Correction.OBSERVER_VELOCITY)
    assert second.t_tai_ns is None and second.recorded_observer() == Observer()


@pytest.mark.parametrize("record, match", [
    ({"utc": "2026-03-20 21:00:00"}, "expected ISO 8601 UTC"),
    ({"utc": "2201-01-01T00:00:00Z"}, "outside 1972-2200"),
    ({"utc": 1700000000}, "expected ISO 8601 UTC"),
    ({"utc": "2026-03-20T21:00:00Z", "observer_velocity_km_s": [1, 2]}, "three numbers"),
    ({"utc": "2026-03-20T21:00:00Z", "observer_velocity_km_s": "fast"}, "three numbers")])
def test_an_unusable_time_in_a_record_is_one_line_naming_file_and_line(tmp_path, record,
                                                                        match):
    folder = _folder(tmp_path, [{}, record])
    with pytest.raises(UserError, match=match) as err:
        ReplaySource([folder])
    assert "frames.jsonl line 2: " in str(err.value) and "\n" not in str(err.value)


# -- the proper-motion epoch --------------------------------------------------------------


def test_the_catalogue_follows_the_frames_epoch_beyond_the_step():
    cfg = dataclasses.replace(Config(), catalogue=dataclasses.replace(
        Config().catalogue, epoch_year=2026.0, epoch_step_years=0.01))
    pipeline = Pipeline(cfg)
    stars = np.zeros(0, [("x", float), ("y", float), ("flux", float)])
    first = pipeline.catalogue
    near = tai_ns_from_utc_iso("2026-01-03T00:00:00Z")         # 2026.005
    pipeline.solve_stars(stars, 0, Observer(near, None, TimeSource.RECORD))
    assert pipeline.catalogue is first
    far = tai_ns_from_utc_iso("1999-06-01T00:00:00Z")
    pipeline.solve_stars(stars, 0, Observer(far, None, TimeSource.RECORD))
    assert pipeline.catalogue.epoch_year == pytest.approx(julian_year_from_tai_ns(far))
    # HIP 57939 (Groombridge 1830, 7.06 arcsec/yr) moved by 26.6 years of proper motion
    i = int(np.flatnonzero(first.hip == 57939)[0])
    moved = math.degrees(math.acos(float(first.vectors[i] @ pipeline.catalogue.vectors[i])))
    assert moved * 3600 == pytest.approx(7.06 * (2026.0 - pipeline.catalogue.epoch_year),
                                         rel=2e-3)
    pipeline.solve_stars(stars, 0)                     # no time: the epoch stays
    assert pipeline.catalogue.epoch_year == pytest.approx(julian_year_from_tai_ns(far))
