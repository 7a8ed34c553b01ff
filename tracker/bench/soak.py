"""Soak: many frames through the whole service with faults injected; memory, drops, latency.

Set-up: a few 1600x1300 frames of one simulated sky (realistic noise) are
saved as .npy in a temporary folder together with one truncated PNG, and
the service runs on the replay backend (looping) with the real pipeline and
the real serial link on a pseudo-terminal whose other end plays the flight
computer. Faults injected, each on a fixed schedule of frame numbers:

- corrupt frames: the truncated PNG comes round once per pass of the folder;
- a source that raises: the source raises OSError every ``--raise-every``
  frames (the service must close it, back off and reopen);
- a stage that raises: the pipeline raises every ``--stage-every`` frames;
- the serial port closed: the FC side closes its pty and opens a new one
  (the port path is a symlink, as udev's /dev/fcu) every ``--port-every``;
- FC garbage: random bytes, a frame with a broken CRC and a PING every
  ``--garbage-every`` frames (half a period after the port closes), and one
  flood halfway (64 KiB random + 500 PINGs).

At the end the FC asks for STATUS (REQUEST_STATUS) and the bench checks
that every injected fault is counted by the service and shows in STATUS.
Reported: resident memory (RSS) over time, frames dropped and why, and the
end-to-end latency (frame out of the source -> packets queued on the link)
as percentiles, overall and in tracking mode, with the per-stage split, and
the link's own (frame read -> last byte of its ATTITUDE on the wire).
"""

from __future__ import annotations

import dataclasses
import json
import os
import resource
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from tracker.bench.machine import describe_machine
from tracker.capture.backends import make_source
from tracker.capture.base import FrameError
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.pipeline import Pipeline
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.messages import Direction, ErrorCode, Mode, MsgId
from tracker.protocol.nullmodem import ReplugPty

__all__ = ["add_arguments", "run"]

_PAGE = os.sysconf("SC_PAGE_SIZE")


def add_arguments(parser) -> None:
    parser.add_argument("--frames", type=int, default=10000, help="frames to run (10000)")
    parser.add_argument("--files", type=int, default=49,
                        help="good frame files per pass of the folder (the corrupt one "
                             "makes it 1 in files+1)")
    parser.add_argument("--raise-every", type=int, default=2500, metavar="N")
    parser.add_argument("--stage-every", type=int, default=997, metavar="N")
    parser.add_argument("--port-every", type=int, default=2000, metavar="N")
    parser.add_argument("--garbage-every", type=int, default=250, metavar="N")
    parser.add_argument("--seed", type=int, default=7, help="sky and noise seed")


def _rss_bytes() -> int:
    with open("/proc/self/statm", encoding="ascii") as fh:
        return int(fh.read().split()[1]) * _PAGE


def _make_frames(cfg: Config, folder: Path, files: int, seed: int) -> None:
    """``files`` .npy frames (4 noise draws of one sky, hard-linked) and a truncated PNG."""
    from tracker.catalogue import load_catalogue
    from tracker.sim import random_attitude, render_sky

    cat = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year, cfg.catalogue.mag_limit)
    rng = np.random.default_rng(seed)
    R = random_attitude(rng)
    draws = []
    for k in range(min(4, files)):
        path = folder / f"draw{k}.npy"
        np.save(path, render_sky(cfg.camera, cat, R, cfg.sim, rng).image)
        draws.append(path)
    for k in range(files):
        os.link(draws[k % len(draws)], folder / f"f{k:04d}.npy")
    for path in draws:
        path.unlink()
    png = b"\x89PNG\r\n\x1a\n" + bytes(100)           # header only: "truncated PNG"
    (folder / "zz_corrupt.png").write_bytes(png)


class _Injector:
    """Counts and schedules the injected faults; everything keyed on frame numbers."""

    def __init__(self, args):
        self.args = args
        self.n = dict.fromkeys(("corrupt_frame", "source_raise", "stage_raise", "port_close",
                                "garbage_burst", "bad_crc_frame", "flood"), 0)
        self.taken = 0          # items taken from sources, all openings together
        self.active = True      # injections stop once the frame budget is reached

    def due(self, every: int) -> bool:
        return self.active and every > 0 and self.taken % every == 0


