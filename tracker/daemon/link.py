"""The daemon's side of the serial link: results out, FC commands in, as values.

Wraps :class:`tracker.protocol.link.Link` (which owns the port, its reopen
with backoff, output rates, the priority queue and ACK/NACK) and implements
its :class:`~tracker.protocol.link.CommandHandler`. It never holds the
daemon: commands go from the link's reader thread into a
:class:`~tracker.daemon.commands.CommandMailbox` that the frame loop empties
(:meth:`DaemonLink.take_commands`), and STATUS comes from the last
:class:`~tracker.daemon.status.StatusSnapshot` the loop published
(:meth:`DaemonLink.publish`), complete from the start.

- SET_MODE, SET_EXPOSURE, SET_GAIN, TIME_SYNC, SET_VELOCITY: ACKed at once
  and posted for the loop, which applies them before the next frame
  (exposure and gain clamped to the configured limits; the time and the
  velocity go to its tracker.daemon.timebase.TimeBase). A ``fc_time_ns`` or
  velocity time outside 1972-2200 (TAI) is NACKed OUT_OF_RANGE by the
  decoder.
- ATTITUDE and CENTROIDS carry the frame's absolute time (TAI ns) as
  ``t_ns`` when its observer context has one (TIME_SYNCED set), else its
  monotonic ``t_ns``; ATTITUDE's ANNUAL_ABERRATION and OBSERVER_VELOCITY
  say what the solver corrected.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.astrometry.observer import Correction, Observer
from tracker.capture.base import Frame
from tracker.config import Config
from tracker.daemon.commands import CommandMailbox, Commands
from tracker.daemon.status import StatusSnapshot, status_values
from tracker.protocol.link import Link
from tracker.protocol.messages import BY_ID, AttitudeFlag, Mode, MsgId, Reason

__all__ = ["DaemonLink", "LinkCounts"]

_U32 = 2**32 - 1


class LinkCounts:
    """The link's fault counters as the daemon's Health counts them (totals so far)."""

    __slots__ = ("link_error", "rx_reject", "tx_drop", "link_internal")

    def __init__(self, stats: dict, rx_rejects: int, drops: int):
        self.link_error = stats.get("port_errors", 0) + stats.get("open_failures", 0)
        self.rx_reject = rx_rejects
        self.tx_drop = drops
        self.link_internal = stats.get("internal_errors", 0)


class DaemonLink:
    """Adapter between the frame loop and the protocol link; see the module docstring.

    ``open_port`` (tests) replaces the pyserial opener.
    """

    def __init__(self, cfg: Config, *, open_port=None):
        self.cfg = cfg
        self.link = Link(cfg.link, self, open_port=open_port)
        self.mailbox = CommandMailbox()
        self._status = StatusSnapshot()
        self._stars = np.zeros(cfg.detect.max_stars, BY_ID[MsgId.CENTROIDS].item_dtype)

    # -- life cycle (called by the loop) ------------------------------------

    def open(self) -> None:
        self.link.start()

    def close(self) -> None:
        self.link.close(drain_s=0.2)

    @property
    def is_open(self) -> bool:
        return self.link.is_open

    @property
    def failure(self) -> str | None:
        """Why the link can no longer serve the FC, or None (see Link.failure)."""
        return self.link.failure

    # -- CommandHandler: the link's reader thread ----------------------------

    def set_mode(self, mode: Mode) -> Reason:
        self.mailbox.post(mode=Mode(mode))
        return Reason.OK

    def set_exposure(self, exposure_us: int) -> Reason:
        self.mailbox.post(exposure_us=exposure_us)
        return Reason.OK

    def set_gain(self, gain: float) -> Reason:
        self.mailbox.post(gain=gain)
        return Reason.OK

    def time_sync(self, offset_ns: int) -> Reason:
        self.mailbox.post(time_offset_ns=offset_ns)
        return Reason.OK

    def set_velocity(self, t_tai_ns: int, velocity_km_s: tuple[float, float, float]
                     ) -> Reason:
        self.mailbox.post(velocity=(int(t_tai_ns), tuple(velocity_km_s)))
        return Reason.OK

    def status(self) -> dict:
        return status_values(self._status)

    # -- the frame loop's thread ----------------------------------------------

    def take_commands(self) -> Commands | None:
        """The FC's requests since the last call, as one value (None if none)."""
        return self.mailbox.take()

    def publish(self, snapshot) -> None:
        """The loop's latest STATUS: kept for REQUEST_STATUS, sent if STATUS is due."""
        self._status = snapshot
        self.link.send_status(**status_values(snapshot))

    def wire_latency_ms(self) -> dict:
        """Exposure mid-point to ATTITUDE's last byte on the wire, ms: percentiles and max."""
        return self.link.latency.percentiles()

    def counts(self) -> LinkCounts:
        return LinkCounts(self.link.stats(), self.link.rx_rejects, self.link.drops)

    def send_frame(self, frame: Frame, result, mode: Mode, observer: Observer,
                   t_ref_ns: int | None = None) -> None:
        """ATTITUDE (and CENTROIDS when due) for one frame seen in ``observer``'s context.

        ``result`` is the pipeline's FrameResult, or None for a frame taken
        but not processed (STANDBY): ATTITUDE then has VALID clear.
        ``t_ref_ns``: the frame's exposure mid-point on the monotonic clock,
        from which ATTITUDE's age and latency run (tracker.protocol.link).
        """
        sol = None if result is None else result.solution
        ok = bool(sol is not None and sol.ok)
        t_ns, flags = frame.t_ns, 0
        if observer.t_tai_ns is not None:
            t_ns, flags = observer.t_tai_ns, AttitudeFlag.TIME_SYNCED
        if ok and Correction.ANNUAL_ABERRATION in observer.corrections:
            flags |= AttitudeFlag.ANNUAL_ABERRATION
        if ok and Correction.OBSERVER_VELOCITY in observer.corrections:
            flags |= AttitudeFlag.OBSERVER_VELOCITY
        rate = sol.rate_rad_s if ok else None
        self.link.send_attitude(
            frame_id=frame.index & _U32, t_ns=t_ns, q=np.asarray(sol.q) if ok else None,
            sigma_cross_arcsec=float(sol.sigma_cross_arcsec) if ok else math.nan,
            sigma_roll_arcsec=float(sol.sigma_roll_arcsec) if ok else math.nan,
            matched=int(sol.matched) if ok else 0, mode=mode,
            flags=int(flags), rate_dps=np.degrees(rate) if rate is not None else None,
            t_ref_ns=t_ref_ns)
        if result is None or self.link.gate.rates_hz.get(MsgId.CENTROIDS, 0) <= 0:
            return
        stars = result.detections.stars
        n = min(len(stars), len(self._stars))
        out = self._stars[:n]
        for name in ("x", "y", "flux", "flags"):
            out[name] = stars[name][:n]
        hip = sol.hip if ok else None
        out["hip"] = hip[:n] if hip is not None and len(hip) >= n else 0
        self.link.send_centroids(frame.index & _U32, t_ns, out, total=len(stars))
