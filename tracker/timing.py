"""Per-stage wall-clock timing and latency percentiles, reported in milliseconds."""

from __future__ import annotations

import threading
import time

import numpy as np

__all__ = ["StageTimer", "LatencyRing"]


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


class LatencyRing:
    """The last ``size`` latencies (ms) in a fixed ring; percentiles and the largest.

    :meth:`add` allocates nothing; one writer thread and readers in other
    threads may share it (a lock guards the ring).
    """

    def __init__(self, size: int = 4096) -> None:
        self._values = np.zeros(int(size), np.float64)
        self._n = 0
        self._lock = threading.Lock()

    def add(self, ms: float) -> None:
        with self._lock:
            self._values[self._n % len(self._values)] = ms
            self._n += 1

    @property
    def count(self) -> int:
        """Latencies added so far (all of them, not only those still in the ring)."""
        return self._n

    def percentiles(self, qs=(50, 90, 99)) -> dict:
        """``{"p50": ms, ...}`` and ``"max"`` over the ring; empty before any value."""
        with self._lock:
            n = min(self._n, len(self._values))
            if not n:
                return {}
            values = self._values[:n].copy()
        out = {f"p{q}": float(v) for q, v in zip(qs, np.percentile(values, qs), strict=True)}
        out["max"] = float(values.max())
        return out
