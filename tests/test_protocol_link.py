"""The link over a real pseudo-terminal: telemetry, commands, priorities, reopening."""

import math
import os
import threading
import time
import tty
from dataclasses import replace

import numpy as np
import pytest
import serial
from icd_reference_decoder import decode_telemetry

from tracker.cli import main
from tracker.config import LinkConfig
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.framing import crc16
from tracker.protocol.link import Link
from tracker.protocol.messages import BY_ID, Direction, Mode, MsgId, Reason
from tracker.protocol.nullmodem import NullModem

STATUS = {
    "uptime_s": 7, "frame_rate_hz": 29.5, "exposure_us": 20000, "gain": 2.0,
    "cpu_temp_c": 51.5, "mode": Mode.TRACKING, "frames": 210, "capture_faults": 1,
    "solve_failures": 2, "last_error": 0, "config_crc": 0xDEADBEEF, "time_source": 2,
    "corrections": 1, "psf_fwhm_px": 2.75,
}


class RecordingHandler:
    """The service's side, recording every call."""

    def __init__(self):
        self.calls = []

    def set_mode(self, mode):
        self.calls.append(("set_mode", mode))
        return Reason.OK

    def set_exposure(self, exposure_us):
        self.calls.append(("set_exposure", exposure_us))
        return Reason.OK

    def set_gain(self, gain):
        self.calls.append(("set_gain", gain))
        return Reason.REJECTED

    def time_sync(self, offset_ns):
        self.calls.append(("time_sync", offset_ns))
        return Reason.OK

    def set_velocity(self, t_tai_ns, velocity_km_s):
        self.calls.append(("set_velocity", (t_tai_ns, velocity_km_s)))
        return Reason.OK

    def status(self):
        return STATUS


@pytest.fixture(name="pty")
def fixture_pty():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    os.close(slave)
    os.close(master)


def _read_for(fd, seconds):
    data, end = b"", time.monotonic() + seconds
    os.set_blocking(fd, False)
    while time.monotonic() < end:
        try:
            data += os.read(fd, 65536)
        except BlockingIOError:
            time.sleep(0.01)
    return data


def _wait_open(link, seconds=5.0):
    deadline = time.monotonic() + seconds
    while not link.is_open and time.monotonic() < deadline:
        time.sleep(0.01)
    assert link.is_open


def _cfg(path, **kw):
    base = LinkConfig(port=path, baudrate=921600, attitude_rate_hz=100.0,
                      centroids_rate_hz=100.0, status_rate_hz=100.0, reopen_backoff_s=0.01)
    return replace(base, **kw)


def test_telemetry_through_pyserial_decodes_the_same_in_both_decoders(pty):
    master, path = pty
    rng = np.random.default_rng(5)
    stars = np.zeros(55, dtype=BY_ID[MsgId.CENTROIDS].item_dtype)
    stars["x"], stars["y"] = rng.uniform(0, 1600, 55), rng.uniform(0, 1300, 55)
    stars["flux"] = rng.permutation(55) + 100.0
    stars["hip"] = rng.integers(0, 120000, 55)
    with Link(_cfg(path, max_centroids=50, queue_status=8)) as link:
        for k in range(3):
            assert link.send_attitude(frame_id=k, t_ns=10**12 + k, q=[0.5, 0.5, -0.5, 0.5],
                                      sigma_cross_arcsec=4.5, sigma_roll_arcsec=31.0, matched=14,
                                      mode=Mode.TRACKING, rate_dps=[0.1, -0.2, 0.3])
            link.send_centroids(k, 10**12 + k, stars)
            link.send_status(**STATUS)
            time.sleep(0.012)
        link.send_attitude(frame_id=9, t_ns=1, q=None, sigma_cross_arcsec=math.nan,
                           sigma_roll_arcsec=math.nan, matched=0, mode=Mode.LOST_IN_SPACE)
        data = _read_for(master, 0.4)
    ours = StreamDecoder(Direction.TM).feed(data)
    ref = decode_telemetry(data)
    assert [p.name for p in ours].count("CENTROIDS") == 6      # 50 stars = 40 + 10, x3
    assert len(ours) == len(ref) == 3 * 4 + 1
    for p, r in zip(ours, ref, strict=True):
        assert (p.id, p.seq, p.wire[10:-2]) == (r["apid"], r["seq"], r["payload"])
        for k, v in r["values"].items():
            assert p.values[k] == v or (math.isnan(v) and math.isnan(p.values[k]))
        if p.id == MsgId.CENTROIDS:
            assert [tuple(row) for row in p.items] == [tuple(i.values()) for i in r["items"]]
    atts = [p.values for p in ours if p.name == "ATTITUDE"]
    att, last = atts[0], atts[-1]
    assert att["flags"] == 3 and att["rate_z"] == pytest.approx(0.3, abs=1e-7)
    first = [p for p in ours if p.name == "CENTROIDS"][:2]
    sent = np.concatenate([p.items for p in first])
    assert sent["flux"].tolist() == sorted(stars["flux"], reverse=True)[:50]  # brightest first
    assert first[0].values["total"] == 55
    assert last["flags"] == 0 and math.isnan(last["q_w"])


