"""Pseudo-terminals that stand in for the flight computer's serial cable.

``with NullModem() as (tracker_port, fc_port):`` gives two device paths;
bytes written to one arrive at the other, through the kernel's tty layer
(raw mode), as they would through a real cable. Used by ``tracker demo``,
the soak benchmark and the tests, so the service's real pyserial code runs
without serial hardware.

:class:`ReplugPty` is one pty whose tracker end is reached through a
symlink, as udev's ``/dev/fcu`` is; :meth:`ReplugPty.replug` swaps in a new
pair, as pulling and replugging a USB-serial cable would.
"""

from __future__ import annotations

import os
import pty
import select
import threading
import tty
from pathlib import Path

__all__ = ["NullModem", "ReplugPty"]


class ReplugPty:
    """The FC's end (``master``, non-blocking) of a pty reached through ``link_path``."""

    def __init__(self, link_path: Path | str):
        self.link_path = Path(link_path)
        self.master, self._slave = self._new_pair()

    def _new_pair(self) -> tuple[int, int]:
        master, slave = pty.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        tmp = self.link_path.with_suffix(".new")
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.link_path)
        return master, slave     # the slave is kept open so the node lives until opened

    def replug(self) -> None:
        """Close this pair (the tracker's reads fail) and put a new one behind the link."""
        old = (self.master, self._slave)
        self.master, self._slave = self._new_pair()
        for fd in old:
            os.close(fd)

    def drain_until(self, stop: threading.Event) -> None:
        """Read and drop what the tracker sends until ``stop`` is set (a thread's target).

        Reads go into one buffer made here, so draining allocates nothing per
        read (memory tests run it beside the daemon they measure).
        """
        buffer = bytearray(4096)
        while not stop.is_set():
            try:
                os.readv(self.master, [buffer])
            except (BlockingIOError, OSError):
                stop.wait(0.002)

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


class NullModem:
    """A relay thread copying between the masters of two pty pairs."""

    def __init__(self) -> None:
        self._ends: list[tuple[int, int]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.bytes_relayed = 0

    def __enter__(self) -> tuple[str, str]:
        for _ in range(2):
            master, slave = os.openpty()
            tty.setraw(master)
            tty.setraw(slave)
            self._ends.append((master, slave))
        self._thread = threading.Thread(target=self._relay, name="null-modem", daemon=True)
        self._thread.start()
        return os.ttyname(self._ends[0][1]), os.ttyname(self._ends[1][1])

    def _relay(self) -> None:
        a, b = self._ends[0][0], self._ends[1][0]
        while not self._stop.is_set():
            ready, _, _ = select.select([a, b], [], [], 0.02)
            for fd in ready:
                try:
                    data = os.read(fd, 65536)
                    os.write(b if fd == a else a, data)
                except OSError:
                    continue  # the far end is closed or reopening: drop, as a cable would
                self.bytes_relayed += len(data)

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        for master, slave in self._ends:
            os.close(slave)
            os.close(master)
        self._ends.clear()
