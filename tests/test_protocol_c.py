"""The FC's C99 decoder (tools/fc/) agrees with the Python decoder on the service's bytes."""

import math
import subprocess

import numpy as np
import pytest
from fc_build import FC, build, needs_gcc, python_lines, same_word

from tracker.astrometry.timescale import TAI_NS_MAX, TAI_NS_MIN
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.messages import BY_ID, TYPES, Direction, Mode, MsgId

pytestmark = needs_gcc


@pytest.fixture(scope="module", name="st_dump")
def fixture_st_dump(tmp_path_factory):
    return build(tmp_path_factory.mktemp("fc"), "st_dump", FC / "st_dump.c",
                 FC / "st_decoder.c")


def _service_stream(seed=11):
    """Telemetry as the service sends it, with noise, truncation and corruption between."""
    rng = np.random.default_rng(seed)
    enc = Encoder()
    parts = []
    for k in range(20):
        parts.append(rng.bytes(int(rng.integers(0, 40))))
        q = rng.normal(size=4)
        q = q / np.linalg.norm(q) * np.sign(q[0])
        parts.append(enc.encode(MsgId.ATTITUDE, frame_id=k, t_ns=int(rng.integers(0, 2**63)),
                                q_w=q[0], q_x=q[1], q_y=q[2], q_z=q[3],
                                sigma_cross_arcsec=rng.uniform(1, 10), sigma_roll_arcsec=math.nan,
                                rate_x=rng.normal(), rate_y=-0.0, rate_z=math.inf,
                                matched=k, mode=Mode.TRACKING, flags=k % 16))
        stars = np.zeros(int(rng.integers(0, 70)), dtype=BY_ID[MsgId.CENTROIDS].item_dtype)
        for name in ("x", "y", "flux"):
            stars[name] = rng.uniform(0, 1600, len(stars))
        stars["hip"] = rng.integers(0, 2**32, len(stars))
        stars["flags"] = rng.integers(0, 2**16, len(stars))
        cen = enc.centroids(k, k * 7, stars)
        parts += cen
        if k % 5 == 0:
            parts.append(cen[0][:int(rng.integers(1, len(cen[0])))])   # truncated copy
            bad = bytearray(cen[-1])
            bad[-5] ^= 0x10                                          # CRC will fail
            parts.append(bytes(bad))
        if k % 7 == 0:
            parts.append(enc.encode(MsgId.STATUS, uptime_s=k, frame_rate_hz=29.9,
                                    exposure_us=20000, gain=1.5, cpu_temp_c=60.25, mode=1,
                                    frames=k, capture_faults=0, solve_failures=2,
                                    link_drops=3, link_reopens=4, rx_rejects=5,
                                    last_error=6, config_crc=0xFFFFFFFF, time_source=k % 4,
                                    corrections=k % 8, psf_fwhm_px=2.5 + k / 8))
            parts.append(enc.encode(MsgId.NACK, cmd_id=0x21, cmd_seq=16383, code=4,
                                    rx_t_ns=2**64 - 1))
    return b"".join(parts)


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_c_decoder_agrees_with_python_on_every_field(st_dump, chunk):
    data = _service_stream()
    run = subprocess.run([str(st_dump), str(chunk)], input=data, capture_output=True,
                         check=True)
    c_lines = [line.split() for line in run.stdout.decode().splitlines()]
    counters = dict(w.split("=") for w in c_lines.pop()[1:])
    py = python_lines(data)
    assert len(c_lines) == len(py) > 50
    f32 = {f.name for m in BY_ID.values() for f in (*m.fields, *m.item) if f.type == "f32"}
    for c, p in zip(c_lines, py, strict=True):
        assert c[:2] == p[:2] and len(c) == len(p)
        for cw, pw in zip(c[2:], p[2:], strict=True):
            assert same_word(cw, pw, cw.split("=")[0].split("[")[0] in f32), (cw, pw)
    dec = StreamDecoder()
    dec.feed(data)
    assert int(counters["packets"]) == dec.counters["packets"]
    assert int(counters["bad_crc"]) == dec.counters["bad_crc"] > 0
    assert int(counters["bad_header"]) == dec.counters["bad_header"]


