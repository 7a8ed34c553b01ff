"""The daemon's time: a monotonic clock and interruptible waits, in one injectable object.

Every wait of the loop goes through :meth:`Clock.wait`, so a test can run
the loop on a virtual clock (the camera absent for a minute, in
milliseconds of real time) and every timing decision is made from
:meth:`Clock.now_ns`, never from a second clock.
"""

from __future__ import annotations

import threading
import time

__all__ = ["Clock"]


class Clock:
    """CLOCK_MONOTONIC in ns; :meth:`wait` returns early when ``event`` is set."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def wait(self, event: threading.Event, seconds: float) -> bool:
        """Wait up to ``seconds``; True if ``event`` was set (a stop request)."""
        return event.wait(seconds)
