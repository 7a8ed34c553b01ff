"""The daemon talking to a flight computer over a pseudo-terminal, decoded per the ICD."""

import dataclasses
import os
import pty
import threading
import time
import tty

import numpy as np
import pytest
from daemon_fakes import FakeSource, paced_frames

from tracker.astrometry.observer import Correction, TimeSource
from tracker.capture.base import Frame
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.daemon.notify import Notifier
from tracker.detect import STAR_DTYPE, Detections
from tracker.pipeline import FrameResult
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.framing import crc16
from tracker.protocol.messages import AttitudeFlag, Direction, ErrorCode, Mode, MsgId, Reason


class Solution:
    ok = True
    q = np.array([0.5, 0.5, 0.5, 0.5])
    sigma_cross_arcsec, sigma_roll_arcsec, matched = 4.0, 30.0, 12
    rate_rad_s = None
    hip = np.array([11767, 0, 32349])


class Pipeline:
    def __init__(self):
        self.resets = 0

    def reset(self):
        self.resets += 1

    def process(self, image, bit_depth, t_ns, observer, exposure_s=None):
        stars = np.zeros(3, STAR_DTYPE)
        stars["x"], stars["flux"] = [1.0, 2.0, 3.0], [30.0, 20.0, 10.0]
        return FrameResult(Detections(stars), Solution(), 1.0, {}, None, observer)


def read_packets(fd, decoder, until, timeout=5.0):
    """Decode TM from the master side until ``until(packets)`` or the timeout."""
    packets = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not until(packets):
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            time.sleep(0.01)
            continue
        packets.extend(decoder.feed(data))
    return packets


@pytest.fixture(name="fc")
def fixture_fc():
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    yield master, os.ttyname(slave)
    os.close(master)
    os.close(slave)


def test_fc_commands_garbage_and_telemetry(fc):
    master, port = fc
    cfg = Config()
    cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, port=port,
                                                            centroids_rate_hz=50.0),
                              service=dataclasses.replace(cfg.service, watchdog_s=0.0))
    pipeline = Pipeline()
    svc = Daemon(cfg, source_factory=paced_frames, pipeline=pipeline, link=DaemonLink(cfg),
                 notifier=Notifier(""))
    runner = threading.Thread(target=svc.run)
    runner.start()
    try:
        decoder = StreamDecoder(Direction.TM)
        att = read_packets(master, decoder,
                           lambda ps: sum(p.id == MsgId.ATTITUDE for p in ps) >= 3)
        att = [p for p in att if p.id == MsgId.ATTITUDE]
        assert len(att) >= 3
        v = att[-1].values
        assert np.allclose([v["q_w"], v["q_x"], v["q_y"], v["q_z"]], 0.5)
        assert v["flags"] & AttitudeFlag.VALID and v["matched"] == 12
        assert v["mode"] == Mode.TRACKING            # solved twice in a row: tracking

        fc_enc = Encoder(Direction.TC)
        bad = bytearray(fc_enc.encode(MsgId.PING))
        bad[-1] ^= 0xFF                                # CRC broken: NACKed, counted
        os.write(master, os.urandom(200) + bytes(bad)
                 + fc_enc.encode(MsgId.SET_MODE, mode=Mode.STANDBY))
        replies = read_packets(master, decoder, lambda ps: any(p.id == MsgId.ACK for p in ps))
        assert any(p.id == MsgId.NACK for p in replies)
        ack = next(p for p in replies if p.id == MsgId.ACK)
        assert ack.values["cmd_id"] == MsgId.SET_MODE
        deadline = time.monotonic() + 5
        while svc.mode != Mode.STANDBY and time.monotonic() < deadline:
            time.sleep(0.01)
        assert svc.mode == Mode.STANDBY
        assert svc.health.faults[ErrorCode.RX_REJECT] >= 1

        os.write(master, fc_enc.encode(MsgId.SET_EXPOSURE, exposure_us=1500))
        deadline = time.monotonic() + 5
        while svc.exposure.exposure_us != 1500.0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert svc.exposure.exposure_us == 1500.0 and not svc.exposure.auto

        # LOST_IN_SPACE drops the tracking lock; FAULT can be reported, never commanded
        os.write(master, fc_enc.encode(MsgId.SET_MODE, mode=Mode.LOST_IN_SPACE))
        frame = bytearray(fc_enc.encode(MsgId.SET_MODE, mode=Mode.LOST_IN_SPACE))
        frame[10] = Mode.FAULT                     # payload byte after ASM + header
        body = bytes(frame[4:-2])
        frame[-2:] = crc16(body).to_bytes(2, "big")
        os.write(master, bytes(frame))
        replies = read_packets(master, decoder, lambda ps: any(p.id == MsgId.NACK for p in ps))
        nack = next(p for p in replies if p.id == MsgId.NACK)
        assert nack.values["cmd_id"] == MsgId.SET_MODE
        assert nack.values["code"] == Reason.OUT_OF_RANGE
        deadline = time.monotonic() + 5
        while pipeline.resets == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert pipeline.resets == 1 and svc.mode != Mode.STANDBY
    finally:
        svc.request_stop()
        runner.join(timeout=10)
    assert not runner.is_alive()


