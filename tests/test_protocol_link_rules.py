"""The ICD's link rules (issue 10 items 3, 4, 5, 7, 10), over a real pseudo-terminal."""

import math
import os
import time
import tty
from dataclasses import replace

import numpy as np
import pytest

from tracker.astrometry.timescale import TAI_NS_MAX, TAI_NS_MIN
from tracker.config import LinkConfig
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.link import Link, OutputGate
from tracker.protocol.messages import BY_ID, AttitudeFlag, Direction, Mode, MsgId, Reason, saturate

STATUS = {
    "uptime_s": 7, "frame_rate_hz": 29.5, "exposure_us": 20000, "gain": 2.0,
    "cpu_temp_c": 51.5, "mode": Mode.TRACKING, "frames": 210, "capture_faults": 1,
    "solve_failures": 2, "last_error": 0, "config_crc": 0xDEADBEEF, "time_source": 1,
    "corrections": 3, "psf_fwhm_px": 2.75,
}


class Handler:
    """Accepts everything; ``broken`` names a method that raises instead."""

    def __init__(self, broken=None, status=None):
        self.broken = broken
        self._status = STATUS if status is None else status
        self.calls = []

    def _call(self, name, value):
        if name == self.broken:
            raise RuntimeError(f"{name} is broken")
        self.calls.append((name, value))
        return Reason.OK

    def set_mode(self, mode):
        return self._call("set_mode", mode)

    def set_exposure(self, exposure_us):
        return self._call("set_exposure", exposure_us)

    def set_gain(self, gain):
        return self._call("set_gain", gain)

    def time_sync(self, offset_ns):
        return self._call("time_sync", offset_ns)

    def set_velocity(self, t_tai_ns, velocity_km_s):
        return self._call("set_velocity", (t_tai_ns, velocity_km_s))

    def status(self):
        return self._status


@pytest.fixture(name="pty")
def fixture_pty():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    os.set_blocking(master, False)
    yield master, os.ttyname(slave)
    os.close(slave)
    os.close(master)


def _cfg(path, **kw):
    return replace(LinkConfig(port=path, baudrate=921600, attitude_rate_hz=100.0,
                              centroids_rate_hz=0.0, status_rate_hz=0.0,
                              reopen_backoff_s=0.01), **kw)


def _collect(fd, until, timeout=10.0):
    """Telemetry packets read from fd until ``until(packets)`` (or the timeout)."""
    decoder = StreamDecoder(Direction.TM)
    packets = []
    deadline = time.monotonic() + timeout
    while not until(packets) and time.monotonic() < deadline:
        try:
            packets.extend(decoder.feed(os.read(fd, 65536)))
        except BlockingIOError:
            time.sleep(0.005)
    return packets


def _open(link):
    deadline = time.monotonic() + 5
    while not link.is_open and time.monotonic() < deadline:
        time.sleep(0.005)
    assert link.is_open


def _replies(packets):
    return [p for p in packets if p.id in (MsgId.ACK, MsgId.NACK)]


def test_a_burst_of_100_commands_gets_100_replies_in_order(pty):
    """Item 7: one write of 100 commands; the old 16-deep reply queue dropped 84."""
    master, path = pty
    tc = Encoder(Direction.TC)
    kinds = [lambda: tc.encode(MsgId.PING),
             lambda: tc.encode(MsgId.SET_MODE, mode=Mode.TRACKING),
             lambda: tc.encode(MsgId.SET_GAIN, gain=20.0),            # out of range: NACK
             lambda: tc.encode(MsgId.SET_EXPOSURE, exposure_us=5000)]
    burst = [kinds[k % 4]() for k in range(100)]
    with Link(_cfg(path), Handler()) as link:
        _open(link)
        os.write(master, b"".join(burst))
        got = _collect(master, lambda ps: len(_replies(ps)) >= 100)
    replies = _replies(got)
    sent = StreamDecoder(Direction.TC, validate=False).feed(b"".join(burst))
    assert [(r.values["cmd_id"], r.values["cmd_seq"]) for r in replies] == \
        [(p.id, p.seq) for p in sent]
    assert [r.id for r in replies].count(MsgId.NACK) == 25