def _commands():
    tc = Encoder(Direction.TC)
    bad_crc = bytearray(tc.encode(MsgId.SET_MODE, mode=Mode.STANDBY))
    bad_crc[-2] ^= 0x40
    unknown = bytearray(tc.encode(MsgId.PING))
    unknown[5] = 0x7E                                       # APID 0x07E: no such command
    unknown[-2:] = crc16(bytes(unknown[4:-2])).to_bytes(2, "big")
    short = bytearray(tc.encode(MsgId.SET_EXPOSURE, exposure_us=5000))
    del short[13]                                            # 3-byte payload, length fixed
    short[9] -= 1
    short[-2:] = crc16(bytes(short[4:-2])).to_bytes(2, "big")
    return [
        (bytes(bad_crc), MsgId.NACK, Reason.BAD_CRC),
        (bytes(unknown), MsgId.NACK, Reason.UNKNOWN_ID),
        (bytes(short), MsgId.NACK, Reason.WRONG_LENGTH),
        (tc.encode(MsgId.SET_EXPOSURE, exposure_us=2_000_000), MsgId.NACK, Reason.OUT_OF_RANGE),
        (tc.encode(MsgId.SET_GAIN, gain=math.nan), MsgId.NACK, Reason.OUT_OF_RANGE),
        (tc.encode(MsgId.SET_MODE, mode=3), MsgId.NACK, Reason.OUT_OF_RANGE),
        (tc.encode(MsgId.SET_OUTPUT, msg_id=MsgId.ACK, rate_hz=1.0), MsgId.NACK,
         Reason.OUT_OF_RANGE),
        (tc.encode(MsgId.PING), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.SET_MODE, mode=Mode.TRACKING), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.SET_EXPOSURE, exposure_us=15000), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.SET_GAIN, gain=4.0), MsgId.NACK, Reason.REJECTED),
        (tc.encode(MsgId.SET_OUTPUT, msg_id=MsgId.STATUS, rate_hz=0.0), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.TIME_SYNC, fc_time_ns=5 * 10**18), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.SET_VELOCITY, t_ns=1_800_000_000 * 10**9, vx_km_s=-7.5, vy_km_s=0.25,
                   vz_km_s=1.0), MsgId.ACK, Reason.OK),
        (tc.encode(MsgId.REQUEST_STATUS), MsgId.ACK, Reason.OK),
    ]


def test_every_command_gets_the_right_ack_or_nack_and_bad_ones_change_nothing(pty):
    master, path = pty
    handler = RecordingHandler()
    cmds = _commands()
    with Link(_cfg(path, status_rate_hz=5.0), handler) as link:
        _wait_open(link)   # pyserial flushes the input when it opens the port
        for frame, _, _ in cmds:
            os.write(master, frame)
            time.sleep(0.01)
        data = _read_for(master, 0.3)
        rates = dict(link.gate.rates_hz)
    replies = list(StreamDecoder(Direction.TM).feed(data))
    assert [(p.id, Reason(p.values["code"])) for p in replies[:-1]] == \
        [(kind, code) for _, kind, code in cmds]
    assert replies[0].values["cmd_id"] == MsgId.SET_MODE
    assert replies[1].values["cmd_id"] == 0x07E
    assert replies[-1].name == "STATUS" and replies[-1].values["config_crc"] == 0xDEADBEEF
    assert replies[-1].values["rx_rejects"] == 7
    # Only the valid commands reached the service, in order.
    names = [c[0] for c in handler.calls]
    assert names == ["set_mode", "set_exposure", "set_gain", "time_sync", "set_velocity"]
    assert handler.calls[4][1] == (1_800_000_000 * 10**9, (-7.5, 0.25, 1.0))
    assert handler.calls[0][1] == Mode.TRACKING and handler.calls[1][1] == 15000
    # FC clock minus tracker clock: 5e18 minus a monotonic time that is << 1e18.
    assert 4 * 10**18 < handler.calls[3][1] < 5 * 10**18
    assert rates[MsgId.STATUS] == 0.0 and rates[MsgId.ATTITUDE] == 100.0


