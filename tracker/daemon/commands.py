"""FC commands on their way to the frame loop, as values.

The link's reader thread posts what the FC asked (SET_MODE, SET_EXPOSURE,
SET_GAIN, TIME_SYNC, SET_VELOCITY) into a :class:`CommandMailbox`; the frame loop takes everything
posted since its last look as one immutable :class:`Commands` value and
applies it between frames. A later request of one kind replaces an earlier
one, and a LOST_IN_SPACE anywhere in between is kept as ``reacquire``, so
applying the value has the effect of applying the commands one by one in
the order received, and the mailbox never overflows: any burst is ACKed.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

from tracker.protocol.messages import Mode

__all__ = ["Commands", "CommandMailbox"]


@dataclass(frozen=True)
class Commands:
    """What the FC asked since the loop last looked; None = not asked."""

    mode: Mode | None = None
    reacquire: bool = False        # forget the tracking lock (SET_MODE LOST_IN_SPACE)
    exposure_us: float | None = None
    gain: float | None = None
    time_offset_ns: int | None = None      # TAI - monotonic clock (TIME_SYNC)
    velocity: tuple[int, tuple[float, float, float]] | None = None   # (t TAI ns, km/s)


class CommandMailbox:
    """Thread-safe: :meth:`post` from the link's reader, :meth:`take` from the loop."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: Commands | None = None

    def post(self, *, mode: Mode | None = None, exposure_us: float | None = None,
             gain: float | None = None, time_offset_ns: int | None = None,
             velocity: tuple[int, tuple[float, float, float]] | None = None) -> None:
        """Record one command's request (the others keep their pending values)."""
        with self._lock:
            cur = self._pending or Commands()
            if mode is not None:
                cur = replace(cur, mode=mode,
                              reacquire=cur.reacquire or mode == Mode.LOST_IN_SPACE)
            if exposure_us is not None:
                cur = replace(cur, exposure_us=float(exposure_us))
            if gain is not None:
                cur = replace(cur, gain=float(gain))
            if time_offset_ns is not None:
                cur = replace(cur, time_offset_ns=int(time_offset_ns))
            if velocity is not None:
                cur = replace(cur, velocity=velocity)
            self._pending = cur

    def take(self) -> Commands | None:
        """Everything posted since the last take, or None if nothing was."""
        with self._lock:
            cur, self._pending = self._pending, None
            return cur
