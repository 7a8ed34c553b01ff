"""Health counters of the running service, for STATUS packets and systemd.

Every fault the service survives is counted here under a fixed name (see
:data:`FAULTS`), and the last one is kept as a numeric code for the STATUS
packet's ``last_error``. Latencies go into a fixed ring buffer (no
allocation per frame) from which percentiles are read.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["Health", "FAULTS"]

# fault name -> last_error code in STATUS (0 = none). Frames dropped for the
# first four are "capture_faults" in STATUS; the link ones have their own fields.
FAULTS = {
    "frame_unreadable": 1,   # the source yielded a FrameError (corrupt file, bad buffer)
    "camera_timeout": 2,     # no frame within capture.timeout_s
    "camera_lost": 3,        # the source raised; closed and reopened with backoff
    "stage_error": 4,        # detect/identify raised; that frame dropped
    "link_error": 5,         # the serial port failed or would not open; retried by the link
    "rx_reject": 6,          # FC frames refused (bad header, CRC, id, length, range)
    "tx_drop": 7,            # telemetry the link queue dropped (full or stale)
}
_DROPPING = ("frame_unreadable", "camera_timeout", "camera_lost", "stage_error")


class Health:
    """Counters, rates and latency percentiles; see the module docstring."""

    def __init__(self, ring: int = 4096):
        self.started_ns = time.monotonic_ns()
        self.faults = dict.fromkeys(FAULTS, 0)
        self.last_error = 0
        self.last_error_text = ""
        self.frames = 0            # frames taken from the source (good or not)
        self.processed = 0         # frames through the pipeline
        self.solved = 0
        self.solve_failures = 0    # frames with stars but no attitude
        self.frame_rate_hz = 0.0
        self._rate_t_ns = self.started_ns
        self._rate_n = 0
        self._lat = np.zeros(ring, np.float64)
        self._lat_n = 0

    def fault(self, name: str, text: str = "", count: int = 1) -> None:
        """Count ``count`` occurrences of a fault from :data:`FAULTS`."""
        self.faults[name] += count
        self.last_error = FAULTS[name]
        self.last_error_text = text or name

    @property
    def capture_faults(self) -> int:
        """Frames lost for any reason (the STATUS field of that name)."""
        return sum(self.faults[k] for k in _DROPPING)

    def frame_done(self, latency_ms: float) -> None:
        """Record one processed frame's end-to-end latency."""
        self._lat[self._lat_n % len(self._lat)] = latency_ms
        self._lat_n += 1
        self._rate_n += 1
        now = time.monotonic_ns()
        if now - self._rate_t_ns >= 2_000_000_000:
            self.frame_rate_hz = self._rate_n * 1e9 / (now - self._rate_t_ns)
            self._rate_t_ns, self._rate_n = now, 0

    def latency_percentiles(self, qs=(50, 90, 99)) -> dict:
        """Latency percentiles (ms) over the last ``ring`` frames; empty before any."""
        n = min(self._lat_n, len(self._lat))
        if not n:
            return {}
        values = np.percentile(self._lat[:n], qs)
        return {f"p{q}": float(v) for q, v in zip(qs, values, strict=True)}

    @property
    def uptime_s(self) -> float:
        return (time.monotonic_ns() - self.started_ns) / 1e9

    def summary(self, state: str) -> str:
        """One line for systemd's STATUS= and the log."""
        faults = ", ".join(f"{k} {v}" for k, v in self.faults.items() if v)
        lat = self.latency_percentiles((50,))
        lat_text = f", latency p50 {lat['p50']:.1f} ms" if lat else ""
        return (f"{state}: {self.processed} frames, {self.solved} solved, "
                f"{self.frame_rate_hz:.1f} fps{lat_text}; faults: {faults or 'none'}")