def test_time_sync_and_set_velocity_reach_the_solver_and_the_fc_sees_tai(fc):
    """Issue 14: after TIME_SYNC, t_ns is TAI (TIME_SYNCED) and the solver gets the frame's
    absolute time; with SET_VELOCITY also the velocity; ATTITUDE and STATUS say what was
    corrected. Before the sync: the monotonic clock and no correction."""
    master, port = fc
    cfg = Config()
    cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, port=port,
                                                            status_rate_hz=20.0),
                              service=dataclasses.replace(cfg.service, watchdog_s=0.0))

    class Recording(Pipeline):
        observers = []

        def process(self, image, bit_depth, t_ns, observer, exposure_s=None):
            self.observers.append((t_ns, observer))
            return super().process(image, bit_depth, t_ns, observer)

    def frames():
        i = 0
        while True:
            time.sleep(0.005)
            yield Frame(i, f"f{i}", np.zeros((8, 8), np.uint16), 10, time.monotonic_ns())
            i += 1

    pipeline = Recording()
    svc = Daemon(cfg, source_factory=lambda: FakeSource(frames()), pipeline=pipeline,
                 link=DaemonLink(cfg), notifier=Notifier(""))
    runner = threading.Thread(target=svc.run)
    runner.start()
    fc_enc = Encoder(Direction.TC)
    decoder = StreamDecoder(Direction.TM)
    try:
        got = read_packets(master, decoder, lambda ps: sum(p.id == MsgId.STATUS
                                                          for p in ps) >= 2)
        before = [p.values for p in got if p.id == MsgId.ATTITUDE][-1]
        assert before["flags"] == AttitudeFlag.VALID and before["t_ns"] < 10**18
        status = [p.values for p in got if p.id == MsgId.STATUS][-1]
        assert (status["time_source"], status["corrections"]) == (TimeSource.NONE, 0)

        tai_now = 1_805_000_000 * 10**9                   # 2027-03-14, TAI
        os.write(master, fc_enc.encode(MsgId.TIME_SYNC, fc_time_ns=tai_now))
        synced_at = time.monotonic_ns()
        os.write(master, fc_enc.encode(MsgId.SET_VELOCITY, t_ns=tai_now, vx_km_s=-7.5,
                                       vy_km_s=0.25, vz_km_s=1.0))
        replies = read_packets(master, decoder,
                               lambda ps: sum(p.id == MsgId.ACK for p in ps) >= 2)
        n = len(replies)
        got = replies + read_packets(
            master, decoder, lambda ps: sum(p.id == MsgId.STATUS for p in ps) >= 2
            and sum(p.id == MsgId.ATTITUDE for p in ps) >= 5)
        att = [p.values for p in got[n:] if p.id == MsgId.ATTITUDE][-1]
        both = (AttitudeFlag.VALID | AttitudeFlag.TIME_SYNCED | AttitudeFlag.ANNUAL_ABERRATION
                | AttitudeFlag.OBSERVER_VELOCITY)
        assert att["flags"] == both
        # TAI of a frame exposed after the sync: the sync's time plus the time since, to
        # within the read latency and the 20-byte packet's 0.2 ms on the wire
        assert 0 < att["t_ns"] - tai_now < time.monotonic_ns() - synced_at + 10**8
        status = [p.values for p in got[n:] if p.id == MsgId.STATUS][-1]
        assert status["time_source"] == TimeSource.TIME_SYNC
        assert status["corrections"] == Correction.ANNUAL_ABERRATION | \
            Correction.OBSERVER_VELOCITY
        t_ns, observer = pipeline.observers[-1]
        assert observer.velocity_km_s == (-7.5, 0.25, 1.0)
        # the sync's offset: TAI at the write less the reader's latency, plus the wire time the
        # link subtracts (a pty has none), so either sign, within the read latency
        assert abs(observer.t_tai_ns - t_ns - (tai_now - synced_at)) < 10**8
    finally:
        svc.request_stop()
        runner.join(timeout=10)
    assert not runner.is_alive()


def test_status_carries_the_psf_the_detector_measured(fc):
    """Issue 12: STATUS psf_fwhm_px is the FWHM the real detector measures on the frames
    (here rendered at sigma 1.7 px, FWHM 4.00 px), NaN before the first frame."""
    from tracker.config import SimConfig
    from tracker.pipeline import Pipeline as RealPipeline
    from tracker.sim import render_points

    master, port = fc
    cfg = Config()
    cfg = dataclasses.replace(
        cfg, link=dataclasses.replace(cfg.link, port=port, status_rate_hz=20.0),
        identify=dataclasses.replace(cfg.identify, enabled=False),
        service=dataclasses.replace(cfg.service, watchdog_s=0.0))
    sim = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    rng = np.random.default_rng(5)
    xs, ys = rng.uniform(20, 380, 40), rng.uniform(20, 380, 40)
    image = render_points((400, 400), xs, ys, np.full(40, 4000.0), sim, rng,
                          noise_model="realistic", psf_sigma_px=1.7).image

    def frames():
        i = 0
        while True:
            time.sleep(0.02)
            yield Frame(i, f"f{i}", image, 10, time.monotonic_ns())
            i += 1

    svc = Daemon(cfg, source_factory=lambda: FakeSource(frames()), pipeline=RealPipeline(cfg),
                 link=DaemonLink(cfg), notifier=Notifier(""))
    assert np.isnan(svc._snapshot().psf_fwhm_px)
    runner = threading.Thread(target=svc.run)
    runner.start()
    try:
        decoder = StreamDecoder(Direction.TM)
        got = read_packets(master, decoder, lambda ps: any(
            p.id == MsgId.STATUS and np.isfinite(p.values["psf_fwhm_px"]) for p in ps),
            timeout=30.0)
        fwhm = [p.values["psf_fwhm_px"] for p in got
                if p.id == MsgId.STATUS and np.isfinite(p.values["psf_fwhm_px"])]
        assert fwhm and fwhm[-1] == pytest.approx(2.3548 * 1.7, rel=0.05)
    finally:
        svc.request_stop()
        runner.join(timeout=10)
    assert not runner.is_alive()
