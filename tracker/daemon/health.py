"""Health counters of the running daemon, for STATUS packets and systemd.

Every fault the daemon survives is counted here under its
:class:`~tracker.protocol.messages.ErrorCode` (the ICD lists them), and the
latest one is kept for STATUS ``last_error``. Latencies go into a fixed ring
buffer (no allocation per frame) from which percentiles are read. Times come
from the daemon's clock (ns), so a test's virtual clock drives rates and
uptime too.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from tracker.protocol.messages import ErrorCode
from tracker.timing import LatencyRing

__all__ = ["Health", "FRAME_LOSSES"]

# Faults that lose frames: STATUS capture_faults is their sum.
FRAME_LOSSES = (ErrorCode.FRAME_UNREADABLE, ErrorCode.CAMERA_TIMEOUT, ErrorCode.CAMERA_LOST,
                ErrorCode.STAGE_ERROR)
_RATE_WINDOW_NS = 2_000_000_000


class Health:
    """Counters, rates and latency percentiles; see the module docstring."""

    def __init__(self, clock: Callable[[], int] = time.monotonic_ns, ring: int = 4096):
        self._clock = clock
        self.started_ns = clock()
        self.faults = dict.fromkeys((e for e in ErrorCode if e != ErrorCode.NONE), 0)
        self.last_error = ErrorCode.NONE
        self.last_error_text = ""
        self.frames = 0            # frames received from the source (good or not)
        self.superseded = 0        # live frames a newer one replaced before processing
        self.processed = 0         # frames through the pipeline
        self.solved = 0
        self.solve_failures = 0    # frames with stars but no attitude
        self.frame_rate_hz = 0.0
        self._rate_t_ns = self.started_ns
        self._rate_n = 0
        self.latency = LatencyRing(ring)

    def fault(self, code: ErrorCode, text: str = "", count: int = 1) -> None:
        """Count ``count`` occurrences of a fault; it becomes the last error."""
        self.faults[code] += count
        self.last_error = code
        self.last_error_text = text or code.name.lower()

    @property
    def capture_faults(self) -> int:
        """Frames lost for any reason (the STATUS field of that name)."""
        return sum(self.faults[k] for k in FRAME_LOSSES)

    def frame_done(self, latency_ms: float) -> None:
        """Record one processed frame's end-to-end latency."""
        self.latency.add(latency_ms)
        self._rate_n += 1
        self.tick()

    def tick(self) -> None:
        """Refresh the frame rate (frames per second over the last ~2 s; 0 when none come)."""
        now = self._clock()
        if now - self._rate_t_ns >= _RATE_WINDOW_NS:
            self.frame_rate_hz = self._rate_n * 1e9 / (now - self._rate_t_ns)
            self._rate_t_ns, self._rate_n = now, 0

    def latency_percentiles(self, qs=(50, 90, 99)) -> dict:
        """Latency percentiles (ms) over the last ``ring`` frames, and ``max``; empty before
        any."""
        return self.latency.percentiles(qs)

    def fault_counts(self) -> dict[str, int]:
        """The faults seen so far, by lower-case ErrorCode name (reports, JSON)."""
        return {k.name.lower(): v for k, v in self.faults.items() if v}

    @property
    def uptime_s(self) -> float:
        return (self._clock() - self.started_ns) / 1e9

    def summary(self, mode: str) -> str:
        """One line for systemd's STATUS= and the log."""
        faults = ", ".join(f"{k} {v}" for k, v in self.fault_counts().items())
        lat = self.latency_percentiles((50,))
        lat_text = f", latency p50 {lat['p50']:.1f} ms" if lat else ""
        last = f"; last: {self.last_error_text}" if self.last_error else ""
        skipped = f", {self.superseded} superseded" if self.superseded else ""
        return (f"{mode}: {self.processed} frames, {self.solved} solved{skipped}, "
                f"{self.frame_rate_hz:.1f} fps{lat_text}; faults: {faults or 'none'}{last}")
