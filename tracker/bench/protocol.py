"""Serial protocol: encode/decode cost, decoder fuzzing, link behaviour under overload.

Three parts, reported as Markdown and JSON in ``--out``:

1. Cost per packet of encoding and of stream-decoding ATTITUDE, CENTROIDS
   (40 stars, one full part) and STATUS, in microseconds.
2. ``--fuzz`` random and mutated inputs (random bytes; valid streams with
   bytes flipped, inserted, deleted, truncated) through both decoders in
   random chunking: exceptions (must be 0), the largest buffer seen, and how
   many packets survived.
3. The link on a real pseudo-terminal with the writer paced to
   ``--overload-baud``, asked for more than fits (ATTITUDE 30 Hz, CENTROIDS
   of 48 stars at 10 Hz, STATUS 2 Hz for ``--seconds``): what was queued,
   sent, received and dropped per class.
"""

from __future__ import annotations

import json
import os
import threading
import time
import traceback
import tty
from dataclasses import replace
from pathlib import Path

import numpy as np

from tracker.bench.machine import describe_machine
from tracker.protocol.budget import bytes_per_second, load_bytes_per_second
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.link import Link
from tracker.protocol.messages import BY_ID, Direction, Mode, MsgId

STATUS_VALUES = {
    "uptime_s": 100, "frame_rate_hz": 30.0, "exposure_us": 20000, "gain": 2.0,
    "cpu_temp_c": 55.0, "mode": Mode.TRACKING, "frames": 3000, "capture_faults": 0,
    "solve_failures": 1, "link_drops": 0, "link_reopens": 0, "rx_rejects": 0, "last_error": 0,
    "config_crc": 0x12345678, "time_source": 1, "corrections": 3, "psf_fwhm_px": 2.75,
}


def add_arguments(parser) -> None:
    parser.add_argument("--fuzz", type=int, default=100_000,
                        help="random and mutated inputs through the decoders")
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="length of the overload run")
    parser.add_argument("--overload-baud", type=int, default=57600,
                        help="baud rate the writer is paced to in the overload run")
    parser.add_argument("--seed", type=int, default=1, help="random seed")


def sample_stars(rng: np.random.Generator, n: int) -> np.ndarray:
    """n random stars in the CENTROIDS item layout (1600 x 1300 frame)."""
    stars = np.zeros(n, dtype=BY_ID[MsgId.CENTROIDS].item_dtype)
    stars["x"] = rng.uniform(0, 1599, n)
    stars["y"] = rng.uniform(0, 1299, n)
    stars["flux"] = rng.uniform(1e2, 1e5, n)
    stars["hip"] = rng.integers(0, 120_000, n)
    stars["flags"] = rng.integers(0, 16, n)
    return stars


def sample_attitude(enc: Encoder, k: int) -> bytes:
    return enc.encode(MsgId.ATTITUDE, frame_id=k, t_ns=k * 33_333_333, q_w=0.5, q_x=0.5,
                      q_y=-0.5, q_z=0.5, sigma_cross_arcsec=5.0, sigma_roll_arcsec=30.0,
                      rate_x=0.01, rate_y=0.0, rate_z=-0.02, matched=17, mode=Mode.TRACKING,
                      flags=3)


def _costs(rng: np.random.Generator, n: int = 3000) -> dict:
    enc = Encoder()
    stars = sample_stars(rng, 40)
    makers = {
        "ATTITUDE": lambda k: sample_attitude(enc, k),
        "CENTROIDS": lambda k: enc.centroids(k, k, stars)[0],
        "STATUS": lambda k: enc.encode(MsgId.STATUS, **STATUS_VALUES),
    }
    out = {}
    for name, make in makers.items():
        t0 = time.perf_counter()
        packets = [make(k) for k in range(n)]
        t_enc = (time.perf_counter() - t0) / n
        stream = b"".join(packets)
        dec = StreamDecoder(Direction.TM)
        t0 = time.perf_counter()
        got = sum(len(dec.feed(stream[i:i + 4096])) for i in range(0, len(stream), 4096))
        t_dec = (time.perf_counter() - t0) / n
        out[name] = {"packet_bytes": len(packets[0]), "encode_us": t_enc * 1e6,
                     "decode_us": t_dec * 1e6, "decoded": got, "of": n}
    return out


