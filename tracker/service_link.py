"""The service's side of the serial link: results out, FC commands in.

Wraps :class:`tracker.protocol.link.Link` (which owns the port, its reopen
with backoff, output rates, the priority queue and ACK/NACK) and
implements its :class:`~tracker.protocol.link.CommandHandler`. Commands
arrive on the link's reader thread; they are only stored there and applied
by :meth:`ServiceLink.poll` on the frame loop's thread, the one thread that
touches the service.

State -> protocol mode: standby -> STANDBY, acquiring -> LOST_IN_SPACE,
tracking -> TRACKING, fault -> FAULT (STATUS.last_error says why).
SET_MODE LOST_IN_SPACE forgets the tracking state and acquires from
scratch; SET_MODE TRACKING keeps any lock. Either way the service enters
tracking by itself once frames solve.
SET_EXPOSURE / SET_GAIN fix the value and stop automatic exposure.
After TIME_SYNC, ``t_ns`` in ATTITUDE and CENTROIDS is on the FC's clock and
TIME_SYNCED is set.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from tracker.capture.live import cpu_temperature_c
from tracker.config import Config, config_checksum
from tracker.protocol.link import Link
from tracker.protocol.messages import BY_ID, AttitudeFlag, Mode, MsgId, Reason
from tracker.service import State

__all__ = ["ServiceLink"]

_MODE_OF_STATE = {"standby": Mode.STANDBY, "acquiring": Mode.LOST_IN_SPACE,
                  "fault": Mode.FAULT, "tracking": Mode.TRACKING}
_RX_REJECTS = ("rx_bad_header", "rx_bad_crc", "rx_unknown_id", "rx_wrong_length",
               "rx_out_of_range")
_U32 = 2**32 - 1


class ServiceLink:
    """Adapter between :class:`~tracker.service.Service` and the protocol link.

    ``link`` (tests) replaces the Link built from ``cfg.link``; it must have
    been made with this object as its handler (see :meth:`attach`).
    """

    def __init__(self, cfg: Config, *, open_port=None):
        self.cfg = cfg
        self.link = Link(cfg.link, self, open_port=open_port)
        self._lock = threading.Lock()
        self._pending: dict[str, object] = {}
        self._time_offset_ns: int | None = None
        self._status: dict = {}
        self._temp_c = math.nan
        self._temp_next_ns = 0
        self._config_crc = config_checksum(cfg)
        self._stars = np.zeros(cfg.detect.max_stars, BY_ID[MsgId.CENTROIDS].item_dtype)

    # -- life cycle (called by the service) ---------------------------------

    def open(self) -> None:
        self.link.start()

    def close(self) -> None:
        self.link.close(drain_s=0.2)

    @property
    def is_open(self) -> bool:
        return self.link.is_open

    # -- CommandHandler: the link's reader thread ----------------------------

    def _store(self, key: str, value) -> Reason:
        with self._lock:
            self._pending[key] = value
        return Reason.OK

    def set_mode(self, mode: Mode) -> Reason:
        return self._store("mode", Mode(mode))

    def set_exposure(self, exposure_us: int) -> Reason:
        return self._store("exposure_us", float(exposure_us))

    def set_gain(self, gain: float) -> Reason:
        return self._store("gain", float(gain))

    def time_sync(self, offset_ns: int) -> Reason:
        self._time_offset_ns = int(offset_ns)
        return Reason.OK

    def status(self) -> dict:
        return dict(self._status)

    # -- the frame loop's thread ----------------------------------------------

    def poll(self, service) -> None:
        """Apply commands received since the last call; mirror the link's counters."""
        with self._lock:
            pending, self._pending = self._pending, {}
        if "mode" in pending:
            mode = pending["mode"]
            service.set_mode(State.STANDBY if mode == Mode.STANDBY else State.ACQUIRING,
                             reacquire=mode == Mode.LOST_IN_SPACE)
        if "exposure_us" in pending or "gain" in pending:
            service.set_exposure(pending.get("exposure_us"), pending.get("gain"))
        stats = self.link.stats()
        health = service.health
        for name, value in (("link_error", stats.get("port_errors", 0)
                             + stats.get("open_failures", 0)),
                            ("rx_reject", sum(stats.get(k, 0) for k in _RX_REJECTS)),
                            ("tx_drop", self.link.drops)):
            if value > health.faults[name]:
                health.fault(name, count=value - health.faults[name])

    def _t(self, t_ns: int) -> tuple[int, int]:
        offset = self._time_offset_ns
        if offset is None:
            return t_ns, 0
        return t_ns + offset, int(AttitudeFlag.TIME_SYNCED)

    def send_frame(self, frame, result, state) -> None:
        """ATTITUDE (and CENTROIDS when due) for one processed frame."""
        sol = result.solution
        ok = bool(sol is not None and getattr(sol, "ok", False))
        t_ns, flags = self._t(frame.t_ns)
        rate = getattr(sol, "rate_rad_s", None) if ok else None
        self.link.send_attitude(
            frame_id=frame.index & _U32, t_ns=t_ns, q=np.asarray(sol.q) if ok else None,
            sigma_xy_arcsec=float(sol.sigma_cross_arcsec) if ok else math.nan,
            sigma_roll_arcsec=float(sol.sigma_roll_arcsec) if ok else math.nan,
            matched=int(sol.matched) if ok else 0, mode=_MODE_OF_STATE[state.value],
            flags=flags, rate_dps=np.degrees(rate) if rate is not None else None)
        if self.link.gate.rates_hz.get(MsgId.CENTROIDS, 0) <= 0:
            return
        stars = result.detections.stars
        n = min(len(stars), len(self._stars))
        out = self._stars[:n]
        for name in ("x", "y", "flux", "flags"):
            out[name] = stars[name][:n]
        hip = getattr(sol, "hip", None) if ok else None
        out["hip"] = hip[:n] if hip is not None and len(hip) >= n else 0
        self.link.send_centroids(frame.index & _U32, t_ns, out, total=len(stars))

    def send_status(self, service) -> None:
        """STATUS (when due by the link's rate) from the service's health."""
        h = service.health
        if time.monotonic_ns() >= self._temp_next_ns:    # sysfs read at most once a second
            temp = cpu_temperature_c()
            self._temp_c = math.nan if temp is None else temp
            self._temp_next_ns = time.monotonic_ns() + 1_000_000_000
        self._status = {
            "uptime_s": min(int(h.uptime_s), _U32),
            "frame_rate_hz": float(h.frame_rate_hz),
            "exposure_us": min(int(service.exposure.exposure_us), _U32),
            "gain": float(service.exposure.gain),
            "cpu_temp_c": self._temp_c,
            "mode": int(_MODE_OF_STATE[service.state.value]),
            "frames": h.frames & _U32, "capture_faults": min(h.capture_faults, _U32),
            "solve_failures": min(h.solve_failures, _U32), "last_error": h.last_error,
            "config_crc": self._config_crc,
        }
        self.link.send_status(**self._status)