class _FlakySource:
    """A replay source that raises OSError on schedule and counts its corrupt frames."""

    def __init__(self, inner, inj: _Injector):
        self.inner, self.inj = inner, inj

    def __iter__(self):
        for item in self.inner:
            self.inj.taken += 1
            if self.inj.due(self.inj.args.raise_every):
                self.inj.n["source_raise"] += 1
                raise OSError("injected: camera vanished")
            if isinstance(item, FrameError):      # counted always: the service does too
                self.inj.n["corrupt_frame"] += 1
            yield item

    def close(self):
        self.inner.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class _FlakyPipeline:
    def __init__(self, inner: Pipeline, inj: _Injector):
        self.inner, self.inj = inner, inj

    def reset(self):
        self.inner.reset()

    def process(self, image, bit_depth, t_ns, observer=None, exposure_s=None):
        if self.inj.due(self.inj.args.stage_every):
            self.inj.n["stage_raise"] += 1
            raise RuntimeError("injected: stage failure")
        return self.inner.process(image, bit_depth, t_ns, observer, exposure_s)


class _FlightComputer(threading.Thread):
    """The pty's far end: decodes telemetry, injects garbage, closes the port on request."""

    def __init__(self, link_path: Path, inj: _Injector):
        super().__init__(name="soak-fc", daemon=True)
        self.link_path, self.inj = link_path, inj
        self.decoder = StreamDecoder(Direction.TM)
        self.encoder = Encoder(Direction.TC)
        self.counts: dict[str, int] = {}
        self.last_status: dict | None = None
        self.requests: list[str] = []
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.status_event = threading.Event()
        self.pty = ReplugPty(link_path)

    def ask(self, what: str) -> None:
        with self.lock:
            self.requests.append(what)

    def _do(self, what: str) -> None:
        rng = np.random.default_rng(len(self.requests) + sum(self.inj.n.values()))
        if what == "close":
            self.pty.replug()
            self.inj.n["port_close"] += 1
        elif what == "garbage":
            bad = bytearray(self.encoder.encode(MsgId.PING))
            bad[-1] ^= 0x5A
            self._write(rng.integers(0, 256, 200, dtype=np.uint8).tobytes() + bytes(bad)
                        + self.encoder.encode(MsgId.PING))
            self.inj.n["garbage_burst"] += 1
            self.inj.n["bad_crc_frame"] += 1
        elif what == "flood":
            self._write(rng.integers(0, 256, 65536, dtype=np.uint8).tobytes()
                        + b"".join(self.encoder.encode(MsgId.PING) for _ in range(500)))
            self.inj.n["flood"] += 1
        elif what == "status":
            self._write(self.encoder.encode(MsgId.REQUEST_STATUS))

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + 5
        while view and time.monotonic() < deadline:
            try:
                view = view[os.write(self.pty.master, view):]
            except BlockingIOError:
                self._read()
                time.sleep(0.001)

    def _read(self) -> None:
        try:
            data = os.read(self.pty.master, 65536)
        except (BlockingIOError, OSError):
            return
        for p in self.decoder.feed(data):
            self.counts[p.name] = self.counts.get(p.name, 0) + 1
            if p.id == MsgId.STATUS:
                self.last_status = dict(p.values)
                self.status_event.set()

    def run(self) -> None:
        while not self.stop.is_set():
            with self.lock:
                todo, self.requests = self.requests, []
            for what in todo:
                self._do(what)
            self._read()
            time.sleep(0.002)
        self.pty.close()


def _percentiles(values: np.ndarray) -> dict:
    if not len(values):
        return {}
    p = np.percentile(values, [50, 90, 99, 100])
    return {"p50": p[0], "p90": p[1], "p99": p[2], "max": p[3], "n": int(len(values))}