def _mutate(rng: np.random.Generator, data: bytes) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 6))):
        op = int(rng.integers(0, 4))
        pos = int(rng.integers(0, len(b) + 1))
        if op == 0 and b:
            b[min(pos, len(b) - 1)] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            b[pos:pos] = rng.bytes(int(rng.integers(1, 20)))
        elif op == 2:
            del b[pos:pos + int(rng.integers(1, 20))]
        else:
            del b[pos:]
    return bytes(b)


def _fuzz(rng: np.random.Generator, n: int) -> dict:
    tm, tc = Encoder(Direction.TM), Encoder(Direction.TC)
    stars = sample_stars(rng, 60)
    pool = [sample_attitude(tm, 1), *tm.centroids(1, 1, stars),
            tm.encode(MsgId.STATUS, **STATUS_VALUES),
            tc.encode(MsgId.PING), tc.encode(MsgId.SET_MODE, mode=2),
            tc.encode(MsgId.SET_GAIN, gain=2.0),
            tc.encode(MsgId.TIME_SYNC, fc_time_ns=1_800_000_037 * 10**9),
            tc.encode(MsgId.SET_VELOCITY, t_ns=1_800_000_037 * 10**9, vx_km_s=-7.5,
                      vy_km_s=0.5, vz_km_s=1.25)]
    decoders = [StreamDecoder(Direction.TM), StreamDecoder(Direction.TC, keep_rejects=True)]
    crashes, first_error, packets, biggest = 0, None, 0, 0
    t0 = time.perf_counter()
    for k in range(n):
        if k % 2:
            data = rng.bytes(int(rng.integers(0, 400)))
        else:
            picks = rng.integers(0, len(pool), int(rng.integers(1, 5)))
            data = _mutate(rng, b"".join(pool[i] for i in picks))
        cut = sorted(int(c) for c in rng.integers(0, len(data) + 1, 3))
        for dec in decoders:
            try:
                for a, b in zip([0, *cut], [*cut, len(data)], strict=True):
                    packets += sum(1 for p in dec.feed(data[a:b]) if hasattr(p, "msg"))
                biggest = max(biggest, len(dec._buf))
            except Exception:   # the point of the exercise: count, never stop
                crashes += 1
                first_error = first_error or traceback.format_exc()
    elapsed = time.perf_counter() - t0
    return {"inputs": n, "crashes": crashes, "first_error": first_error,
            "packets_recovered": packets, "largest_buffer_bytes": biggest,
            "buffer_bound_bytes": max(d.max_buffer for d in decoders),
            "us_per_input": elapsed / max(n, 1) * 1e6,
            "counters_tm": decoders[0].counters, "counters_tc": decoders[1].counters}


