"""Library API: tracker.solve on full frames against the pipeline it wraps, and its first call.

``--frames`` frames of the configured camera (default: the OV2311 with a
16 mm lens) are rendered at random pointings with the realistic sensor
model. Each is solved lost in space three ways, in turn, so machine load
falls on all alike:

- ``tracker.solve(array)``, the library call;
- ``Pipeline.process`` on the same array, reset before each frame as the
  API resets it (what ``tracker replay`` runs);
- ``tracker.solve(path)`` on the frame written as a PNG (reading included).

Reported: the median and 90th percentile wall time of each, the ratio of
the API's median to the pipeline's, the time of the very first call in this
process (it loads the catalogue and the pattern database; the database is
built beforehand, so no build is timed), the solve rate and the attitude
error against the simulator's truth. Reports: ``api.md``, ``api.json``.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

import tracker
from tracker.attitude import attitude_error, matrix_from_quat
from tracker.bench.machine import describe_machine
from tracker.camera import CameraModel
from tracker.catalogue import Catalogue, load_catalogue
from tracker.identify import database_for
from tracker.pipeline import Pipeline
from tracker.sim import random_attitude, render_sky, write_frame

_ARCSEC = 180 * 3600 / np.pi


def add_arguments(parser) -> None:
    parser.add_argument("--frames", type=int, default=20, help="frames solved each way")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the pointings")


def _timed(call) -> tuple[object, float]:
    t0 = time.perf_counter()
    value = call()
    return value, (time.perf_counter() - t0) * 1e3


def _stats(ms: list[float]) -> dict:
    return {"median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90))}


def run(args, cfg) -> int:
    camera = CameraModel.from_config(cfg.camera)
    database_for(cfg.identify, camera, Catalogue.from_config(cfg.catalogue))   # built first
    catalogue = load_catalogue(epoch_year=2026.0)
    rng = np.random.default_rng(args.seed)
    frames = [render_sky(cfg.camera, catalogue, random_attitude(rng), cfg.sim, rng)
              for _ in range(args.frames)]
    first, first_ms = _timed(lambda: tracker.solve(frames[0].image, cfg))
    pipeline = Pipeline(cfg)
    times: dict[str, list[float]] = {"api_array": [], "pipeline": [], "api_file": []}
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-api-") as folder:
        for i, frame in enumerate(frames):
            path = write_frame(frame, folder, f"f{i:04d}")
            result, ms = _timed(lambda f=frame: tracker.solve(f.image, cfg))
            times["api_array"].append(ms)
            results.append(result)
            pipeline.reset(lens=True)
            _, ms = _timed(lambda f=frame: pipeline.process(f.image, cfg.camera.bit_depth, 0))
            times["pipeline"].append(ms)
            times["api_file"].append(_timed(lambda p=path: tracker.solve(p, cfg))[1])
    errors, solved = [], 0
    for frame, result in zip(frames, results, strict=True):
        if result.ok:
            solved += 1
            cross, roll = attitude_error(matrix_from_quat(result.q),
                                         matrix_from_quat(frame.truth["q"]))
            errors.append((cross * _ARCSEC, roll * _ARCSEC))
    rms = np.sqrt(np.mean(np.square(errors), axis=0)) if errors else [np.nan, np.nan]
    report = {
        "machine": describe_machine(), "args": vars(args) | {"func": None},
        "frame": f"{cfg.camera.width}x{cfg.camera.height}", "frames": args.frames,
        "first_call_ms": first_ms, "first_call_ok": first.ok,
        "times": {name: _stats(ms) for name, ms in times.items()},
        "api_over_pipeline": float(np.median(times["api_array"]) / np.median(times["pipeline"])),
        "solved": solved, "rms_cross_arcsec": float(rms[0]), "rms_roll_arcsec": float(rms[1]),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "api.json").write_text(json.dumps(report, indent=2) + "\n")
    text = _markdown(report)
    (out / "api.md").write_text(text)
    print(text)
    return 0 if solved else 1


def _markdown(r: dict) -> str:
    t = r["times"]
    lines = ["# Benchmark: library API", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in r["machine"].items()), "",
             f"{r['frames']} simulated {r['frame']} frames (realistic sensor, random "
             "pointings), each solved lost in space:", "",
             "| call | median ms | p90 ms |", "|---|---:|---:|"]
    names = {"api_array": "`tracker.solve(array)`",
             "pipeline": "`Pipeline.process(array)` (reset per frame)",
             "api_file": "`tracker.solve(path)` (PNG read included)"}
    for key, label in names.items():
        lines.append(f"| {label} | {t[key]['median_ms']:.1f} | {t[key]['p90_ms']:.1f} |")
    lines += ["", f"- API / pipeline, medians: {r['api_over_pipeline']:.2f}",
              f"- first call in the process (loads the catalogue and the database): "
              f"{r['first_call_ms'] / 1e3:.2f} s",
              f"- solved {r['solved']} of {r['frames']}; RMS error against the truth "
              f"{r['rms_cross_arcsec']:.2f} arcsec across the boresight, "
              f"{r['rms_roll_arcsec']:.1f} arcsec in roll", ""]
    return "\n".join(lines)
