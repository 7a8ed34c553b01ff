"""The serial link on the tracker's side: paced, prioritised writer; command reader.

The frame loop calls :meth:`Link.send_attitude`, :meth:`Link.send_centroids`
and :meth:`Link.send_status`. None of them blocks: each checks the message's
output rate, encodes, and puts the packet in a bounded queue. A writer thread
takes packets by queue class (``MessageDef.priority``: 0 ATTITUDE, 1 ACK/NACK,
2 CENTROIDS, 3 STATUS) and paces itself to ``bandwidth_fraction * baudrate /
10`` bytes per second, so the kernel's transmit buffer stays short and the
queue, not the order of arrival, decides what goes first. ATTITUDE goes
before replies, so no command traffic can slow it; a reply waits at most one
ATTITUDE packet.

When a class's queue is full its oldest packet is dropped; a telemetry packet
older than ``max_age_ms`` when its turn comes is dropped too (an ATTITUDE
given its frame's time is aged from that: :meth:`Link.send_attitude`). Replies are not
dropped for age: a burst of up to ``queue_replies`` commands gets every
reply; a longer flood (commands arriving faster than their replies can be
sent) sheds the oldest waiting replies. Every drop is counted.

A reader thread decodes commands from the FC and answers each with exactly
one ACK or NACK. PING, SET_OUTPUT and REQUEST_STATUS are handled here;
SET_MODE, SET_EXPOSURE, SET_GAIN, TIME_SYNC and SET_VELOCITY go to the daemon's
:class:`CommandHandler`, called on the reader thread. Commands with a bad
CRC, unknown id, wrong length or out-of-range field are NACKed without
calling it. If the port fails (open, read or write), it is closed and
reopened after ``reopen_backoff_s``, doubling up to ``reopen_backoff_max_s``.

Latency: for each ATTITUDE given its frame's time (``t_ref_ns``, the
exposure mid-point on this clock), the writer records the time from it to
the packet's last byte on the wire: when ``write`` returns, plus the bytes
still in the kernel's transmit queue (TIOCOUTQ, the packet itself at least
when the port cannot say) at the baud rate. :attr:`Link.latency` holds
them (percentiles, the largest). The stale rule bounds it: an ATTITUDE is
never sent more than ``max_age_ms`` after its exposure plus the writer's
burst (20 ms of the link's bandwidth) and its own transmission.

An exception raised while serving the FC (a bug, or a handler that fails)
is caught, counted (``internal_errors``), logged and answered with NACK
INTERNAL; the thread goes on. A thread that ends anyway sets
:attr:`Link.failure`, which the daemon checks on every tick: it then exits
for systemd to restart it, rather than run on deaf.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

import numpy as np
import serial

from tracker.config import LinkConfig
from tracker.protocol.budget import BITS_PER_BYTE, bytes_per_second
from tracker.protocol.decoder import Packet, Rejection, StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.messages import (
    BY_ID,
    AttitudeFlag,
    Direction,
    Mode,
    MsgId,
    Reason,
    saturate,
)
from tracker.timing import LatencyRing

__all__ = ["CommandHandler", "Link", "OutputGate", "LINK_STATUS_FIELDS"]

log = logging.getLogger(__name__)

_PORT_ERRORS = (serial.SerialException, OSError, TypeError, ValueError)
_CLASSES = ("attitude", "reply", "centroids", "status")   # index = MessageDef.priority
_REPLY = BY_ID[MsgId.ACK].priority
_NAN = float("nan")
# STATUS fields the link fills in from its own counters.
LINK_STATUS_FIELDS = ("link_drops", "link_reopens", "rx_rejects")
# Decoder counters that are FC packets refused (STATUS rx_rejects).
_RX_REJECTS = ("bad_header", "bad_crc", "unknown_id", "wrong_length", "out_of_range")
_LOGGED_ERRORS = 5
# The flags a caller may add (the aberration ones only to a VALID attitude).
_SENT_FLAGS = (AttitudeFlag.TIME_SYNCED | AttitudeFlag.ANNUAL_ABERRATION
               | AttitudeFlag.OBSERVER_VELOCITY)
_CORRECTION_FLAGS = AttitudeFlag.ANNUAL_ABERRATION | AttitudeFlag.OBSERVER_VELOCITY


class CommandHandler(Protocol):
    """What the daemon implements to obey the FC. Called on the link's reader thread.

    Keep each call short (hand the request to the frame loop as a value) and
    return a :class:`Reason`: ``Reason.OK`` for ACK, ``Reason.REJECTED`` to
    refuse. Values have already been range-checked against the ICD.
    """

    def set_mode(self, mode: Mode) -> Reason: ...

    def set_exposure(self, exposure_us: int) -> Reason: ...

    def set_gain(self, gain: float) -> Reason: ...

    def time_sync(self, offset_ns: int) -> Reason:
        """TAI (the FC's) = tracker monotonic clock + offset_ns (transmission time removed)."""

    def set_velocity(self, t_tai_ns: int, velocity_km_s: tuple[float, float, float]
                     ) -> Reason:
        """The observer's geocentric velocity (ICRS, km/s) holding at TAI ``t_tai_ns``."""

    def status(self) -> dict:
        """Every STATUS field except :data:`LINK_STATUS_FIELDS` (the link fills those in),
        for REQUEST_STATUS; complete from the service's start."""


class OutputGate:
    """Decides whether a telemetry message is due, given its output rate in Hz.

    :meth:`set_rate` may be called from another thread; a new rate makes the
    message due at once, then at the new rate.
    """

    def __init__(self, rates_hz: dict[int, float]) -> None:
        self.rates_hz = dict(rates_hz)
        self._next = dict.fromkeys(self.rates_hz, 0)
        self._lock = threading.Lock()

    def set_rate(self, msg_id: int, rate_hz: float) -> None:
        with self._lock:
            self.rates_hz[msg_id] = float(rate_hz)
            self._next[msg_id] = 0

    def due(self, msg_id: int, now_ns: int) -> bool:
        """True if msg_id should be sent at now_ns (and books it)."""
        with self._lock:
            rate = self.rates_hz[msg_id]
            if rate <= 0:
                return False
            period = int(1e9 / rate)
            nxt = self._next[msg_id]
            if now_ns < nxt - period // 20:          # 5 % early is on time (frame jitter)
                return False
            self._next[msg_id] = now_ns + period if now_ns > nxt + period else nxt + period
            return True


class _Queue:
    """Bounded queues, one per class; the oldest of a full class is dropped."""

    def __init__(self, capacities: tuple[int, ...]) -> None:
        self.q = [collections.deque() for _ in capacities]
        self.cap = capacities
        self.cond = threading.Condition()

    def put(self, cls: int, item) -> bool:
        """Queue item; False if that pushed out an older one."""
        with self.cond:
            q = self.q[cls]
            full = len(q) >= self.cap[cls]
            if full:
                q.popleft()
            q.append(item)
            self.cond.notify()
            return not full


class Link:
    """The tracker's end of the serial link; see the module docstring.

    Usage::

        with Link(cfg.link, handler) as link:
            link.send_attitude(frame_id=n, t_ns=t, q=q, sigma_cross_arcsec=5.0, ...)

    ``open_port`` (tests) replaces the pyserial opener; ``clock`` returns ns.
    """

    def __init__(self, cfg: LinkConfig, handler: CommandHandler | None = None, *,
                 open_port: Callable[[], serial.SerialBase] | None = None,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.cfg = cfg
        self.handler = handler
        self._open_port = open_port or self._open_serial
        self._clock = clock
        self.gate = OutputGate({MsgId.ATTITUDE: cfg.attitude_rate_hz,
                                MsgId.CENTROIDS: cfg.centroids_rate_hz,
                                MsgId.STATUS: cfg.status_rate_hz})
        self.rate_bytes_s = bytes_per_second(cfg.baudrate) * cfg.bandwidth_fraction
        self._queue = _Queue((cfg.queue_attitude, cfg.queue_replies, cfg.queue_centroids,
                              cfg.queue_status))
        self._encoder = Encoder(Direction.TM)
        self._enc_lock = threading.Lock()
        self._decoder = StreamDecoder(Direction.TC, validate=True, keep_rejects=True)
        self._port: serial.SerialBase | None = None
        self._port_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._rx_t_ns = 0
        self.latency = LatencyRing()
        self._byte_ns = BITS_PER_BYTE * 1e9 / cfg.baudrate
        self._failure: str | None = None
        self.counters: collections.Counter = collections.Counter()
        self._count_lock = threading.Lock()

    # ---- life cycle -------------------------------------------------------

    def start(self) -> Link:
        self._stop.clear()
        self._threads = [threading.Thread(target=self._guarded, args=(self._read_loop,),
                                          name="link-reader", daemon=True),
                         threading.Thread(target=self._guarded, args=(self._write_loop,),
                                          name="link-writer", daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def close(self, drain_s: float = 0.0) -> None:
        """Stop the threads (after up to drain_s seconds of sending what is queued)."""
        deadline = time.monotonic() + drain_s
        while time.monotonic() < deadline and any(self._queue.q) and self.failure is None:
            time.sleep(0.01)
        self._stop.set()
        with self._queue.cond:
            self._queue.cond.notify_all()
        for t in self._threads:
            t.join(timeout=2.0)
        with self._queue.cond:
            for name, q in zip(_CLASSES, self._queue.q, strict=True):
                self._count(f"unsent_{name}", len(q))
                q.clear()
        with self._port_lock:
            if self._port is not None:
                self._port.close()
                self._port = None

    def __enter__(self) -> Link:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._port is not None

    @property
    def failure(self) -> str | None:
        """Why the link can no longer serve the FC (a thread ended), or None."""
        if self._failure is None and not self._stop.is_set():
            dead = [t.name for t in self._threads if not t.is_alive()]
            if dead:
                return f"{', '.join(dead)} ended"
        return self._failure

    # ---- the frame loop's calls -------------------------------------------

    def send_attitude(self, *, frame_id: int, t_ns: int, q: np.ndarray | None,
                      sigma_cross_arcsec: float, sigma_roll_arcsec: float, matched: int,
                      mode: Mode, flags: int = 0, rate_dps: np.ndarray | None = None,
                      t_ref_ns: int | None = None) -> bool:
        """Queue ATTITUDE if due; True if queued.

        q = [w, x, y, z] (v_cam = R v_icrs) or None when there is no solution
        (sent as NaN, VALID clear). rate_dps (deg/s about camera X, Y, Z) or
        None (NaN, RATE_VALID clear). VALID and RATE_VALID are set from these;
        ``flags`` may add TIME_SYNCED, and to a VALID attitude ANNUAL_ABERRATION
        and OBSERVER_VELOCITY. Integers saturate at their wire type.
        ``t_ref_ns``: the frame's exposure mid-point on the link's clock; the
        packet's age (``max_age_ms``) and its latency run from it.
        """
        if not self.gate.due(MsgId.ATTITUDE, self._clock()):
            self._count("over_rate_attitude")   # a frame sooner than the output rate's period
            return False
        flags = int(flags) & _SENT_FLAGS
        if q is None:
            q = (_NAN,) * 4
            flags &= ~_CORRECTION_FLAGS
        else:
            flags |= AttitudeFlag.VALID
        if rate_dps is None:
            rate_dps = (_NAN,) * 3
        else:
            flags |= AttitudeFlag.RATE_VALID
        return self._put(MsgId.ATTITUDE, t_ref_ns=t_ref_ns, frame_id=frame_id, t_ns=t_ns,
                         q_w=q[0], q_x=q[1], q_y=q[2], q_z=q[3],
                         sigma_cross_arcsec=sigma_cross_arcsec,
                         sigma_roll_arcsec=sigma_roll_arcsec,
                         rate_x=rate_dps[0], rate_y=rate_dps[1], rate_z=rate_dps[2],
                         matched=matched, mode=int(mode), flags=flags)

    def send_centroids(self, frame_id: int, t_ns: int, stars: np.ndarray,
                       total: int | None = None) -> bool:
        """Queue CENTROIDS parts for the brightest ``max_centroids`` stars if due.

        stars: rows with fields x, y, flux, hip, flags (e.g. an array of
        ``BY_ID[MsgId.CENTROIDS].item_dtype``), in any order.
        """
        if not self.gate.due(MsgId.CENTROIDS, self._clock()):
            return False
        total = len(stars) if total is None else total
        stars = stars[np.argsort(-stars["flux"], kind="stable")[:self.cfg.max_centroids]]
        head = saturate(MsgId.CENTROIDS, {"frame_id": frame_id, "t_ns": t_ns})
        with self._enc_lock:
            packets = self._encoder.centroids(head["frame_id"], head["t_ns"], stars, total)
        now = self._clock()
        for packet in packets:
            self._enqueue(BY_ID[MsgId.CENTROIDS].priority, now, packet)
        return True

    def send_status(self, **values) -> bool:
        """Queue STATUS if due; values = the STATUS fields except :data:`LINK_STATUS_FIELDS`."""
        if not self.gate.due(MsgId.STATUS, self._clock()):
            return False
        return self._put_status(values)

    def stats(self) -> dict:
        """Counters: queued_/sent_/dropped_full_/dropped_stale_/dropped_write_/unsent_<class>
        (class: attitude, reply, centroids, status), over_rate_attitude (frames whose
        ATTITUDE the output rate held back), bytes_sent, port_errors, reopens,
        open_failures, commands, acks, nacks, internal_errors, rx_<decoder counter>."""
        with self._count_lock:
            out = dict(self.counters)
        out.update({f"rx_{k}": v for k, v in self._decoder.counters.items()})
        return out

    @property
    def drops(self) -> int:
        """Packets shed so far (telemetry and replies)."""
        with self._count_lock:
            return sum(v for k, v in self.counters.items() if k.startswith("dropped_"))

    @property
    def rx_rejects(self) -> int:
        """FC packets refused so far: implausible header, bad CRC, id, length, range."""
        return sum(self._decoder.counters[k] for k in _RX_REJECTS)

    # ---- internals ----------------------------------------------------------

    def _count(self, key: str, n: int = 1) -> None:
        with self._count_lock:
            self.counters[key] += n

    def _guarded(self, body: Callable[[], None]) -> None:
        """Run a thread's loop; record why it ended if it ends before close()."""
        try:
            body()
        except BaseException as exc:
            self._failure = f"{threading.current_thread().name}: {type(exc).__name__}: {exc}"
            log.critical("link thread ended: %s", self._failure, exc_info=exc)
            raise

    def _internal_error(self, what: str, exc: BaseException) -> None:
        self._count("internal_errors")
        if self.counters["internal_errors"] <= _LOGGED_ERRORS:
            log.error("link: %s failed: %s", what, exc, exc_info=exc)

    def _put_status(self, values: dict) -> bool:
        values = dict(values, link_drops=self.drops, link_reopens=self.counters["reopens"],
                      rx_rejects=self.rx_rejects)
        return self._put(MsgId.STATUS, **values)

    def _put(self, msg_id: MsgId, t_ref_ns: int | None = None, **values) -> bool:
        values = saturate(msg_id, values)
        with self._enc_lock:
            packet = self._encoder.encode(msg_id, **values)
        self._enqueue(BY_ID[msg_id].priority, self._clock(), packet, t_ref_ns)
        return True

    def _enqueue(self, cls: int, now_ns: int, packet: bytes, t_ref_ns: int | None = None
                 ) -> None:
        name = _CLASSES[cls]
        self._count(f"queued_{name}")
        if not self._queue.put(cls, (now_ns, packet, t_ref_ns)):
            self._count(f"dropped_full_{name}")

    def _on_wire_ns(self, port, packet: bytes) -> int:
        """When the last byte just written leaves: now plus the transmit queue's bytes."""
        try:
            queued = int(port.out_waiting)
        except (AttributeError, *_PORT_ERRORS):
            queued = len(packet)
        return self._clock() + round(queued * self._byte_ns)

    def _open_serial(self) -> serial.SerialBase:
        # exclusive: an flock on the device, so a second user (tracker selftest, a
        # terminal program) is refused with a clear error instead of stealing bytes
        return serial.serial_for_url(self.cfg.port, baudrate=self.cfg.baudrate,
                                     timeout=self.cfg.read_timeout_s,
                                     write_timeout=self.cfg.write_timeout_s, exclusive=True)

    def _port_failed(self, port: serial.SerialBase, exc: Exception) -> None:
        with self._port_lock:
            if self._port is not port:
                return
            self._port = None
        self._count("port_errors")
        log.warning("serial port %s failed: %s; reopening", self.cfg.port, exc)
        try:
            port.close()
        except _PORT_ERRORS:
            pass

    def _read_loop(self) -> None:
        backoff = self.cfg.reopen_backoff_s
        opened_before = False
        while not self._stop.is_set():
            port = self._port
            if port is None:
                try:
                    port = self._open_port()
                except _PORT_ERRORS as exc:
                    self._count("open_failures")
                    log.warning("cannot open %s: %s; retry in %.2f s", self.cfg.port, exc,
                                backoff)
                    self._stop.wait(backoff)
                    backoff = min(2 * backoff, self.cfg.reopen_backoff_max_s)
                    continue
                self._count("reopens", int(opened_before))
                opened_before = True
                backoff = self.cfg.reopen_backoff_s
                with self._port_lock:
                    self._port = port
            try:
                data = port.read(1)
                if data and port.in_waiting:
                    data += port.read(port.in_waiting)
            except _PORT_ERRORS as exc:
                self._port_failed(port, exc)
                continue
            if data:
                self._rx_t_ns = self._clock()
                try:
                    items = self._decoder.feed(data)
                except Exception as exc:      # the decoder never raises on bytes; a bug
                    self._internal_error("decoding", exc)
                    continue
                for item in items:
                    self._serve(item)

    def _serve(self, item: Packet | Rejection) -> None:
        """Answer one decoded packet; whatever fails here is counted, never fatal."""
        try:
            if isinstance(item, Rejection):
                self._reply(False, item.apid, item.seq, item.reason)
            else:
                self._obey(item)
        except Exception as exc:
            self._internal_error(f"serving {getattr(item, 'name', 'a rejected packet')}", exc)

    def _write_loop(self) -> None:
        burst = max(self.rate_bytes_s * 0.02, float(max(m.max_size for m in BY_ID.values())
                                                    + 12))
        tokens, last = burst, self._clock()
        max_age_ns = int(self.cfg.max_age_ms * 1e6)
        qs = self._queue
        while not self._stop.is_set():
            now = self._clock()
            tokens = min(burst, tokens + (now - last) * 1e-9 * self.rate_bytes_s)
            last = now
            with qs.cond:
                cls = next((k for k, q in enumerate(qs.q) if q), None)
                if cls is None:
                    qs.cond.wait(0.1)
                    continue
                t0, packet, t_ref = qs.q[cls][0]
                if cls != _REPLY and now - (t0 if t_ref is None else t_ref) > max_age_ns:
                    qs.q[cls].popleft()
                    self._count(f"dropped_stale_{_CLASSES[cls]}")
                    continue
                wait = (len(packet) - tokens) / self.rate_bytes_s
                port = self._port
                if wait <= 0 and port is not None:
                    qs.q[cls].popleft()
            if port is None:
                self._stop.wait(0.05)
                continue
            if wait > 0:
                time.sleep(min(wait, 0.05))
                continue
            try:
                port.write(packet)
            except _PORT_ERRORS as exc:   # SerialTimeoutException is a SerialException
                self._count(f"dropped_write_{_CLASSES[cls]}")
                self._port_failed(port, exc)
                continue
            if t_ref is not None:
                self.latency.add((self._on_wire_ns(port, packet) - t_ref) / 1e6)
            tokens -= len(packet)
            self._count(f"sent_{_CLASSES[cls]}")
            self._count("bytes_sent", len(packet))

    def _reply(self, ok: bool, cmd_id: int, seq: int, code: Reason) -> None:
        self._put(MsgId.ACK if ok else MsgId.NACK, cmd_id=cmd_id, cmd_seq=seq,
                  code=int(code), rx_t_ns=self._rx_t_ns)
        self._count("acks" if ok else "nacks")

    def _obey(self, packet: Packet) -> None:
        self._count("commands")
        try:
            code = Reason(self._apply(packet.id, packet.values, len(packet.wire)))
        except Exception as exc:   # a fault in the daemon's handler must not stop the link
            self._internal_error(f"command {packet.name}", exc)
            code = Reason.INTERNAL
        self._reply(code == Reason.OK, packet.id, packet.seq, code)
        if packet.id == MsgId.REQUEST_STATUS and code == Reason.OK:
            self._put_status(self.handler.status())

    def _apply(self, msg_id: int, v: dict, packet_len: int) -> Reason:
        if msg_id == MsgId.PING:
            return Reason.OK
        if msg_id == MsgId.SET_OUTPUT:
            self.gate.set_rate(MsgId(v["msg_id"]), v["rate_hz"])
            return Reason.OK
        h = self.handler
        if h is None:
            return Reason.REJECTED
        if msg_id == MsgId.REQUEST_STATUS:
            return Reason.OK
        if msg_id == MsgId.SET_MODE:
            return h.set_mode(Mode(v["mode"]))
        if msg_id == MsgId.SET_EXPOSURE:
            return h.set_exposure(v["exposure_us"])
        if msg_id == MsgId.SET_GAIN:
            return h.set_gain(v["gain"])
        if msg_id == MsgId.TIME_SYNC:
            # The packet's first byte left the FC one transmission time before its last arrived.
            sent_ns = self._rx_t_ns - round(packet_len * BITS_PER_BYTE * 1e9 / self.cfg.baudrate)
            return h.time_sync(v["fc_time_ns"] - sent_ns)
        if msg_id == MsgId.SET_VELOCITY:
            return h.set_velocity(v["t_ns"], (v["vx_km_s"], v["vy_km_s"], v["vz_km_s"]))
        return Reason.UNKNOWN_ID
