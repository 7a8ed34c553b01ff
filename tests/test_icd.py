"""The interface control document's own numbers, checked (issue 14 item 5).

docs/protocol.md is read as an FC engineer reads it: the worked example of
R(q) (section 2.1) is recomputed from its quaternion; the test vectors
(section 5.3) are decoded by the C decoder compiled with gcc, by the Python
decoder and by a decoder written from the document alone, and re-encoded by
the tracker's encoder; the C command example (tools/fc/st_command.c) gets
its ACK and NACK from the daemon over a pseudo-terminal.
"""

import math
import re
import subprocess
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from daemon_fakes import FakePipeline
from fc_build import FC, GCC, build, needs_gcc, python_lines, same_word
from icd_reference_decoder import decode_telemetry

from tracker.astrometry.observer import TimeSource
from tracker.attitude import matrix_from_quat, radec_roll_from_matrix
from tracker.capture.live import CameraError
from tracker.commands.monitor import host_tai_ns
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.daemon.notify import Notifier
from tracker.protocol.framing import build_packet
from tracker.protocol.messages import BY_ID, MsgId, Reason
from tracker.protocol.nullmodem import NullModem
from tracker.sim.sequence import attitude_at

ICD = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text()
F32 = {f.name for m in BY_ID.values() for f in (*m.fields, *m.item) if f.type == "f32"}


def _number(pattern: str) -> float:
    return float(re.search(pattern, ICD).group(1))


def test_the_worked_example_of_r_q_recomputes_from_its_quaternion():
    q = [float(v) for v in re.search(r"q = \[(0\.[^\]]+)\]", ICD).group(1).split(",")]
    block = ICD[ICD.index("R = |"):]
    rows = [[float(v) for v in re.findall(r"[+-]\d\.\d{6}", line)]
            for line in block.splitlines()[:3]]
    R = matrix_from_quat(q)
    np.testing.assert_allclose(R, rows, atol=6e-7)
    entry = {name: _number(rf"{name} = [^=]+= ([+-]\d\.\d{{6}})")
             for name in ("R31", "R32", "R33", "R13", "R23")}
    for name, value in entry.items():
        assert R[int(name[1]) - 1, int(name[2]) - 1] == pytest.approx(value, abs=6e-7)
    ra, dec, roll = np.degrees(radec_roll_from_matrix(R))
    assert (ra, dec, roll) == pytest.approx((_number(r"RA   = .*= ([\d.+-]+) deg"),
                                             _number(r"Dec  = .*= ([\d.+-]+) deg"),
                                             _number(r"roll = .*= ([\d.+-]+) deg")), abs=6e-5)
    # the formulas as written give the same angles
    assert math.degrees(math.atan2(entry["R32"], entry["R31"])) == pytest.approx(ra, abs=1e-4)
    assert math.degrees(math.asin(entry["R33"])) == pytest.approx(dec, abs=1e-4)
    assert math.degrees(math.atan2(-entry["R13"], -entry["R23"])) == pytest.approx(roll,
                                                                                   abs=1e-4)


def test_a_positive_rate_y_turns_the_boresight_toward_plus_x():
    """Section 2.2: rate_y > 0 moves stars toward smaller x, by about rate_y * f px/s."""
    R0 = np.eye(3)
    star = R0[2]                                         # on the boresight at t = 0
    rate = np.radians([0.0, 0.5, 0.0])
    v = attitude_at(R0, rate, 1.0) @ star
    f_px = 5333.3
    assert f_px * v[0] / v[2] == pytest.approx(-f_px * rate[1], rel=1e-4)


def _vectors() -> list[tuple[bytes, str]]:
    """(bytes, the st_dump line) of each test vector of section 5.3."""
    part = ICD[ICD.index("<!-- test-vectors:start -->"):ICD.index("<!-- test-vectors:end -->")]
    out = []
    for block in re.findall(r"```text\n(.*?)```", part, re.S):
        lines = block.strip().splitlines()
        data = bytes.fromhex(" ".join(line for line in lines if not line.startswith("->")))
        out.append((data, next(line[3:] for line in lines if line.startswith("-> "))))
    return out


def test_the_vectors_are_attitude_centroids_and_status():
    assert [line.split()[1] for _, line in _vectors()] == ["ATTITUDE", "CENTROIDS", "STATUS"]