def test_c_header_types_match_the_table():
    header = (FC / "st_protocol.h").read_text()
    for m in BY_ID.values():
        for f in m.fields:
            assert f"    {TYPES[f.type][2]} {f.name};" in header


def test_c_frame_builder_and_packers_make_the_same_commands_as_python(tmp_path):
    src = tmp_path / "build_cmds.c"
    src.write_text("""
#include <stdio.h>
#include "st_decoder.h"
static void put(unsigned apid, unsigned seq, const uint8_t *p, size_t n)
{
    uint8_t f[64];
    size_t k, len = st_build_packet(f, sizeof f, apid, 1, seq, p, n);
    for (k = 0; k < len; k++) printf("%02x", f[k]);
    printf("\\n");
}
int main(void)
{
    uint8_t p[16];
    st_set_mode_t mode = {ST_MODE_TRACKING};
    st_set_output_t out = {ST_ID_CENTROIDS, 2.5f};
    st_time_sync_t ts = {1234567890123456789ull};
    st_ping_t ping = {0};
    put(ST_ID_SET_MODE, 0, p, st_pack_set_mode(p, &mode));
    put(ST_ID_SET_OUTPUT, 0, p, st_pack_set_output(p, &out));
    put(ST_ID_TIME_SYNC, 0, p, st_pack_time_sync(p, &ts));
    put(ST_ID_PING, 0, p, st_pack_ping(p, &ping));
    put(ST_ID_PING, 16383, p, st_pack_ping(p, &ping));
    return 0;
}
""")
    exe = build(tmp_path, "build_cmds", src, FC / "st_decoder.c")
    got = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split()
    enc = Encoder(Direction.TC)
    pings = [enc.encode(MsgId.PING) for _ in range(16384)]
    want = [enc.encode(MsgId.SET_MODE, mode=Mode.TRACKING),
            enc.encode(MsgId.SET_OUTPUT, msg_id=MsgId.CENTROIDS, rate_hz=2.5),
            enc.encode(MsgId.TIME_SYNC, fc_time_ns=1234567890123456789),
            pings[0], pings[16383]]
    assert got == [w.hex() for w in want]


def test_c_header_refuses_what_the_tracker_nacks(tmp_path):
    """The ICD's range rules in the FC's header: TIME_SYNC outside 1972-2200 TAI, SET_OUTPUT
    rates other than 0 or 0.01 .. 100 Hz (1e-45 included) are ST_OUT_OF_RANGE."""
    src = tmp_path / "ranges.c"
    src.write_text("""
#include <stdio.h>
#include "st_protocol.h"
static int time_sync(uint64_t t)
{
    uint8_t p[8];
    st_time_sync_t m = {0}, back;
    m.fc_time_ns = t;
    return st_parse_time_sync(p, st_pack_time_sync(p, &m), &back);
}
static int output(float hz)
{
    uint8_t p[6];
    st_set_output_t m = {ST_ID_ATTITUDE, 0.0f}, back;
    m.rate_hz = hz;
    return st_parse_set_output(p, st_pack_set_output(p, &m), &back);
}
int main(void)
{
    printf("%d %d %d %d %d %d\\n", time_sync(0u), time_sync({lo}ull),
           time_sync({lo}ull - 1u), time_sync({hi}ull), time_sync({hi}ull + 1u),
           time_sync(18446744073709551615ull));
    printf("%d %d %d %d %d %d\\n", output(0.0f), output(0.01f), output(100.0f),
           output(1e-45f), output(0.009f), output(-1.0f));
    printf("%d %d\\n", ST_ERR_CAMERA_LOST, ST_ERR_LINK_INTERNAL);
    return 0;
}
""".replace("{lo}", str(TAI_NS_MIN)).replace("{hi}", str(TAI_NS_MAX)))
    exe = build(tmp_path, "ranges", src)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout.split("\n")
    ok, bad = "0", "4"      # ST_OK, ST_OUT_OF_RANGE
    assert out[0].split() == [bad, ok, bad, ok, bad, bad]
    assert out[1].split() == [ok, ok, ok, bad, bad, bad]
    assert out[2].split() == ["3", "8"]
