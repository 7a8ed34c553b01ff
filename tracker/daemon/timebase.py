"""Each frame's observer context in the daemon: its absolute time and the observer's velocity.

Frames are stamped on the tracker's monotonic clock (``Frame.t_ns``). Their
absolute time (TAI ns since 1970, tracker.astrometry.timescale) comes from
the first of these that applies:

1. the frame's own record (a replay's ``utc``, with its
   ``observer_velocity_km_s``): source RECORD;
2. the flight computer's latest TIME_SYNC: ``t_ns`` + its offset (TAI minus
   the monotonic clock); source TIME_SYNC;
3. the tracker's own clock, if ``time.system_clock`` trusts it (``always``,
   or ``synchronised`` while the kernel says so, asked at most once a
   second of the monotonic clock; tracker.system_clock): ``t_ns`` + the
   system clock's TAI offset, read afresh at each such check (NTP may step
   the clock); source SYSTEM_CLOCK;
4. none: no absolute time, no aberration corrected.

The velocity for sources 2 and 3 is the latest SET_VELOCITY whose time
lies within ``time.velocity_max_age_s`` of the frame's (either side); an
older one is stale: not applied, and the context says so. A frame whose
absolute time would fall outside 1972-2200 has none.

Only the frame loop's thread uses a TimeBase; FC commands reach it as
values (tracker.daemon.commands).
"""

from __future__ import annotations

from collections.abc import Callable

from tracker.astrometry.observer import Observer, TimeSource
from tracker.astrometry.timescale import TimeError
from tracker.capture.base import Frame
from tracker.config import TimeConfig
from tracker.system_clock import kernel_synchronised, tai_minus_monotonic_ns

__all__ = ["TimeBase"]

_CHECK_PERIOD_NS = 1_000_000_000


class TimeBase:
    """Maps frames to :class:`Observer` contexts; see the module docstring.

    ``synchronised`` and ``system_offset_ns`` (tests) replace the kernel's
    answer and the system clock's TAI - monotonic offset.
    """

    def __init__(self, cfg: TimeConfig, *,
                 synchronised: Callable[[], bool | None] = kernel_synchronised,
                 system_offset_ns: Callable[[], int] = tai_minus_monotonic_ns) -> None:
        self.cfg = cfg
        self._synchronised = synchronised
        self._system_offset_ns = system_offset_ns
        self._sync_offset_ns: int | None = None
        self._velocity: tuple[int, tuple[float, float, float]] | None = None
        self._system: int | None = None            # offset while the system clock is trusted
        self._checked_at: int | None = None
        self._max_age_ns = round(cfg.velocity_max_age_s * 1e9)

    def time_sync(self, offset_ns: int) -> None:
        """TIME_SYNC: from now on TAI = monotonic + offset_ns (the latest one counts)."""
        self._sync_offset_ns = int(offset_ns)

    def set_velocity(self, t_tai_ns: int, velocity_km_s: tuple[float, float, float]) -> None:
        """SET_VELOCITY: the observer's geocentric velocity (ICRS, km/s) at TAI t_tai_ns."""
        self._velocity = (int(t_tai_ns), tuple(float(v) for v in velocity_km_s))

    def _offset(self, t_ns: int) -> tuple[int, TimeSource] | None:
        if self._sync_offset_ns is not None:
            return self._sync_offset_ns, TimeSource.TIME_SYNC
        policy = self.cfg.system_clock
        if policy == "never":
            return None
        if self._checked_at is None or not 0 <= t_ns - self._checked_at < _CHECK_PERIOD_NS:
            self._checked_at = t_ns
            trusted = policy == "always" or bool(self._synchronised())
            self._system = self._system_offset_ns() if trusted else None
        return None if self._system is None else (self._system, TimeSource.SYSTEM_CLOCK)

    def observer_at(self, t_ns: int) -> Observer:
        """The context of a frame exposed at ``t_ns`` (monotonic) with no record of its own."""
        found = self._offset(t_ns)
        if found is None:
            return Observer()
        offset, source = found
        t_tai = t_ns + offset
        velocity, stale = None, False
        if self._velocity is not None:
            if abs(t_tai - self._velocity[0]) <= self._max_age_ns:
                velocity = self._velocity[1]
            else:
                stale = True
        try:
            return Observer(t_tai, velocity, source, stale)
        except TimeError:
            return Observer()

    def observer_for(self, frame: Frame) -> Observer:
        """The context of a frame: its own record's, else :meth:`observer_at` its t_ns."""
        if frame.t_tai_ns is not None:
            return frame.recorded_observer()
        return self.observer_at(frame.t_ns)
