"""Time scales: TAI on the wire, UTC only at the edges, TT for the ephemeris.

The tracker's absolute time is **TAI nanoseconds since 1970-01-01T00:00:00
TAI** (``t_tai_ns``): a continuous count with no leap seconds, the scale of
PTP and, offset by 19 s, of GPS time. The flight computer sends it in
TIME_SYNC, so nothing on the wire depends on a leap-second table.

UTC appears only where people write times: ``utc`` strings in a replay's
``frames.jsonl`` (ISO 8601 ending in ``Z``) and in reports. UTC = TAI minus
the leap-second count of :data:`TAI_MINUS_UTC`, IERS Bulletin C's steps since
1972 (37 s since 2017-01-01; Bulletin C 70, July 2025, announced no step at
the end of 2025). A UTC after :data:`LEAP_TABLE_CONFIRMED_UNTIL` is converted
with the last known count; an unannounced step would shift such a time by
1 s, which moves the Earth's velocity by 0.03 m/s and aberration by
0.02 mas: irrelevant for attitude, stated so it is not a surprise. The
seconds before 1972 (UTC's rubber-second era) are refused.

TT = TAI + 32.184 s exactly. The ephemeris is argued in TDB, which differs
from TT by periodic terms below 1.7 ms; they are ignored (the Earth moves
50 m in that time).
"""

from __future__ import annotations

import calendar
import re
import time

__all__ = [
    "TAI_MINUS_UTC", "LEAP_TABLE_CONFIRMED_UNTIL", "TimeError", "tai_minus_utc_s",
    "tai_ns_from_utc_iso", "utc_iso_from_tai_ns", "jd_tt_from_tai_ns",
    "julian_year_from_tai_ns", "check_tai_ns", "TAI_NS_MIN", "TAI_NS_MAX",
]


class TimeError(ValueError):
    """A time that cannot be used; the message is one line."""


def _utc_s(date: str) -> int:
    return calendar.timegm(tuple(int(p) for p in date.split("-")) + (0, 0, 0))


# (first UTC second of the step, as POSIX seconds; TAI - UTC from then on, s).
TAI_MINUS_UTC: tuple[tuple[int, int], ...] = tuple((_utc_s(d), n) for d, n in (
    ("1972-01-01", 10), ("1972-07-01", 11), ("1973-01-01", 12), ("1974-01-01", 13),
    ("1975-01-01", 14), ("1976-01-01", 15), ("1977-01-01", 16), ("1978-01-01", 17),
    ("1979-01-01", 18), ("1980-01-01", 19), ("1981-07-01", 20), ("1982-07-01", 21),
    ("1983-07-01", 22), ("1985-07-01", 23), ("1988-01-01", 24), ("1990-01-01", 25),
    ("1991-01-01", 26), ("1992-07-01", 27), ("1993-07-01", 28), ("1994-07-01", 29),
    ("1996-01-01", 30), ("1997-07-01", 31), ("1999-01-01", 32), ("2006-01-01", 33),
    ("2009-01-01", 34), ("2012-07-01", 35), ("2015-07-01", 36), ("2017-01-01", 37),
))
LEAP_TABLE_CONFIRMED_UNTIL = "2025-12-31T23:59:59Z"

_NS = 1_000_000_000
_TT_MINUS_TAI_NS = 32_184_000_000
_UNIX_EPOCH_JD = 2440587.5
_J2000_JD = 2451545.0
# Times the tracker accepts as absolute (TIME_SYNC, replay): 1972 to 2200 (TAI).
TAI_NS_MIN = (_utc_s("1972-01-01") + 10) * _NS
TAI_NS_MAX = (_utc_s("2200-01-01") + 37) * _NS

_ISO = re.compile(r"(\d{4})-(\d{2})-(\d{2})[T ](\d{2}):(\d{2}):(\d{2})(\.\d{1,9})?Z\Z")


