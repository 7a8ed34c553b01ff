"""Aberration: the attitude against the ICRS truth, frames rendered with and without it.

For each date and each observer velocity (at rest relative to the Earth's
centre, and ``--speed-km-s`` in a random direction), frames at random
attitudes are rendered twice with the same noise (tracker.sim): once
without aberration, once as that observer sees the sky then (the Earth's
velocity plus the observer's). The catalogue is at the date's epoch in both.
Each frame goes through the whole pipeline (detector, lost in space,
refinement), lost in space every time:

* ``plain``: the frame without aberration, solved without a time;
* ``corrected``: the aberrated frame solved with its time and velocity
  (what the tracker does after TIME_SYNC and SET_VELOCITY);
* ``uncorrected``: the aberrated frame solved without them (the apparent
  attitude, what the tracker did before).

What the tracker cannot know is randomised: the PSF width per frame (1.0 to
1.6 px while the detector assumes 1.2) and the lens's focal length per date
(within 3 % of the configured one, a lens label's tolerance; each arm's
solver learns it from the frames, as in use). Errors are
cross-boresight (angle between the boresights) and roll, in arcsec against
the simulator's ICRS attitude; the target is a median cross-boresight error
of the corrected frames within 0.3 arcsec of the plain frames'. The solve
time with and without the correction is reported from the solver's own
stage timings.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from tracker.astrometry.observer import Observer, TimeSource
from tracker.astrometry.timescale import julian_year_from_tai_ns, tai_ns_from_utc_iso
from tracker.attitude import attitude_error
from tracker.bench.machine import describe_machine
from tracker.catalogue import load_catalogue
from tracker.config import Config
from tracker.pipeline import Pipeline
from tracker.sim import random_attitude, render_sky

__all__ = ["add_arguments", "run", "run_conditions", "summarise", "DATES", "ARMS"]

_ARCSEC = math.degrees(1.0) * 3600.0
# A year's quarters (the Earth's velocity turns by 90 deg between them), and two
# dates years away (the proper-motion epoch moves with the frames).
DATES = ("2026-03-20T21:00:00Z", "2026-06-21T03:00:00Z", "2026-09-22T12:00:00Z",
         "2026-12-21T18:00:00Z", "2001-05-09T00:00:00Z", "2043-11-02T06:00:00Z")
ARMS = ("plain", "corrected", "uncorrected")


def add_arguments(p) -> None:
    p.add_argument("--frames", type=int, default=10,
                   help="random attitudes per date and velocity")
    p.add_argument("--dates", default=",".join(DATES), help="ISO 8601 UTC, comma separated")
    p.add_argument("--speed-km-s", type=float, default=7.5,
                   help="the moving observer's speed relative to the Earth's centre")
    p.add_argument("--lens-mm", type=float, default=16.0, help="focal length")
    p.add_argument("--seed", type=int, default=14)


def _velocity(rng: np.random.Generator, speed: float) -> tuple[float, float, float] | None:
    if speed == 0:
        return None
    d = rng.normal(size=3)
    return tuple(float(v) for v in d / np.linalg.norm(d) * speed)


def _solve(pipeline: Pipeline, image, depth: int, R_true, observer: Observer | None) -> dict:
    pipeline.reset()                       # every frame lost in space; the lens is kept
    result = pipeline.process(image, depth, 0, observer)
    sol = result.solution
    row = {"ok": bool(sol is not None and sol.ok),
           "solve_ms": sum(v for k, v in result.stages_ms.items()
                           if k.startswith("identify."))}
    if row["ok"]:
        cross, roll = attitude_error(sol.R, R_true)
        row.update(cross_arcsec=cross * _ARCSEC, roll_arcsec=roll * _ARCSEC,
                   matched=sol.matched, focal_length_mm=sol.lens.focal_length_mm)
    return row


def run_conditions(cfg: Config, dates, speeds_km_s, frames: int, seed: int) -> list[dict]:
    """One row per (date, speed, attitude): the three arms' results (module docstring).

    Per date one lens (its focal length drawn once) and one pipeline per arm,
    each keeping its lens estimate from frame to frame as a tracker in use
    does (the arm without the observer's context must not teach the others
    aberration's scale as a focal length).
    """
    rng = np.random.default_rng(seed)
    rows = []
    depth = cfg.camera.bit_depth
    for date in dates:
        t_tai = tai_ns_from_utc_iso(date)
        epoch = julian_year_from_tai_ns(t_tai)
        day_cfg = dataclasses.replace(cfg, catalogue=dataclasses.replace(
            cfg.catalogue, epoch_year=epoch))
        pipelines = {arm: Pipeline(day_cfg) for arm in ARMS}
        sky = load_catalogue(cfg.catalogue.path, epoch)       # every star, as the sky shows
        lens = dataclasses.replace(cfg.camera, focal_length_mm=cfg.camera.focal_length_mm
                                   * (1.0 + float(rng.uniform(-0.03, 0.03))))
        for speed in speeds_km_s:
            for _ in range(frames):
                R = random_attitude(rng)
                velocity = _velocity(rng, speed)
                sim = dataclasses.replace(cfg.sim, psf_sigma_px=float(rng.uniform(1.0, 1.6)))
                noise_seed = int(rng.integers(2**32))
                plain = render_sky(lens, sky, R, sim, np.random.default_rng(noise_seed))
                seen = render_sky(lens, sky, R, sim, np.random.default_rng(noise_seed),
                                  t_tai_ns=t_tai, observer_velocity_km_s=velocity)
                observer = Observer(t_tai, velocity, TimeSource.RECORD)
                rows.append({
                    "date": date, "speed_km_s": speed, "velocity_km_s": velocity,
                    "focal_length_mm": lens.focal_length_mm,
                    "plain": _solve(pipelines["plain"], plain.image, depth, R, None),
                    "corrected": _solve(pipelines["corrected"], seen.image, depth, R,
                                        observer),
                    "uncorrected": _solve(pipelines["uncorrected"], seen.image, depth, R,
                                          None)})
    return rows


def _stats(rows: list[dict], arm: str) -> dict:
    ok = [r[arm] for r in rows if r[arm]["ok"]]
    cross = np.array([s["cross_arcsec"] for s in ok])
    roll = np.array([s["roll_arcsec"] for s in ok])
    ms = np.array([r[arm]["solve_ms"] for r in rows])
    nan = math.nan
    return {"frames": len(rows), "solved": len(ok),
            "cross_median": float(np.median(cross)) if len(cross) else nan,
            "cross_rms": float(np.sqrt(np.mean(cross ** 2))) if len(cross) else nan,
            "roll_rms": float(np.sqrt(np.mean(roll ** 2))) if len(roll) else nan,
            "solve_ms_median": float(np.median(ms)) if len(ms) else nan}


def summarise(rows: list[dict]) -> dict:
    """Per speed and overall: each arm's statistics and the corrected - plain medians."""
    out = {}
    groups = {f"{s:g} km/s": [r for r in rows if r["speed_km_s"] == s]
              for s in sorted({r["speed_km_s"] for r in rows})}
    groups["all"] = rows
    for name, sel in groups.items():
        arms = {arm: _stats(sel, arm) for arm in ARMS}
        arms["median_difference_arcsec"] = (arms["corrected"]["cross_median"]
                                            - arms["plain"]["cross_median"])
        out[name] = arms
    return out


def _markdown(machine: dict, args, summary: dict, dates) -> str:
    lines = ["# tracker bench aberration", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()), "",
             f"{args.frames} random attitudes per date and velocity, {args.lens_mm:g} mm lens, "
             f"realistic sensor, PSF 1.0-1.6 px, focal length within 3 % (one lens per "
             f"date); seed {args.seed}. "
             f"Dates (UTC): {', '.join(dates)}. Velocity relative to the Earth's centre: 0 and "
             f"{args.speed_km_s:g} km/s in a random direction. Errors against the ICRS truth, "
             "arcsec.", "",
             "| observer | frames | plain: median cross (RMS) | corrected: median cross (RMS) "
             "| uncorrected: median cross (RMS) | corrected - plain | roll RMS plain / "
             "corrected | solve ms plain / corrected |",
             "|---|---|---|---|---|---|---|---|"]
    for name, arms in summary.items():
        p, c, u = arms["plain"], arms["corrected"], arms["uncorrected"]
        lines.append(
            f"| {name} | {c['solved']}/{c['frames']} | {p['cross_median']:.2f} "
            f"({p['cross_rms']:.2f}) | {c['cross_median']:.2f} ({c['cross_rms']:.2f}) | "
            f"{u['cross_median']:.2f} ({u['cross_rms']:.2f}) | "
            f"{arms['median_difference_arcsec']:+.2f} | {p['roll_rms']:.1f} / "
            f"{c['roll_rms']:.1f} | {p['solve_ms_median']:.1f} / {c['solve_ms_median']:.1f} |")
    return "\n".join(lines) + "\n"


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cfg = dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera,
                                                              focal_length_mm=args.lens_mm))
    dates = [d.strip() for d in args.dates.split(",") if d.strip()]
    rows = run_conditions(cfg, dates, (0.0, args.speed_km_s), args.frames, args.seed)
    summary = summarise(rows)
    machine = describe_machine()
    text = _markdown(machine, args, summary, dates)
    (out / "aberration.md").write_text(text, encoding="utf-8")
    (out / "aberration.json").write_text(json.dumps(
        {"machine": machine, "args": vars(args) | {"func": None}, "summary": summary,
         "rows": rows}, indent=1, default=str), encoding="utf-8")
    print(text)
    return 0