def run(args, cfg: Config) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="soak-"))
    frames_dir = tmp / "frames"
    frames_dir.mkdir()
    print(f"soak: rendering {args.files} frame files in {frames_dir}", flush=True)
    _make_frames(cfg, frames_dir, args.files, args.seed)
    link_path = tmp / "fcu"
    cfg = dataclasses.replace(
        cfg, capture=dataclasses.replace(cfg.capture, backend="replay", loop=True, fps=0.0,
                                         replay_path=str(frames_dir)),
        link=dataclasses.replace(cfg.link, port=str(link_path), reopen_backoff_s=0.05),
        service=dataclasses.replace(cfg.service, frames=0, retry_initial_s=0.05,
                                    retry_max_s=0.2, watchdog_s=60.0))
    inj = _Injector(args)
    fc = _FlightComputer(link_path, inj)
    n = args.frames
    lat = np.full(n, np.nan)
    tracking = np.zeros(n, bool)
    stage_names: dict[str, np.ndarray] = {}
    rss: list[tuple[int, int]] = [(0, _rss_bytes())]
    done = {"k": 0, "t0": 0.0}

    def on_frame(report) -> None:
        k = done["k"]
        if k >= n:
            return
        lat[k] = report.latency_ms
        tracking[k] = report.mode == Mode.TRACKING
        for name, ms in report.stages_ms.items():
            stage_names.setdefault(name, np.full(n, np.nan))[k] = ms
        done["k"] = k = k + 1
        if inj.active:
            if args.port_every and k % args.port_every == 0:
                fc.ask("close")
            if args.garbage_every and k % args.garbage_every == args.garbage_every // 2:
                # half a period off the port closes: bytes sent while the port is
                # being reopened are flushed by the open, not a service fault
                fc.ask("garbage")
            if k == n // 2:
                fc.ask("flood")
        if k % 100 == 0:
            rss.append((k, _rss_bytes()))
        if k % 1000 == 0:
            rate = k / (time.monotonic() - done["t0"])
            print(f"soak: {k}/{n} frames, {rate:.1f} fps, RSS {rss[-1][1] / 2**20:.1f} MiB",
                  flush=True)
        if k == n:
            inj.active = False
            done["injected_drops"] = (inj.n["corrupt_frame"] + inj.n["source_raise"]
                                      + inj.n["stage_raise"])

    service = Daemon(cfg, source_factory=lambda: _FlakySource(make_source(cfg), inj),
                     pipeline=_FlakyPipeline(Pipeline(cfg), inj), link=DaemonLink(cfg),
                     on_frame=on_frame)

    def stopper() -> None:
        while done["k"] < n and not fc.stop.is_set():
            time.sleep(0.05)
        time.sleep(0.5)                  # let the link's counters settle
        # a STATUS already queued may answer first: wait for one that counts every frame
        frames = service.health.frames
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            fc.status_event.clear()
            fc.ask("status")
            fc.status_event.wait(1)
            if (fc.last_status or {}).get("frames", -1) >= frames:
                break
        service.request_stop()

    fc.start()
    threading.Thread(target=stopper, name="soak-stopper", daemon=True).start()
    done["t0"] = time.monotonic()
    crashed = None
    try:
        service.run()
    except Exception as exc:    # the one thing the soak must not see
        crashed = f"{type(exc).__name__}: {exc}"
    wall = time.monotonic() - done["t0"]
    time.sleep(0.3)
    fc.stop.set()
    fc.join(5)
    report = _report(args, service, inj, fc, lat, tracking, stage_names, rss, wall, crashed,
                     done.get("injected_drops", 0))
    (out / "soak.json").write_text(json.dumps(report, indent=2, default=float) + "\n")
    (out / "soak.md").write_text(_markdown(report))
    print((out / "soak.md").read_text())
    return 0 if report["ok"] else 1


def _report(args, service, inj, fc, lat, tracking, stage_names, rss, wall, crashed,
            injected_drops) -> dict:
    h = service.health
    link = service.link.link.stats()
    status = fc.last_status or {}
    valid = ~np.isnan(lat)
    split_mask = valid & tracking if tracking.any() else valid
    split = {name: float(np.nanmedian(v[split_mask])) for name, v in stage_names.items()
             if np.any(~np.isnan(v[split_mask]))}
    warm = next((b for k, b in rss if k >= 100), rss[0][1])
    checks = {
        "no crash": crashed is None,
        "corrupt frames counted":
            h.faults[ErrorCode.FRAME_UNREADABLE] == inj.n["corrupt_frame"],
        "source raises counted": h.faults[ErrorCode.CAMERA_LOST] == inj.n["source_raise"],
        "stage raises counted": h.faults[ErrorCode.STAGE_ERROR] == inj.n["stage_raise"],
        "port closes -> link reopens": link.get("reopens", 0) == inj.n["port_close"],
        "bad-CRC frames -> rx rejects": link.get("rx_bad_crc", 0) >= inj.n["bad_crc_frame"],
        "STATUS capture_faults": status.get("capture_faults", -1) >= injected_drops > 0,
        "STATUS link_reopens": status.get("link_reopens") == inj.n["port_close"],
        "STATUS rx_rejects": status.get("rx_rejects", -1) >= inj.n["bad_crc_frame"],
    }
    return {
        "machine": describe_machine(),
        "frames": int(valid.sum()), "wall_s": wall, "fps": valid.sum() / wall,
        "args": {k: v for k, v in vars(args).items() if k not in ("func",)},
        "crash": crashed,
        "injected": inj.n,
        "service_faults": h.fault_counts(), "capture_faults": h.capture_faults,
        "frames_taken": h.frames, "processed": h.processed, "solved": h.solved,
        "tracking_frames": int(tracking.sum()),
        "link": link, "fc_decoded": fc.counts, "final_status": status,
        "latency_ms": _percentiles(lat[valid]),
        "latency_tracking_ms": _percentiles(lat[valid & tracking]),
        "wire_latency_ms": dict(service.link.wire_latency_ms(),
                                n=service.link.link.latency.count),
        "stage_median_ms": split,
        "rss_mib": [(k, b / 2**20) for k, b in rss],
        "rss_growth_mib": (rss[-1][1] - warm) / 2**20,
        "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "checks": checks,
        "ok": all(checks.values()),
    }