def tai_minus_utc_s(utc_posix_s: float) -> int:
    """TAI - UTC (whole seconds) at a UTC instant given as POSIX seconds (>= 1972)."""
    if utc_posix_s < TAI_MINUS_UTC[0][0]:
        raise TimeError("UTC before 1972 has no whole-second offset from TAI")
    count = TAI_MINUS_UTC[0][1]
    for start, n in TAI_MINUS_UTC:
        if utc_posix_s < start:
            break
        count = n
    return count


def tai_ns_from_utc_iso(text: str) -> int:
    """TAI ns since 1970 of an ISO 8601 UTC time ``YYYY-MM-DDThh:mm:ss[.f]Z``.

    A leap second (``23:59:60``) is accepted on the dates the table has one.
    """
    m = _ISO.match(text.strip()) if isinstance(text, str) else None
    if m is None:
        raise TimeError(f"utc {text!r}: expected ISO 8601 UTC like 2026-11-23T17:29:15.25Z")
    year, month, day, hour, minute, second = (int(g) for g in m.groups()[:6])
    frac_ns = int((m.group(7) or ".")[1:].ljust(9, "0"))
    if not (1 <= month <= 12 and 1 <= day <= calendar.monthrange(year, month)[1]
            and hour < 24 and minute < 60 and second <= 60):
        raise TimeError(f"utc {text!r}: no such date or time")
    posix = calendar.timegm((year, month, day, hour, minute, min(second, 59)))
    if second == 60:
        if hour != 23 or minute != 59 or tai_minus_utc_s(posix + 1) == tai_minus_utc_s(posix):
            raise TimeError(f"utc {text!r}: no leap second at that time")
        return (posix + tai_minus_utc_s(posix) + 1) * _NS + frac_ns
    return (posix + tai_minus_utc_s(posix)) * _NS + frac_ns


def utc_iso_from_tai_ns(t_tai_ns: int) -> str:
    """ISO 8601 UTC (``...Z``, nanoseconds) of a TAI time; a leap second prints as :60."""
    seconds, frac = divmod(int(check_tai_ns(int(t_tai_ns))), _NS)
    offset, leap = TAI_MINUS_UTC[0][1], False
    for start, n in TAI_MINUS_UTC:
        if seconds < start + n - 1:
            break
        if seconds == start + n - 1 and n == offset + 1:   # the inserted 23:59:60
            leap = True
            break
        offset = n
    y, mo, d, h, mi, s = time.gmtime(seconds - offset - leap)[:6]
    return f"{y:04d}-{mo:02d}-{d:02d}T{h:02d}:{mi:02d}:{60 if leap else s:02d}.{frac:09d}Z"


def jd_tt_from_tai_ns(t_tai_ns: int) -> tuple[float, float]:
    """Julian date in TT as two parts (whole days from 1970, fraction), for full precision."""
    tt_ns = int(t_tai_ns) + _TT_MINUS_TAI_NS
    days, rest_ns = divmod(tt_ns, 86400 * _NS)
    return _UNIX_EPOCH_JD + days, rest_ns / (86400 * _NS)


def julian_year_from_tai_ns(t_tai_ns: int) -> float:
    """Decimal Julian year (TT; J2000.0 = 2000.0) of a TAI time, the proper-motion epoch."""
    jd1, jd2 = jd_tt_from_tai_ns(t_tai_ns)
    return 2000.0 + ((jd1 - _J2000_JD) + jd2) / 365.25


def check_tai_ns(t_tai_ns: int) -> int:
    """The time itself if it lies in 1972-2200 TAI; otherwise :class:`TimeError`."""
    if not isinstance(t_tai_ns, int) or not TAI_NS_MIN <= t_tai_ns <= TAI_NS_MAX:
        raise TimeError(f"absolute time {t_tai_ns!r} ns is outside 1972-2200 (TAI ns since 1970)")
    return t_tai_ns

