"""The observer context of one frame: when it was seen, and how fast the camera moved.

An :class:`Observer` travels with a frame from its source through
``Pipeline.process`` to the solver:

* ``t_tai_ns``: the exposure mid-point, TAI ns since 1970
  (tracker.astrometry.timescale), or None when no absolute time is known;
* ``velocity_km_s``: the observer's velocity relative to the Earth's centre,
  ICRS axes, km/s (a spacecraft's orbital velocity), or None (at rest
  there, or unknown);
* ``time_source``: where the absolute time came from (:class:`TimeSource`);
* ``velocity_stale``: a velocity was known but too old for this frame, so
  it is not applied.

What the solver corrects follows from it (:attr:`Observer.corrections`):
with an absolute time, the annual aberration (the Earth's barycentric
velocity, up to 20.5 arcsec); with a velocity as well, the observer's own
(up to 5 arcsec in low Earth orbit). Without an absolute time nothing is
corrected, a velocity included: the Earth's 30 km/s dwarfs it, and
correcting the smaller part alone would not make the attitude ICRS.
The attitude is then the apparent one, off the ICRS attitude by up to
|beta| ~ 25 arcsec, and the flags say so.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from tracker.astrometry.aberration import observer_beta
from tracker.astrometry.timescale import (
    check_tai_ns,
    julian_year_from_tai_ns,
    utc_iso_from_tai_ns,
)

__all__ = ["Observer", "TimeSource", "Correction", "VELOCITY_LIMIT_KM_S", "check_velocity"]

# Largest velocity component accepted, km/s (geocentric): escape speed at the Earth's
# surface is 11.2 km/s; 200 covers every spacecraft's speed relative to the Earth.
VELOCITY_LIMIT_KM_S = 200.0


class TimeSource(enum.IntEnum):
    """Where a frame's absolute time came from (STATUS ``time_source``)."""

    NONE = 0            # no absolute time: t_ns is the tracker's monotonic clock
    TIME_SYNC = 1       # the flight computer's TIME_SYNC
    SYSTEM_CLOCK = 2    # the tracker's own clock, trusted by time.system_clock
    RECORD = 3          # the frame's record (a replay's frames.jsonl `utc`)


class Correction(enum.IntFlag):
    """What the solver corrects for a frame (STATUS ``corrections``)."""

    NONE = 0
    ANNUAL_ABERRATION = 1     # the Earth's barycentric velocity at the frame's time
    OBSERVER_VELOCITY = 2     # plus the observer's velocity relative to the Earth's centre
    VELOCITY_STALE = 4        # a velocity is known but too old for the frame: not applied


def check_velocity(velocity_km_s, what: str = "observer velocity") -> tuple[float, float, float]:
    """Three finite numbers within +-:data:`VELOCITY_LIMIT_KM_S`, or ValueError (one line)."""
    try:
        v = tuple(float(c) for c in velocity_km_s)
    except (TypeError, ValueError):
        v = ()
    if isinstance(velocity_km_s, (str, bytes)) or len(v) != 3 or not all(
            math.isfinite(c) and abs(c) <= VELOCITY_LIMIT_KM_S for c in v):
        raise ValueError(f"{what} {velocity_km_s!r}: expected three numbers (x, y, z; km/s, "
                         f"ICRS axes) within +-{VELOCITY_LIMIT_KM_S:g}")
    return v


@dataclass(frozen=True)
class Observer:
    """One frame's observer context; see the module docstring.

    Raises TimeError for an absolute time outside 1972-2200 and ValueError
    for a velocity that is not three finite numbers within
    +-:data:`VELOCITY_LIMIT_KM_S` km/s.
    """

    t_tai_ns: int | None = None
    velocity_km_s: tuple[float, float, float] | None = None
    time_source: TimeSource = TimeSource.NONE
    velocity_stale: bool = False

    def __post_init__(self) -> None:
        if self.t_tai_ns is not None:
            check_tai_ns(self.t_tai_ns)
        if self.velocity_km_s is not None:
            object.__setattr__(self, "velocity_km_s", check_velocity(self.velocity_km_s))
        if (self.t_tai_ns is None) != (self.time_source == TimeSource.NONE):
            raise ValueError("an absolute time needs its source, and a source its time")

    @property
    def corrections(self) -> Correction:
        """The corrections the solver applies for this context."""
        if self.t_tai_ns is None:
            return Correction.NONE
        out = Correction.ANNUAL_ABERRATION
        if self.velocity_km_s is not None:
            out |= Correction.OBSERVER_VELOCITY
        elif self.velocity_stale:
            out |= Correction.VELOCITY_STALE
        return out

    def beta(self) -> np.ndarray | None:
        """The observer's barycentric velocity over c (ICRS, shape (3,)), None without a time."""
        if self.t_tai_ns is None:
            return None
        return observer_beta(self.t_tai_ns, self.velocity_km_s)

    @property
    def epoch_year(self) -> float | None:
        """The frame's decimal Julian year (TT), the proper-motion epoch; None without a time."""
        return None if self.t_tai_ns is None else julian_year_from_tai_ns(self.t_tai_ns)

    def to_json(self) -> dict:
        """``utc``, ``time_source``, ``observer_velocity_km_s`` and ``corrections`` (names)."""
        return {"utc": None if self.t_tai_ns is None else utc_iso_from_tai_ns(self.t_tai_ns),
                "time_source": self.time_source.name.lower(),
                "observer_velocity_km_s": (None if self.velocity_km_s is None
                                           else list(self.velocity_km_s)),
                "corrections": [c.name.lower() for c in Correction
                                if c and c in self.corrections]}
