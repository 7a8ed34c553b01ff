"""A one-line progress bar on standard error, shown only on a terminal (and if enabled)."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """``advance()`` once per item; ``total`` None for an open-ended run."""

    def __init__(self, total: int | None, label: str, stream=None, enabled: bool = True):
        self.total = total
        self.label = label
        self.stream = stream or sys.stderr
        self.count = 0
        self.enabled = enabled and bool(getattr(self.stream, "isatty", lambda: False)())
        self._t0 = time.monotonic()
        self._last_draw = 0.0

    def advance(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if self.enabled and (now - self._last_draw > 0.1 or self.count == self.total):
            self._last_draw = now
            self._draw(now)

    def note(self, text: str) -> None:
        """A message on its own line, the bar redrawn after it."""
        if self.enabled:
            self.stream.write("\r\033[K" + text + "\n")
        else:
            self.stream.write(text + "\n")

    def _draw(self, now: float) -> None:
        rate = self.count / max(now - self._t0, 1e-9)
        if self.total:
            done = int(30 * self.count / self.total)
            bar = "#" * done + "-" * (30 - done)
            text = f"{self.label} [{bar}] {self.count}/{self.total} {rate:.1f}/s"
        else:
            text = f"{self.label} {self.count} {rate:.1f}/s"
        self.stream.write("\r\033[K" + text)
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.count:
            self.stream.write("\n")
            self.stream.flush()
