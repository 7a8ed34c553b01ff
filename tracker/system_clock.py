"""The tracker's own clock as an absolute time: is it synchronised, and what TAI is it.

Frames are stamped on CLOCK_MONOTONIC; the system clock (CLOCK_REALTIME)
is UTC as POSIX counts it (no leap seconds: the inserted second repeats).
TAI = UTC + the leap-second count (tracker.astrometry.timescale), so
``TAI - monotonic`` is an offset that turns a frame's ``t_ns`` into TAI.

Whether the system clock deserves that trust is the configuration's call
(``time.system_clock``), because a Raspberry Pi 5 keeps time through a
power-off only with its optional RTC battery: without it, it boots with the
time it saved at shutdown (systemd-timesyncd's clock file, or
fake-hwclock), possibly months old, until NTP corrects it. With
``synchronised`` the tracker asks the kernel, as ``timedatectl``'s "System
clock synchronized" does (systemd's timedated): ``adjtimex()``'s maximum
error below 16 s. NTP and PTP daemons (systemd-timesyncd, chrony, ntpd,
ptp4l with phc2sys) set that error at each synchronisation; the kernel then
grows it by 500 us per second, so a clock that lost its server counts as
synchronised for up to 8.9 hours, by when it may be a few seconds off.
Aberration needs far less: an hour of error moves the annual aberration by
0.015 arcsec.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time

from tracker.astrometry.timescale import tai_minus_utc_s

__all__ = ["kernel_synchronised", "tai_minus_monotonic_ns", "SYNC_MAX_ERROR_US"]

# timedatectl's rule (systemd timedated): synchronised while maxerror < 16 s.
SYNC_MAX_ERROR_US = 16_000_000
_NS = 1_000_000_000


class _Timex(ctypes.Structure):
    """The head of Linux's ``struct timex`` (the rest is room the kernel may fill)."""

    _fields_ = [("modes", ctypes.c_uint), ("offset", ctypes.c_long), ("freq", ctypes.c_long),
                ("maxerror", ctypes.c_long), ("esterror", ctypes.c_long),
                ("status", ctypes.c_int), ("rest", ctypes.c_char * 256)]


def _adjtimex():
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name, use_errno=True).adjtimex
    except (OSError, AttributeError, TypeError):
        return None


def kernel_synchronised() -> bool | None:
    """True if the kernel says an NTP/PTP daemon keeps the clock within 16 s.

    None where it cannot be asked (not Linux, or adjtimex refused).
    Reading (``modes`` = 0) needs no privilege.
    """
    call = _adjtimex()
    if call is None:
        return None
    tx = _Timex()
    if call(ctypes.byref(tx)) < 0:
        return None
    return 0 <= tx.maxerror < SYNC_MAX_ERROR_US


def tai_minus_monotonic_ns() -> int:
    """TAI (ns since 1970, from the system clock and the leap table) minus CLOCK_MONOTONIC.

    The system clock is read between two monotonic reads and paired with
    their mean, so the offset is good to the reads' spacing (microseconds).
    """
    m0 = time.monotonic_ns()
    utc_ns = time.time_ns()
    m1 = time.monotonic_ns()
    tai_ns = utc_ns + tai_minus_utc_s(utc_ns / _NS) * _NS
    return tai_ns - (m0 + m1) // 2
