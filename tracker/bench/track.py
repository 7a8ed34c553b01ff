"""Tracking: windowed against full-frame on the same slewed frames, errors against truth, memory.

Scenarios (``--scenarios``, ``lens_mm:rate_deg_s:seconds[:draws]`` each)
render a constant-rate slew about a random axis from a random attitude at
``--fps`` with ``--exposure-ms`` of smear (tracker.sim, realistic sensor),
one frame in the middle dark (a blackout: the sky at its median level, no
stars). What the tracker cannot know is randomised per draw: the PSF width
(1.0-1.6 px; the detector assumes 1.2) and the lens's focal length (within
2 % of the configured one; the solver learns it). A scenario of several
draws renders that many such sequences, each with its own attitude, axis,
PSF and focal length and fresh pipelines, and pools their frames: a slew
sweeps the sky through many star fields, but a still camera sees one, and
its errors are then mostly that field's fixed bias (which stars, at which
pixel phases, under which lens error), so one still draw is one sample of
the error and a windowed/full ratio from it says little; the per-draw
ratios are reported beside the pooled one.

Every frame goes through two pipelines in turn, in the same process:

* ``full``: identify.track_windows false, the whole frame detected every
  frame (tracking solve when locked): the reference;
* ``windows``: windowed tracking as configured (tracker.identify.windows).

Per scenario and arm: frames solved and tracked, lock losses (a frame after
the third, other than the dark one, not solved in tracking mode), frames
until tracking again after the dark frame, cross-boresight and roll RMS and
the rate's RMS error against the truth over the tracked frames, and per frame
ms: the full arm's detection and the windowed arm's whole frame (windows'
detection and identification). The cost ratio is the median windowed frame
over the median full-frame detection of the same frames (wall time). Two
more readings of it, added because the full-frame detector's two slab
threads read faster or slower with the host's load while the windowed
path's single thread moves much less: the paired ratio, the median over
frames of each frame's windowed time over its own full-frame detection
(the two run back to back on that frame, so a drift of the machine meets
both alike), and the CPU ratio, the median windowed frame's process CPU
time over the median full-frame detection's (tracker.pipeline.FrameResult:
every thread's, so the detector's second slab thread counts as work even
when it ran in parallel; waiting for a core does not count; the clock is
read around the detector's whole call, where the wall figure sums its
stages). sep and tetra3
detect the first ``--peer-frames`` frames of each scenario for scale.

``--memory-frames`` (0: skip) runs the whole service (tracker run's Daemon:
replay backend looping over one still frame, so every frame after the first
few is tracked in windows; real link on a pseudo-terminal drained by a
reader) and reports the Python memory held (tracemalloc) after
``--memory-warmup`` frames and at the end, with the window sizes whose
detectors the pipeline held at both points (larger windows get their own
detector when first needed, which is no growth per frame; the replayed
frames are stamped ``capture.replay_interval_s`` apart however fast the
machine runs them, so the windows do not follow the machine's load).
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np

from tracker.attitude import attitude_error
from tracker.bench.detect_peers import PEERS, peer_available
from tracker.bench.machine import describe_machine
from tracker.capture.backends import make_source
from tracker.catalogue import load_catalogue
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.daemon.notify import Notifier
from tracker.errors import UserError
from tracker.pipeline import Pipeline
from tracker.protocol.nullmodem import ReplugPty
from tracker.sim import random_attitude, render_sequence, render_sky, write_frame

__all__ = ["add_arguments", "run", "run_scenario", "parse_scenarios", "memory_run"]

_ARCSEC = math.degrees(1.0) * 3600.0
ARMS = ("full", "windows")


def add_arguments(p) -> None:
    p.add_argument("--scenarios", default="16:0:10:5,16:1:60,16:2:10,16:3:10,8:1:10,8:3:10",
                   help="lens_mm:rate_deg_s:seconds[:draws], comma separated (draws "
                        "default 1)")
    p.add_argument("--fps", type=float, default=10.0, help="frame rate of the slews")
    p.add_argument("--exposure-ms", type=float, default=20.0, help="exposure (sets the smear)")
    p.add_argument("--peer-frames", type=int, default=3,
                   help="frames per scenario detected by sep and tetra3 for scale")
    p.add_argument("--memory-frames", type=int, default=10000,
                   help="frames through the whole service for the memory check; 0 = skip")
    p.add_argument("--memory-warmup", type=int, default=500,
                   help="frames before the memory reference")
    p.add_argument("--seed", type=int, default=13)


def parse_scenarios(text: str) -> list[tuple[float, float, float, int]]:
    """[(lens_mm, rate_deg_s, seconds, draws)] from ``lens:rate:seconds[:draws],...``.

    Raises UserError (one line, exit 2) naming the item when one is malformed.
    """
    out = []
    for item in text.split(","):
        fields = item.split(":")
        try:
            if len(fields) not in (3, 4):
                raise ValueError
            lens, rate, seconds = (float(v) for v in fields[:3])
            draws = int(fields[3]) if len(fields) == 4 else 1
            if lens <= 0 or rate < 0 or seconds <= 0 or draws < 1:
                raise ValueError
        except ValueError:
            raise UserError(f"--scenarios {item!r}: expected lens_mm:rate_deg_s:seconds[:draws] "
                             "with lens and seconds > 0, rate >= 0, draws >= 1") from None
        out.append((lens, rate, seconds, draws))
    return out


def _frames_to_relock(rows: list[dict], dark: int) -> int | None:
    """Frames after the dark one until tracking again (1: the next frame), None if never."""
    after = [r for r in rows if r["i"] > dark]
    return next((k + 1 for k, r in enumerate(after) if r["mode"] == "tracking"), None)


def _arm_stats(draws: list[tuple[list[dict], int]]) -> dict:
    """One arm's statistics pooled over draws, each (its rows, its dark frame's index).

    Lock losses are (draw, frame) pairs; the frames until tracking again after the dark
    frame are the worst draw's (None when a draw never tracked again).
    """
    rows = [r for draw_rows, _ in draws for r in draw_rows]
    darks = {draw_rows[0]["draw"]: dark for draw_rows, dark in draws}
    tracked = [r for r in rows if r["mode"] == "tracking" and r["i"] >= 3]
    lost = [(r["draw"], r["i"]) for r in rows
            if r["i"] >= 3 and r["i"] != darks[r["draw"]] and r["mode"] != "tracking"]
    relocks = [_frames_to_relock(draw_rows, dark) for draw_rows, dark in draws]
    relock = None if None in relocks else max(relocks)

    def rms(key):
        v = np.array([r[key] for r in tracked])
        return float(np.sqrt(np.mean(np.square(v), axis=0)).tolist()) if len(v) else math.nan

    rate_err = np.array([r["rate_err_deg_s"] for r in tracked if r["rate_err_deg_s"]])
    sigma = np.array([r["rate_sigma_deg_s"] for r in tracked if r["rate_sigma_deg_s"]])
    return {
        "frames": len(rows), "solved": sum(r["ok"] for r in rows), "tracked": len(tracked),
        "windowed": sum(r["windows"] > 0 for r in rows), "lock_lost_frames": lost,
        "relock_frames": relock, "cross_rms_arcsec": rms("cross_arcsec"),
        "roll_rms_arcsec": rms("roll_arcsec"),
        "rate_rms_deg_s": (np.sqrt(np.mean(rate_err ** 2, axis=0)).tolist()
                           if len(rate_err) else None),
        "rate_sigma_median_deg_s": (np.median(sigma, axis=0).tolist() if len(sigma) else None),
        "frame_ms_median": float(np.median([r["ms"] for r in tracked])) if tracked else math.nan,
        "frame_cpu_ms_median": (float(np.median([r["cpu_ms"] for r in tracked]))
                                if tracked else math.nan),
        "detect_ms_median": (float(np.median([r["detect_ms"] for r in tracked]))
                             if tracked else math.nan),
        "identify_ms_median": (float(np.median([r["identify_ms"] for r in tracked]))
                               if tracked else math.nan),
    }


def _row(i: int, result, R_true, rate_deg_s) -> dict:
    sol = result.solution
    detect = sum(v for k, v in result.stages_ms.items() if k.startswith(("detect.", "windows.")))
    identify = sum(v for k, v in result.stages_ms.items() if k.startswith("identify."))
    row = {"i": i, "ok": bool(sol is not None and sol.ok), "mode": None, "windows": result.windows,
           "ms": result.time_ms, "detect_ms": detect, "identify_ms": identify,
           "cpu_ms": result.cpu_ms, "detect_cpu_ms": result.detect_cpu_ms,
           "stars": int(result.detections.count), "rate_err_deg_s": None,
           "rate_sigma_deg_s": None, "stages_ms": dict(result.stages_ms)}
    if row["ok"]:
        cross, roll = attitude_error(sol.R, R_true)
        row.update(mode=sol.mode, cross_arcsec=cross * _ARCSEC, roll_arcsec=roll * _ARCSEC,
                   matched=sol.matched)
        if sol.rate_rad_s is not None:
            row["rate_err_deg_s"] = (np.degrees(sol.rate_rad_s) - rate_deg_s).tolist()
            row["rate_sigma_deg_s"] = np.degrees(sol.sigma_rate_rad_s).tolist()
    return row


def _run_draw(cfg: Config, catalogue, rate: float, n: int, fps: float, exposure_ms: float,
              peer_frames: int, rng: np.random.Generator, draw: int) -> dict:
    """One draw of a scenario (module docstring): both arms' rows, the peers' ms, its truth."""
    cam = cfg.camera
    seen_lens = dataclasses.replace(cam, focal_length_mm=cam.focal_length_mm
                                    * (1 + rng.uniform(-0.02, 0.02)))
    psf = float(rng.uniform(1.0, 1.6))
    sim = dataclasses.replace(cfg.sim, psf_sigma_px=psf, exposure_ms=exposure_ms)
    axis = rng.normal(size=3)
    rate_deg_s = axis / np.linalg.norm(axis) * rate
    dark = n // 2
    arms = {"full": Pipeline(dataclasses.replace(cfg, identify=dataclasses.replace(
        cfg.identify, track_windows=False))), "windows": Pipeline(cfg)}
    rows: dict[str, list] = {a: [] for a in ARMS}
    peers: dict[str, list] = {name: [] for name in PEERS if peer_available(name)}
    frames = render_sequence(seen_lens, catalogue, random_attitude(rng), sim, rng, n, fps=fps,
                             rate_deg_s=tuple(rate_deg_s))
    for i, frame in enumerate(frames):
        image = (np.full_like(frame.image, int(np.median(frame.image))) if i == dark
                 else frame.image)
        t_ns = int(round(i * 1e9 / fps))
        for arm in (ARMS if i % 2 == 0 else ARMS[::-1]):      # alternate who goes first
            result = arms[arm].process(image, cam.bit_depth, t_ns, exposure_s=exposure_ms / 1e3)
            rows[arm].append(_row(i, result, frame.R, rate_deg_s) | {"draw": draw})
        if i < peer_frames:
            for name in peers:
                t0 = time.perf_counter()
                PEERS[name](image)
                peers[name].append((time.perf_counter() - t0) * 1e3)
    return {"psf_sigma_px": psf, "focal_length_mm": seen_lens.focal_length_mm,
            "rate_vector_deg_s": rate_deg_s.tolist(), "dark_frame": dark, "rows": rows,
            "peers_ms": peers}


def run_scenario(cfg: Config, catalogue, lens_mm: float, rate: float, seconds: float,
                 fps: float, exposure_ms: float, peer_frames: int,
                 rng: np.random.Generator, draws: int = 1) -> dict:
    """One scenario of ``draws`` draws (module docstring): both arms' per-frame rows (each
    with its draw), their statistics pooled over the draws, and each draw's truth and
    windowed/full cross and roll ratios."""
    cam = dataclasses.replace(cfg.camera, focal_length_mm=lens_mm)
    cfg = dataclasses.replace(cfg, camera=cam)
    n = max(8, int(round(seconds * fps)))
    # the first draw continues the bench's stream, so a scenario's first draw (and every
    # later scenario) is the same whatever the number of draws; the others have streams of
    # their own, spawned from the seed
    draw_rngs = [rng, *rng.spawn(draws - 1)]
    runs = [_run_draw(cfg, catalogue, rate, n, fps, exposure_ms, peer_frames, draw_rng, d)
            for d, draw_rng in enumerate(draw_rngs)]
    rows = {arm: [r for run in runs for r in run["rows"][arm]] for arm in ARMS}
    stats = {arm: _arm_stats([(run["rows"][arm], run["dark_frame"]) for run in runs])
             for arm in ARMS}
    per_draw = []
    for run in runs:
        draw_stats = {arm: _arm_stats([(run["rows"][arm], run["dark_frame"])]) for arm in ARMS}
        per_draw.append({k: run[k] for k in ("psf_sigma_px", "focal_length_mm",
                                             "rate_vector_deg_s", "dark_frame")}
                        | {f"{axis}_ratio": draw_stats["windows"][f"{axis}_rms_arcsec"]
                           / draw_stats["full"][f"{axis}_rms_arcsec"]
                           for axis in ("cross", "roll")})
    full_rows = [r for r in rows["full"] if r["i"] >= 3]
    full_detect = float(np.median([r["detect_ms"] for r in full_rows]))
    full_detect_cpu = float(np.median([r["detect_cpu_ms"] for r in full_rows]))
    full_by_frame = {(r["draw"], r["i"]): r for r in rows["full"]}
    paired = [w["ms"] / full_by_frame[w["draw"], w["i"]]["detect_ms"] for w in rows["windows"]
              if w["i"] >= 3 and w["mode"] == "tracking"
              and full_by_frame[w["draw"], w["i"]]["detect_ms"] > 0]
    peers = {name: [ms for run in runs for ms in run["peers_ms"][name]]
             for name in runs[0]["peers_ms"]}
    return {"lens_mm": lens_mm, "rate_deg_s": rate, "seconds": seconds, "frames": n * draws,
            "draws": per_draw, "full_detect_ms_median": full_detect,
            "full_detect_cpu_ms_median": full_detect_cpu,
            "cost_ratio": stats["windows"]["frame_ms_median"] / full_detect,
            "paired_ratio_median": float(np.median(paired)) if paired else math.nan,
            "cpu_ratio": stats["windows"]["frame_cpu_ms_median"] / full_detect_cpu,
            "detect_ratio": stats["windows"]["detect_ms_median"] / full_detect,
            "peers_ms_median": {k: float(np.median(v)) for k, v in peers.items() if v},
            "stats": stats, "rows": rows}


def memory_run(cfg: Config, catalogue, frames: int, warmup: int, seed: int) -> dict:
    """The whole service on one still frame replayed in a loop (module docstring)."""
    tmp = Path(tempfile.mkdtemp(prefix="bench-track-"))
    rng = np.random.default_rng(seed)
    write_frame(render_sky(cfg.camera, catalogue, random_attitude(rng), cfg.sim, rng), tmp,
                "still")
    cfg = dataclasses.replace(
        cfg, capture=dataclasses.replace(cfg.capture, backend="replay", loop=True, fps=0.0,
                                         replay_path=str(tmp / "still.png")),
        link=dataclasses.replace(cfg.link, port=str(tmp / "fcu")),
        service=dataclasses.replace(cfg.service, frames=0, watchdog_s=0.0))
    fc = ReplugPty(tmp / "fcu")
    stop = threading.Event()
    daemon = Daemon(cfg, source_factory=lambda: make_source(cfg), pipeline=Pipeline(cfg),
                    link=DaemonLink(cfg), notifier=Notifier(""))
    seen = {"k": 0, "windowed": 0, "held": {}, "cells": {}}

    def on_frame(report):
        k = seen["k"] = seen["k"] + 1
        seen["windowed"] += any(name.startswith("windows.") for name in report.stages_ms)
        if k in (warmup, frames):
            seen["held"][k] = tracemalloc.get_traced_memory()[0]
            seen["cells"][k] = daemon.pipeline.window_cells
        if k == frames:
            daemon.request_stop()

    daemon.on_frame = on_frame
    daemon.pipeline.solver  # noqa: B018  (catalogue and database: start-up, not per frame)
    drainer = threading.Thread(target=fc.drain_until, args=(stop,), daemon=True)
    drainer.start()
    tracemalloc.start()
    t0 = time.monotonic()
    try:
        daemon.run()
    finally:
        tracemalloc.stop()
        stop.set()
        drainer.join(5)
        fc.close()
    wall = time.monotonic() - t0
    held = seen["held"]
    return {"frames": seen["k"], "windowed_frames": seen["windowed"], "warmup": warmup,
            "growth_bytes": held.get(frames, math.nan) - held.get(warmup, math.nan),
            "window_cells": {"warmup": seen["cells"].get(warmup), "end": seen["cells"].get(frames)},
            "wall_s": wall, "fps": seen["k"] / wall}


def _fmt(v, spec=".1f") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v,
                                                                                        spec)


def _markdown(machine: dict, args, results: list[dict], memory: dict | None) -> str:
    lines = ["# tracker bench track", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()), "",
             f"{args.fps:g} fps, {args.exposure_ms:g} ms exposure, realistic sensor, PSF "
             "1.0-1.6 px and focal length within 2 % per draw, one dark frame per draw in the "
             f"middle; seed {args.seed}. Both arms on every frame in the same run.", "",
             "| lens | rate deg/s | frames | arm | tracked | lock lost | back after dark "
             "| cross RMS\" | roll RMS\" | rate RMS deg/s (x, y, z) | frame ms | detect ms |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for arm in ARMS:
            s = r["stats"][arm]
            rate = ("-" if s["rate_rms_deg_s"] is None
                    else ", ".join(f"{v:.4f}" for v in s["rate_rms_deg_s"]))
            lines.append(
                f"| {r['lens_mm']:g} mm | {r['rate_deg_s']:g} | {r['frames']} | {arm} | "
                f"{s['tracked']} | {len(s['lock_lost_frames'])} | {_fmt(s['relock_frames'], 'd')}"
                f" | {_fmt(s['cross_rms_arcsec'], '.2f')} | {_fmt(s['roll_rms_arcsec'], '.1f')}"
                f" | {rate} | {_fmt(s['frame_ms_median'], '.2f')} | "
                f"{_fmt(s['detect_ms_median'], '.2f')} |")
    lines += ["", "| lens | rate deg/s | full-frame detection ms | windowed frame ms | "
              "ratio | windows' detection / full | paired ratio | CPU ms: full detection, "
              "windowed | CPU ratio | windowed / full cross, roll RMS | peers ms (full frame) |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        w, f = r["stats"]["windows"], r["stats"]["full"]
        peers = ", ".join(f"{k} {v:.1f}" for k, v in r["peers_ms_median"].items()) or "-"
        lines.append(
            f"| {r['lens_mm']:g} mm | {r['rate_deg_s']:g} | {r['full_detect_ms_median']:.2f} | "
            f"{_fmt(w['frame_ms_median'], '.2f')} | 1/{1 / r['cost_ratio']:.1f} | "
            f"1/{1 / r['detect_ratio']:.1f} | 1/{1 / r['paired_ratio_median']:.1f} | "
            f"{r['full_detect_cpu_ms_median']:.2f}, {_fmt(w['frame_cpu_ms_median'], '.2f')} | "
            f"1/{1 / r['cpu_ratio']:.1f} | "
            f"{w['cross_rms_arcsec'] / f['cross_rms_arcsec']:.2f}, "
            f"{w['roll_rms_arcsec'] / f['roll_rms_arcsec']:.2f} | {peers} |")
    for r in results:
        if len(r["draws"]) > 1:
            lines += ["", f"{r['lens_mm']:g} mm, {r['rate_deg_s']:g} deg/s: "
                      f"{len(r['draws'])} draws pooled above; each draw's PSF sigma, focal "
                      "length and windowed / full cross, roll RMS: " + "; ".join(
                          f"{d['psf_sigma_px']:.2f} px, {d['focal_length_mm']:.2f} mm, "
                          f"{d['cross_ratio']:.2f}, {d['roll_ratio']:.2f}" for d in r["draws"])
                      + "."]
    if memory is not None:
        lines += ["", f"Whole service, {memory['frames']} frames ({memory['windowed_frames']} "
                  f"tracked in windows), {memory['fps']:.0f} fps with tracemalloc on: Python "
                  f"memory held grew {memory['growth_bytes'] / 1024:.1f} KiB from frame "
                  f"{memory['warmup']} to the last; window detectors held (window px) then "
                  f"{memory['window_cells']['warmup']}, at the end "
                  f"{memory['window_cells']['end']} (each about 40 MiB)."]
    return "\n".join(lines) + "\n"


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    catalogue = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    results = []
    for lens, rate, seconds, draws in parse_scenarios(args.scenarios):
        print(f"track: {lens:g} mm, {rate:g} deg/s, {seconds:g} s"
              + (f", {draws} draws" if draws > 1 else ""), flush=True)
        results.append(run_scenario(cfg, catalogue, lens, rate, seconds, args.fps,
                                    args.exposure_ms, args.peer_frames, rng, draws))
    memory = None
    if args.memory_frames > 0:
        print(f"track: {args.memory_frames} frames through the service", flush=True)
        memory = memory_run(cfg, catalogue, args.memory_frames,
                            min(args.memory_warmup, args.memory_frames), args.seed)
    machine = describe_machine()
    text = _markdown(machine, args, results, memory)
    (out / "track.md").write_text(text, encoding="utf-8")
    (out / "track.json").write_text(json.dumps(
        {"machine": machine, "args": vars(args) | {"func": None}, "scenarios": results,
         "memory": memory}, indent=1, default=float), encoding="utf-8")
    print(text)
    return 0