def test_when_the_uart_is_too_slow_attitude_goes_first_and_oldest_are_dropped(pty):
    master, path = pty
    cfg = _cfg(path, baudrate=9600, queue_attitude=4, queue_centroids=2, queue_status=2,
               max_age_ms=60000.0)
    link = Link(cfg)
    stars = np.zeros(10, dtype=BY_ID[MsgId.CENTROIDS].item_dtype)
    for k in range(6):     # queued before the writer starts: it finds them all waiting
        link.send_status(**STATUS)
        link.send_centroids(k, k, stars)
        link.send_attitude(frame_id=k, t_ns=k, q=[1, 0, 0, 0], sigma_cross_arcsec=1.0,
                           sigma_roll_arcsec=1.0, matched=5, mode=Mode.TRACKING)
        time.sleep(0.011)
    link.start()
    data = _read_for(master, 1.2)   # 9600 baud: 864 B/s, about 1000 B in 1.2 s
    link.close()
    got = StreamDecoder(Direction.TM).feed(data)
    assert [p.name for p in got][:6] == ["ATTITUDE"] * 4 + ["CENTROIDS"] * 2
    assert [p.values["frame_id"] for p in got[:6]] == [2, 3, 4, 5, 4, 5]  # the newest kept
    s = link.stats()
    assert (s["dropped_full_attitude"], s["dropped_full_centroids"],
            s["dropped_full_status"]) == (2, 4, 4)


def test_a_port_that_fails_is_reopened_with_backoff(pty):
    master, path = pty
    attempts = []

    def flaky_open():
        attempts.append(time.monotonic())
        if len(attempts) < 3:
            raise serial.SerialException("not yet")
        return serial.Serial(path, baudrate=921600, timeout=0.02)

    link = Link(_cfg(path), open_port=flaky_open).start()
    _wait_open(link)
    assert link.stats()["open_failures"] == 2
    assert attempts[2] - attempts[1] >= 0.02 - 1e-3           # backoff doubled: 0.01, 0.02
    link._port.close()                                        # the device goes away
    deadline = time.monotonic() + 2
    while link.stats().get("reopens", 0) < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    link.send_attitude(frame_id=1, t_ns=1, q=[1, 0, 0, 0], sigma_cross_arcsec=1.0,
                       sigma_roll_arcsec=1.0, matched=5, mode=Mode.TRACKING)
    data = _read_for(master, 0.2)
    link.close()
    assert link.stats()["reopens"] == 1 and link.stats()["port_errors"] == 1
    assert [p.name for p in StreamDecoder().feed(data)] == ["ATTITUDE"]


@pytest.fixture(name="null_modem")
def fixture_null_modem():
    """Two pseudo-terminals joined master to master: (tracker's path, FC's path)."""
    with NullModem() as ports:
        yield ports


def test_monitor_prints_attitude_as_ra_dec_roll_and_its_ping_is_acked(null_modem, tmp_path,
                                                                       capsys):
    tracker_path, fc_path = null_modem
    link = Link(_cfg(tracker_path, status_rate_hz=0.0), RecordingHandler()).start()
    _wait_open(link)
    stop = threading.Event()

    def produce():
        k = 0
        while not stop.is_set():
            # RA 90, Dec 0, roll 0: boresight +Y of ICRS (q from tracker.attitude).
            link.send_attitude(frame_id=k, t_ns=k, q=[0.7071068, 0.7071068, 0.0, 0.0],
                               sigma_cross_arcsec=4.0, sigma_roll_arcsec=30.0, matched=9,
                               mode=Mode.TRACKING)
            k += 1
            time.sleep(0.02)

    producer = threading.Thread(target=produce, daemon=True)
    producer.start()
    try:
        rc = main(["monitor", fc_path, "--send", "ping", "--count", "6",
                   "--duration", "5", "--log", str(tmp_path / "log.jsonl")])
    finally:
        stop.set()
        producer.join()
        link.close()
    out = capsys.readouterr().out
    assert rc == 0
    assert "ACK" in out and "PING seq 0  OK" in out
    line = next(x for x in out.splitlines() if x.startswith("ATTITUDE"))
    assert "RA   90.0000 Dec  +0.0000" in line and "TRACKING" in line
    assert (tmp_path / "log.jsonl").read_text().count('"name": "ATTITUDE"') >= 4


def test_monitor_refuses_an_unknown_command():
    assert main(["monitor", "loop://", "--send", "launch"]) == 2
