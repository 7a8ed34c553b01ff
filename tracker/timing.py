"""Per-stage wall-clock timing, reported in milliseconds."""

from __future__ import annotations

import time

__all__ = ["StageTimer"]


class StageTimer:
    """Accumulates milliseconds per named stage; reuse with :meth:`reset`.

    Usage::

        timer.reset()
        timer.start("background"); ...; timer.stop()
    """

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}
        self._name: str | None = None
        self._t0 = 0

    def reset(self) -> None:
        self.ms.clear()
        self._name = None

    def start(self, name: str) -> None:
        self.stop()
        self._name = name
        self._t0 = time.perf_counter_ns()

    def stop(self) -> None:
        if self._name is not None:
            dt = (time.perf_counter_ns() - self._t0) / 1e6
            self.ms[self._name] = self.ms.get(self._name, 0.0) + dt
            self._name = None

    @property
    def total_ms(self) -> float:
        return sum(self.ms.values())