@pytest.mark.parametrize("index", [0, 1, 2], ids=["ATTITUDE", "CENTROIDS", "STATUS"])
def test_a_vector_decodes_in_python_and_re_encodes_to_the_same_bytes(index):
    data, line = _vectors()[index]
    want = line.split()
    (got,) = python_lines(data)
    assert got[:2] == want[:2] and len(got) == len(want)
    for py_word, doc_word in zip(got[2:], want[2:], strict=True):
        assert same_word(doc_word, py_word, doc_word.split("=")[0].split("[")[0] in F32)
    # the decoder written from the document alone agrees
    (ref,) = decode_telemetry(data)
    words = dict(w.split("=") for w in want[2:] if "[" not in w)
    for name, value in ref["values"].items():
        assert (np.float32(value) == np.float32(float(words[name])) if name in F32
                else value == int(words[name])), name
    # and the tracker's encoder makes the same bytes from the values
    msg = BY_ID[MsgId[want[1]]]
    values = {k: float(v) if k in F32 else int(v) for k, v in words.items()}
    items = None
    if msg.item:
        items = np.zeros(values["count"], msg.item_dtype)
        for w in want[2:]:
            if "[" in w:
                name, k, v = re.match(r"(\w+)\[(\d+)\]=(.*)", w).groups()
                items[name][int(k)] = float(v) if name in F32 else int(v)
    assert build_packet(msg.id, False, int(want[0]), msg.pack(values, items)) == data


@needs_gcc
def test_the_vectors_decode_in_c_exactly_as_the_icd_prints_them(tmp_path):
    st_dump = build(tmp_path, "st_dump", FC / "st_dump.c", FC / "st_decoder.c")
    vectors = _vectors()
    run = subprocess.run([str(st_dump)], input=b"".join(d for d, _ in vectors),
                         capture_output=True, check=True)
    lines = run.stdout.decode().splitlines()
    assert lines[:-1] == [line for _, line in vectors]
    assert lines[-1].startswith("COUNTERS packets=3 bad_header=0 bad_crc=0 unknown_id=0")


@pytest.fixture(name="st_command", scope="module")
def fixture_st_command(tmp_path_factory):
    if GCC is None:
        pytest.skip("gcc not found: the FC's C code cannot be compiled here")
    return build(tmp_path_factory.mktemp("fc"), "st_command", FC / "st_command.c",
                 FC / "st_decoder.c")


def _run(st_command, port, *words):
    proc = subprocess.run([str(st_command), port, "921600", *words], capture_output=True,
                          text=True, timeout=30)
    return proc.returncode, proc.stdout.strip()


def test_the_c_example_sends_commands_and_matches_their_replies(st_command):
    """tools/fc/st_command.c against the daemon (camera absent: commands are still
    answered) on a null-modem pair of pseudo-terminals."""
    with NullModem() as (tracker_port, fc_port):
        cfg = Config()
        cfg = replace(cfg, link=replace(cfg.link, port=tracker_port, status_rate_hz=50.0),
                      service=replace(cfg.service, watchdog_s=0.0, retry_initial_s=0.05,
                                      retry_max_s=0.05))

        def no_camera():
            raise CameraError("no camera 0")

        daemon = Daemon(cfg, source_factory=no_camera, pipeline=FakePipeline(),
                        link=DaemonLink(cfg), notifier=Notifier(""))
        runner = threading.Thread(target=daemon.run)
        runner.start()
        try:
            deadline = time.monotonic() + 10
            while not daemon.link.is_open and time.monotonic() < deadline:
                time.sleep(0.01)
            assert _run(st_command, fc_port, "ping") == (0, "ACK ping seq 0")
            code, text = _run(st_command, fc_port, "set-mode", "3")       # FAULT: refused
            assert (code, text) == (1, f"NACK set-mode seq 0 code {Reason.OUT_OF_RANGE:d}")
            assert _run(st_command, fc_port, "time-sync")[0] == 0
            assert _run(st_command, fc_port, "set-velocity", "-7.5", "0.25", "1")[0] == 0
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline:
                observer = daemon.timebase.observer_at(time.monotonic_ns())
                if observer.velocity_km_s is not None:
                    break
                time.sleep(0.01)
            assert observer.time_source == TimeSource.TIME_SYNC
            assert abs(observer.t_tai_ns - host_tai_ns()) < 10**9
            assert observer.velocity_km_s == (-7.5, 0.25, 1.0)
        finally:
            daemon.request_stop()
            runner.join(timeout=10)
    assert not runner.is_alive()


def test_the_c_example_gives_up_after_three_tries_without_a_reply(st_command):
    with NullModem() as (_, fc_port):                  # nobody at the tracker's end
        t0 = time.monotonic()
        code, text = _run(st_command, fc_port, "ping")
        elapsed = time.monotonic() - t0
    assert (code, text) == (2, "no reply to ping after 3 tries")
    assert elapsed >= 0.6                                # 3 x 200 ms
