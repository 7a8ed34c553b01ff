"""On the device: per-stage ms, the frame rate processing allows, CPU temperature; run it on the Pi.

Renders one slew (``--lens-mm``, ``--rate-deg-s``, ``--seconds`` at ``--fps``,
``--exposure-ms``; tracker.sim) and runs it through the windowed and the
full-frame pipelines in turn, as ``tracker bench track`` does
(:func:`tracker.bench.track.run_scenario`). Prints and writes
(``device.md``/``.json``) the machine, the SoC temperature and throttling
state before and after, and for each arm the median ms of every stage and of
the whole frame over the tracked frames, with the frame rate that
processing alone allows (1000 / median frame ms). Capture of frame N+1
overlaps the processing of frame N (tracker.daemon.capture_ahead), so the
service keeps the camera's rate while that figure is above it; ``tracker
selftest`` measures the camera's own rate.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from tracker.bench.machine import describe_machine
from tracker.bench.track import ARMS, run_scenario
from tracker.board import THROTTLE_BITS, cpu_temperature_c, throttled
from tracker.catalogue import load_catalogue

__all__ = ["add_arguments", "run", "stage_medians"]


def add_arguments(p) -> None:
    p.add_argument("--lens-mm", type=float, default=16.0)
    p.add_argument("--rate-deg-s", type=float, default=1.0)
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--exposure-ms", type=float, default=20.0)
    p.add_argument("--seed", type=int, default=13)


def _board() -> dict:
    temp = cpu_temperature_c()
    try:
        value = throttled()
    except (OSError, ValueError):
        value = None
    flags = ([text for bit, text in THROTTLE_BITS.items() if value >> bit & 1]
             if value is not None else None)
    return {"cpu_temp_c": temp, "throttled": None if value is None else f"0x{value:x}",
            "throttle_flags": flags}


def stage_medians(rows: list[dict]) -> dict:
    """Median ms per stage (over the tracked frames that ran it) and of the tracked frame."""
    tracked = [r for r in rows if r["mode"] == "tracking"]
    names = sorted({name for r in tracked for name in r["stages_ms"]})
    out = {name: float(np.median([r["stages_ms"][name] for r in tracked
                                  if name in r["stages_ms"]])) for name in names}
    out["frame"] = float(np.median([r["ms"] for r in tracked])) if tracked else math.nan
    return out


def _celsius(board: dict) -> str:
    return "unknown" if board["cpu_temp_c"] is None else f"{board['cpu_temp_c']:.1f} C"


def _markdown(report: dict) -> str:
    b0, b1 = report["board_before"], report["board_after"]
    lines = ["# tracker bench device", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in report["machine"].items()), "",
             f"SoC temperature {_celsius(b0)} before, {_celsius(b1)} after; "
             f"throttled {b0['throttled']} before, {b1['throttled']} after "
             f"({', '.join(b1['throttle_flags'] or []) or 'none'}).", "",
             f"{report['frames']} frames, {report['lens_mm']:g} mm, {report['rate_deg_s']:g} "
             f"deg/s, {report['exposure_ms']:g} ms exposure.", "",
             "| stage | " + " | ".join(f"{arm} ms" for arm in ARMS) + " |",
             "|---|" + "---|" * len(ARMS)]
    names = sorted(set().union(*(report["stages"][arm] for arm in ARMS)) - {"frame"})
    for name in [*names, "frame"]:
        cells = " | ".join(f"{report['stages'][arm][name]:.2f}" if name in report["stages"][arm]
                           else "-" for arm in ARMS)
        lines.append(f"| {name} | {cells} |")
    lines += ["", "Frame rate processing allows: " + ", ".join(
        f"{arm} {report['fps'][arm]:.0f} fps" for arm in ARMS)
        + f"; lock lost in {report['lock_lost']} frames."]
    return "\n".join(lines) + "\n"


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    before = _board()
    catalogue = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    result = run_scenario(cfg, catalogue, args.lens_mm, args.rate_deg_s, args.seconds,
                          args.fps, args.exposure_ms, 0, np.random.default_rng(args.seed))
    stages = {arm: stage_medians(result["rows"][arm]) for arm in ARMS}
    report = {"machine": describe_machine(), "board_before": before, "board_after": _board(),
              "frames": result["frames"], "lens_mm": args.lens_mm,
              "rate_deg_s": args.rate_deg_s, "exposure_ms": args.exposure_ms,
              "stages": stages, "fps": {arm: 1000.0 / stages[arm]["frame"] for arm in ARMS},
              "lock_lost": len(result["stats"]["windows"]["lock_lost_frames"])}
    text = _markdown(report)
    (out / "device.md").write_text(text, encoding="utf-8")
    (out / "device.json").write_text(json.dumps(report, indent=1, default=float),
                                     encoding="utf-8")
    print(text)
    return 0