def test_a_handler_that_raises_gets_nack_internal_and_the_link_keeps_answering(pty):
    """Item 3: an exception while serving a command is caught, counted, answered."""
    master, path = pty
    tc = Encoder(Direction.TC)
    with Link(_cfg(path), Handler(broken="set_mode", status={})) as link:
        _open(link)
        os.write(master, tc.encode(MsgId.SET_MODE, mode=Mode.STANDBY))
        os.write(master, tc.encode(MsgId.REQUEST_STATUS))     # status() is incomplete: {}
        os.write(master, tc.encode(MsgId.PING))
        got = _collect(master, lambda ps: len(_replies(ps)) >= 3)
        stats = link.stats()
        assert link.failure is None
    codes = [(r.values["cmd_id"], Reason(r.values["code"])) for r in _replies(got)]
    assert codes == [(MsgId.SET_MODE, Reason.INTERNAL), (MsgId.REQUEST_STATUS, Reason.OK),
                     (MsgId.PING, Reason.OK)]
    assert stats["internal_errors"] == 2       # the handler's exception, the bad status


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_link_thread_that_ends_is_reported_as_the_link_failure(pty):
    _, path = pty
    link = Link(_cfg(path), Handler())
    def reader_ends():
        raise SystemExit("reader gone")

    link._read_loop = reader_ends
    link.start()
    deadline = time.monotonic() + 5
    while link.failure is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert "link-reader: SystemExit: reader gone" == link.failure
    link.close()


def test_time_sync_outside_1972_2200_tai_is_nacked_and_times_saturate(pty):
    """Item 4 (issue 14: TAI, 1972-2200): no TIME_SYNC or frame time can push t_ns out of u64;
    a SET_VELOCITY's time obeys the same range."""
    master, path = pty
    tc = Encoder(Direction.TC)
    handler = Handler()
    with Link(_cfg(path, queue_attitude=8), handler) as link:
        _open(link)
        for t in (2**64 - 1, 2**63, TAI_NS_MAX + 1, TAI_NS_MIN - 1, 0, TAI_NS_MAX, TAI_NS_MIN):
            os.write(master, tc.encode(MsgId.TIME_SYNC, fc_time_ns=t))
        os.write(master, tc.encode(MsgId.SET_VELOCITY, t_ns=TAI_NS_MIN - 1, vx_km_s=1.0,
                                   vy_km_s=2.0, vz_km_s=3.0))
        os.write(master, tc.encode(MsgId.SET_VELOCITY, t_ns=TAI_NS_MIN, vx_km_s=1.0,
                                   vy_km_s=2.0, vz_km_s=-200.0))
        os.write(master, tc.encode(MsgId.SET_VELOCITY, t_ns=TAI_NS_MIN, vx_km_s=1.0,
                                   vy_km_s=math.nan, vz_km_s=0.0))
        os.write(master, tc.encode(MsgId.SET_VELOCITY, t_ns=TAI_NS_MIN, vx_km_s=200.5,
                                   vy_km_s=0.0, vz_km_s=0.0))
        for k, t_ns in enumerate((-1, -(2**70), 2**64, 2**80, 12345)):
            link.gate.set_rate(MsgId.ATTITUDE, 100.0)          # due at once
            link.send_attitude(frame_id=k, t_ns=t_ns, q=None, sigma_cross_arcsec=math.nan,
                               sigma_roll_arcsec=math.nan, matched=70000, mode=Mode.TRACKING)
        got = _collect(master, lambda ps: len(ps) >= 16)
    codes = [Reason(r.values["code"]) for r in _replies(got)]
    bad, ok = Reason.OUT_OF_RANGE, Reason.OK
    assert codes == [bad, bad, bad, bad, bad, ok, ok, bad, ok, bad, bad]
    assert [c[0] for c in handler.calls] == ["time_sync", "time_sync", "set_velocity"]
    assert handler.calls[2][1] == (TAI_NS_MIN, (1.0, 2.0, -200.0))
    att = [p.values for p in got if p.id == MsgId.ATTITUDE]
    assert [a["t_ns"] for a in att] == [0, 0, 2**64 - 1, 2**64 - 1, 12345]
    assert {a["matched"] for a in att} == {0xFFFF}