def _fmt(p: dict) -> str:
    if not p:
        return "(none)"
    return (f"p50 {p['p50']:.2f}, p90 {p['p90']:.2f}, p99 {p['p99']:.2f}, "
            f"max {p['max']:.2f} ms (n={p['n']})")


def _markdown(r: dict) -> str:
    lines = ["# Soak: the service under injected faults", ""]
    lines += [f"- {k}: {v}" for k, v in r["machine"].items()]
    lines += ["", f"{r['frames_taken']} frames taken from the source, {r['processed']} "
              f"through the pipeline, {r['solved']} solved; {r['frames']} latency samples "
              f"in {r['wall_s']:.1f} s ({r['fps']:.1f} fps), {r['tracking_frames']} in "
              "tracking mode; "
              f"crash: {r['crash'] or 'none'}", "",
              "## Latency (frame out of the source -> packets queued)", "",
              f"- all frames: {_fmt(r['latency_ms'])}",
              f"- tracking mode: {_fmt(r['latency_tracking_ms'])}",
              f"- the frame read -> the last byte of its ATTITUDE on the wire (the replayed "
              f"frames have no exposure time; at most link.max_age_ms by the stale rule): "
              f"{_fmt(r['wire_latency_ms'])}", "",
              "Median per stage (tracking frames if any, else all), ms:", "",
              "| stage | ms |", "|---|---|"]
    lines += [f"| {k} | {v:.3f} |" for k, v in r["stage_median_ms"].items()]
    lines += ["", "## Faults: injected, counted by the service, in the final STATUS", "",
              "| fault | injected | service count |", "|---|---|---|"]
    f = r["service_faults"]
    rows = [("corrupt frame", "corrupt_frame", f.get("frame_unreadable", 0)),
            ("source raises", "source_raise", f.get("camera_lost", 0)),
            ("stage raises", "stage_raise", f.get("stage_error", 0)),
            ("port closed", "port_close", r["link"].get("reopens", 0)),
            ("bad-CRC frame", "bad_crc_frame", r["link"].get("rx_bad_crc", 0)),
            ("garbage bursts (200 B)", "garbage_burst", r["link"].get("rx_bytes_dropped", 0)),
            ("flood (64 KiB + 500 PING)", "flood", r["link"].get("commands", 0))]
    lines += [f"| {name} | {r['injected'][key]} | {count} |" for name, key, count in rows]
    lines += ["", "(garbage bursts: service column = bytes dropped by the decoder; flood: "
              "commands obeyed in total)", "",
              f"Final STATUS packet: {r['final_status']}", "",
              f"Frames dropped and why: {r['service_faults']}", "",
              f"## Memory: RSS growth after the first 100 frames {r['rss_growth_mib']:.2f} MiB; "
              f"peak {r['max_rss_mib']:.1f} MiB", ""]
    lines += ["| frame | RSS MiB |", "|---|---|"]
    samples = r["rss_mib"]
    step = max(1, len(samples) // 20)
    lines += [f"| {k} | {m:.2f} |" for k, m in samples[::step] + samples[-1:]]
    lines += ["", "## Checks", ""]
    lines += [f"- {'PASS' if ok else 'FAIL'} {name}" for name, ok in r["checks"].items()]
    return "\n".join(lines) + "\n"