def _overload(cfg, rng: np.random.Generator, baud: int, seconds: float) -> dict:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    link_cfg = replace(cfg.link, port=os.ttyname(slave), baudrate=baud, attitude_rate_hz=30.0,
                       centroids_rate_hz=10.0, status_rate_hz=2.0, max_centroids=48)
    received: dict[str, int] = {}
    order: list[str] = []
    stop = threading.Event()

    def drain() -> None:
        dec = StreamDecoder(Direction.TM)
        while not stop.is_set():
            try:
                data = os.read(master, 65536)
            except OSError:
                return
            for p in dec.feed(data):
                received[p.name] = received.get(p.name, 0) + 1
                if len(order) < 40:
                    order.append(p.name)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    stars = sample_stars(rng, 48)
    link = Link(link_cfg).start()
    t0 = time.monotonic()
    k = 0
    while time.monotonic() - t0 < seconds:
        t_ns = time.monotonic_ns()
        link.send_attitude(frame_id=k, t_ns=t_ns, q=[1.0, 0.0, 0.0, 0.0], sigma_cross_arcsec=5.0,
                           sigma_roll_arcsec=30.0, matched=12, mode=Mode.TRACKING)
        link.send_centroids(k, t_ns, stars)
        link.send_status(**STATUS_VALUES)
        k += 1
        time.sleep(max(0.0, t0 + k / 30.0 - time.monotonic()))
    link.close()
    time.sleep(0.2)
    stop.set()
    os.close(slave)
    reader.join(timeout=1.0)
    os.close(master)
    stats = link.stats()
    classes = {}
    for cls, name in (("attitude", "ATTITUDE"), ("centroids", "CENTROIDS"),
                      ("status", "STATUS")):
        classes[name] = {key: stats.get(f"{key}_{cls}", 0) for key in
                         ("queued", "sent", "dropped_full", "dropped_stale", "unsent")}
        classes[name]["received"] = received.get(name, 0)
    usable = bytes_per_second(baud) * link_cfg.bandwidth_fraction
    return {"baud": baud, "seconds": seconds, "frames": k, "usable_bytes_s": usable,
            "asked_bytes_s": load_bytes_per_second(30.0, 10.0, 2.0, 48),
            "sent_bytes_s": stats.get("bytes_sent", 0) / seconds, "classes": classes,
            "first_packets": order}


def run(args, cfg) -> int:
    rng = np.random.default_rng(args.seed)
    result = {"machine": describe_machine(), "costs": _costs(rng),
              "fuzz": _fuzz(rng, args.fuzz),
              "overload": _overload(cfg, rng, args.overload_baud, args.seconds)}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "protocol.json").write_text(json.dumps(result, indent=2, default=str) + "\n")
    (out / "protocol.md").write_text(_markdown(result))
    print(_markdown(result))
    return 1 if result["fuzz"]["crashes"] else 0


def _markdown(r: dict) -> str:
    m = r["machine"]
    lines = ["# Benchmark: serial protocol", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_gib']} GiB, {m['os']}, "
             f"Python {m['python']}", "", "## Cost per packet", "",
             "| message | packet bytes | encode us | decode us |", "|---|---:|---:|---:|"]
    for name, c in r["costs"].items():
        lines.append(f"| {name} | {c['packet_bytes']} | {c['encode_us']:.1f} | "
                     f"{c['decode_us']:.1f} |")
    f = r["fuzz"]
    lines += ["", "## Decoder fuzzing", "",
              f"{f['inputs']} inputs (half random bytes, half mutated valid streams), each "
              f"through the TM and the TC decoder in random chunks: **{f['crashes']} "
              f"crashes**, {f['packets_recovered']} packets recovered, largest buffer "
              f"{f['largest_buffer_bytes']} bytes (bound {f['buffer_bound_bytes']}), "
              f"{f['us_per_input']:.1f} us per input.", ""]
    o = r["overload"]
    lines += ["## Link under overload", "",
              f"Writer paced to {o['baud']} baud ({o['usable_bytes_s']:.0f} B/s usable), "
              f"asked for {o['asked_bytes_s']:.0f} B/s (ATTITUDE 30 Hz, CENTROIDS 48 stars "
              f"10 Hz, STATUS 2 Hz) for {o['seconds']:g} s ({o['frames']} frames); sent "
              f"{o['sent_bytes_s']:.0f} B/s.", "",
              "| message | queued | sent | received | dropped (queue full) | dropped (stale) "
              "| still queued at the end |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, c in o["classes"].items():
        lines.append(f"| {name} | {c['queued']} | {c['sent']} | {c['received']} | "
                     f"{c['dropped_full']} | {c['dropped_stale']} | {c['unsent']} |")
    lines += ["", f"First packets received: {', '.join(o['first_packets'][:20])}", ""]
    return "\n".join(lines)
