"""Two pseudo-terminals joined back to back: a serial cable on one machine.

``with NullModem() as (tracker_port, fc_port):`` gives two device paths;
bytes written to one arrive at the other, through the kernel's tty layer
(raw mode), as they would through a real cable. Used by ``tracker demo``,
the soak benchmark and the tests, so the service's real pyserial code runs
without serial hardware.
"""

from __future__ import annotations

import os
import select
import threading
import tty

__all__ = ["NullModem"]


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