def test_output_rate_changes_take_effect_at_once():
    """Item 5: 0.01 Hz then 30 Hz must not wait out the 100 s period of the low rate."""
    gate = OutputGate({MsgId.ATTITUDE: 30.0})
    t = 10**12
    assert gate.due(MsgId.ATTITUDE, t)
    gate.set_rate(MsgId.ATTITUDE, 0.01)
    assert gate.due(MsgId.ATTITUDE, t + 10**6)               # new rate: due at once
    assert not gate.due(MsgId.ATTITUDE, t + 50 * 10**9)      # then every 100 s
    gate.set_rate(MsgId.ATTITUDE, 30.0)
    assert gate.due(MsgId.ATTITUDE, t + 50 * 10**9 + 1)
    assert not gate.due(MsgId.ATTITUDE, t + 50 * 10**9 + 10**7)
    assert gate.due(MsgId.ATTITUDE, t + 50 * 10**9 + 34 * 10**6)


@pytest.mark.parametrize("rate_hz, valid", [(0.0, True), (0.01, True), (100.0, True),
                                            (1e-45, False), (0.009, False), (-0.0, True),
                                            (100.01, False), (math.nan, False),
                                            (math.inf, False), (-1.0, False)])
def test_set_output_rates_are_off_or_0_01_to_100_hz(rate_hz, valid):
    """Item 5: a subnormal rate (1e-45 Hz: ATTITUDE off for ever) is NACKed."""
    tc = Encoder(Direction.TC)
    dec = StreamDecoder(Direction.TC, keep_rejects=True)
    out = dec.feed(tc.encode(MsgId.SET_OUTPUT, msg_id=MsgId.ATTITUDE,
                             rate_hz=np.float32(rate_hz)))
    assert (getattr(out[0], "reason", Reason.OK) == Reason.OK) == valid


def test_status_counts_implausible_headers_and_saturates_counters(pty):
    """Item 10: rx_rejects includes bad headers; counters saturate, never wrap."""
    master, path = pty
    tc = Encoder(Direction.TC)
    bad_version = bytearray(tc.encode(MsgId.PING))
    bad_version[4] |= 0x20                                    # version 1: implausible
    with Link(_cfg(path, status_rate_hz=100.0), Handler()) as link:
        _open(link)
        os.write(master, bytes(bad_version) * 3 + tc.encode(MsgId.PING))
        _collect(master, lambda ps: len(_replies(ps)) >= 1)
        link.send_status(**dict(STATUS, frames=2**32 + 5, capture_faults=2**40,
                                uptime_s=-3))
        got = _collect(master, lambda ps: any(p.id == MsgId.STATUS for p in ps))
    status = next(p.values for p in got if p.id == MsgId.STATUS)
    assert status["rx_rejects"] == 3
    assert (status["frames"], status["capture_faults"]) == (2**32 - 1, 2**32 - 1)
    assert status["uptime_s"] == 0


def test_saturate_clamps_each_integer_to_its_wire_type():
    got = saturate(MsgId.STATUS, {"link_reopens": 70000, "mode": 9, "gain": -1.5,
                                  "frames": -7})
    assert got == {"link_reopens": 0xFFFF, "mode": 9, "gain": -1.5, "frames": 0}
    assert BY_ID[MsgId.STATUS].pack(saturate(MsgId.STATUS, dict(
        STATUS, frames=2**33, link_drops=1, link_reopens=2**20, rx_rejects=0)))


