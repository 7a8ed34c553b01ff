"""systemd notification (sd_notify(3)) without a dependency, and the watchdog's pace.

:class:`Notifier` sends datagrams such as ``READY=1``, ``WATCHDOG=1`` or
``STATUS=...`` to the AF_UNIX socket named by ``$NOTIFY_SOCKET`` (a leading
``@`` means the abstract namespace). Without that variable (tests, a shell)
it does nothing. A send that fails is logged once and otherwise ignored:
systemd then restarts the unit through its watchdog, which is the right
outcome.

:class:`Watchdog` paces ``WATCHDOG=1``: at most every half of systemd's
``WatchdogSec`` (``$WATCHDOG_USEC``), as sd_watchdog_enabled(3) advises. The
daemon calls :meth:`Watchdog.kick` only from its loop, and only while the
loop is healthy, so a loop that hangs or a link that died stops the pings
and systemd restarts the unit.
"""

from __future__ import annotations

import logging
import os
import socket

__all__ = ["Notifier", "Watchdog", "watchdog_interval_s"]

log = logging.getLogger(__name__)


class Notifier:
    """``notify("READY=1")`` etc.; ``enabled`` says whether anyone is listening."""

    def __init__(self, address: str | None = None):
        address = os.environ.get("NOTIFY_SOCKET") if address is None else address
        self._addr = "\0" + address[1:] if address and address[0] == "@" else address
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) if self._addr else None
        self._warned = False

    @property
    def enabled(self) -> bool:
        return self._sock is not None

    def notify(self, *lines: str) -> None:
        if self._sock is None:
            return
        try:
            self._sock.sendto("\n".join(lines).encode(), self._addr)
        except OSError as exc:
            if not self._warned:
                log.warning("systemd notify to %s failed: %s", self._addr, exc)
                self._warned = True

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval_s() -> float | None:
    """Half of systemd's WatchdogSec for this process (``$WATCHDOG_USEC``), or None."""
    usec, pid = os.environ.get("WATCHDOG_USEC"), os.environ.get("WATCHDOG_PID")
    if not usec or (pid and pid != str(os.getpid())):
        return None
    try:
        return int(usec) / 2e6
    except ValueError:
        return None


class Watchdog:
    """Sends ``WATCHDOG=1`` through ``notifier`` at most every ``interval_s`` (None: never)."""

    def __init__(self, notifier: Notifier, interval_s: float | None):
        self.notifier = notifier
        self.period_ns = None if interval_s is None else int(interval_s * 1e9)
        self._next_ns = 0

    def kick(self, now_ns: int) -> None:
        """The loop is alive and well at now_ns: ping systemd if a ping is due."""
        if self.period_ns is not None and now_ns >= self._next_ns:
            self.notifier.notify("WATCHDOG=1")
            self._next_ns = now_ns + self.period_ns