def test_only_advertised_attitude_flags_are_ever_sent(pty):
    """Item 10: PREDICTED was advertised and never set; every flag in the ICD is one the
    link can send, and a caller cannot set VALID/RATE_VALID or any other bit itself."""
    master, path = pty
    with Link(_cfg(path, queue_attitude=8), Handler()) as link:
        _open(link)
        for k, (q, rate) in enumerate(((None, None), ([1.0, 0, 0, 0], None),
                                       ([1.0, 0, 0, 0], [0.1, 0.2, 0.3]))):
            link.gate.set_rate(MsgId.ATTITUDE, 100.0)
            link.send_attitude(frame_id=k, t_ns=k, q=q, sigma_cross_arcsec=1.0,
                               sigma_roll_arcsec=1.0, matched=5, mode=Mode.TRACKING,
                               flags=0xFFFF, rate_dps=rate)
        got = _collect(master, lambda ps: len(ps) >= 3)
    flags = [p.values["flags"] for p in got]
    corrected = AttitudeFlag.ANNUAL_ABERRATION | AttitudeFlag.OBSERVER_VELOCITY
    # the aberration flags only with VALID: an attitude not solved was not corrected
    assert flags == [AttitudeFlag.TIME_SYNCED,
                     AttitudeFlag.TIME_SYNCED | AttitudeFlag.VALID | corrected,
                     AttitudeFlag.TIME_SYNCED | AttitudeFlag.VALID | AttitudeFlag.RATE_VALID
                     | corrected]
    assert {f.name for f in AttitudeFlag} == {"VALID", "RATE_VALID", "TIME_SYNCED",
                                              "ANNUAL_ABERRATION", "OBSERVER_VELOCITY"}


def test_attitude_ages_from_its_exposure_and_its_latency_is_measured_to_the_wire(pty):
    """An ATTITUDE older than max_age_ms since its exposure is shed; each one sent gets
    its latency, from the exposure to its last byte on the wire, at least its age."""
    master, path = pty
    cfg = _cfg(path, max_age_ms=200.0)
    with Link(cfg, Handler()) as link:
        _open(link)
        now = time.monotonic_ns()
        common = {"q": np.array([1.0, 0, 0, 0]), "sigma_cross_arcsec": 2.0,
                  "sigma_roll_arcsec": 20.0, "matched": 10, "mode": Mode.TRACKING}
        link.send_attitude(frame_id=1, t_ns=1, t_ref_ns=now - 300_000_000, **common)
        link.gate.set_rate(MsgId.ATTITUDE, 100.0)
        link.send_attitude(frame_id=2, t_ns=2, t_ref_ns=now - 50_000_000, **common)
        got = _collect(master, lambda ps: any(p.values["frame_id"] == 2 for p in ps))
        link.close(drain_s=0.0)
        stats = link.stats()
    assert [p.values["frame_id"] for p in got] == [2]
    assert stats["dropped_stale_attitude"] == 1 and stats["sent_attitude"] == 1
    assert link.latency.count == 1 and link.latency.percentiles()["max"] >= 50.0


def test_an_attitude_sooner_than_the_output_rate_allows_is_counted_as_held_back(pty):
    """At 30 Hz, a frame 10 ms after the last (a late frame, then the next on time) sends
    no ATTITUDE, and the link counts it, so every frame's ATTITUDE is accounted for."""
    master, path = pty
    now = [10**12]
    with Link(_cfg(path, queue_attitude=8, attitude_rate_hz=30.0), Handler(),
              clock=lambda: now[0]) as link:
        common = {"q": None, "sigma_cross_arcsec": 2.0, "sigma_roll_arcsec": 20.0,
                  "matched": 0, "mode": Mode.LOST_IN_SPACE}
        sent = []
        for k, dt_ms in enumerate((0, 10, 40, 100)):
            now[0] += dt_ms * 10**6
            sent.append(link.send_attitude(frame_id=k, t_ns=k, t_ref_ns=now[0], **common))
        stats = link.stats()
    assert sent == [True, False, True, True]
    assert stats["over_rate_attitude"] == 1 and stats["queued_attitude"] == 3
