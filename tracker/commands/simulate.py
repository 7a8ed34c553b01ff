"""``tracker simulate --out DIR``: render synthetic frames with truth files.

Attitude: ``--ra/--dec/--roll`` (degrees, all three) fix the first frame's
attitude; without them it is random (seeded). With a body rate
(``--rate-deg-s X Y Z``) the frames form one slew at ``--fps``; without
one, frames at a fixed attitude repeat it with fresh noise, and random
frames each get a new random attitude (a lost-in-space test set).
Each frame is written as ``DIR/<prefix>NNNN.png`` plus
``<prefix>NNNN.png.truth.json`` (tracker.sim.io), and ``DIR/frames.jsonl``
indexes them with their time (``t_ns`` = the sequence time) and exposure,
which ``tracker replay`` reads (tracker.capture.replay).

Absolute time: ``--utc START`` (ISO 8601 UTC, the first frame's exposure
mid-point; later frames follow at 1 / fps) renders the stars where they
are seen then: proper motion to that epoch (the catalogue is propagated to
it, whatever ``catalogue.epoch_year`` says) and aberration by the Earth's
velocity plus ``--observer-velocity-km-s X Y Z`` (relative to the Earth's
centre, ICRS axes). ``frames.jsonl`` then carries each frame's ``utc`` and
``observer_velocity_km_s``, so the tracker corrects what the simulator
applied; the truth's attitude stays the ICRS one.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from tracker.astrometry.observer import check_velocity
from tracker.astrometry.timescale import (
    check_tai_ns,
    julian_year_from_tai_ns,
    tai_ns_from_utc_iso,
)
from tracker.attitude import matrix_from_radec_roll
from tracker.capture.replay import METADATA_FILE
from tracker.catalogue import Catalogue
from tracker.commands.progress import Progress
from tracker.errors import UserError
from tracker.sim import random_attitude, render_sequence, render_sky, write_frame

_NOISE_CHOICES = ("realistic", "none", "gaussian_poisson", "salt_pepper", "speckle", "glare")


def register(sub, common) -> None:
    p = sub.add_parser("simulate", parents=[common],
                       help="render synthetic star-field frames with truth JSON")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--frames", type=int, default=1, metavar="N", help="number of frames")
    p.add_argument("--seed", type=int, help="random seed (default: sim.seed)")
    p.add_argument("--ra", type=float, metavar="DEG", help="boresight right ascension")
    p.add_argument("--dec", type=float, metavar="DEG", help="boresight declination")
    p.add_argument("--roll", type=float, metavar="DEG", help="roll (tetra3 convention)")
    p.add_argument("--rate-deg-s", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="body rate about the camera axes (default: sim.rate_deg_s)")
    p.add_argument("--fps", type=float, help="frame rate of a sequence (default: sim.fps)")
    p.add_argument("--noise", choices=_NOISE_CHOICES, help="noise model (default: "
                   "sim.noise_model)")
    p.add_argument("--snr-db", type=float, help="target image SNR for the seed noise models")
    p.add_argument("--utc", metavar="START", help="the first frame's exposure mid-point, ISO "
                   "8601 UTC (e.g. 2026-03-20T21:00:00Z): stars at their apparent places "
                   "then (proper motion and aberration), utc in frames.jsonl")
    p.add_argument("--observer-velocity-km-s", type=float, nargs=3, metavar=("X", "Y", "Z"),
                   help="with --utc: the observer's velocity relative to the Earth's centre, "
                        "ICRS axes (a spacecraft in low Earth orbit: about 7.5 km/s)")
    p.add_argument("--prefix", default="f", help="file name prefix (default: f)")
    p.set_defaults(func=simulate)


def _sim_config(args, cfg):
    changes = {"seed": args.seed, "noise_model": args.noise, "snr_db": args.snr_db,
               "fps": args.fps,
               "rate_deg_s": None if args.rate_deg_s is None else tuple(args.rate_deg_s)}
    changes = {k: v for k, v in changes.items() if v is not None}
    if changes.get("seed", 0) < 0:
        raise UserError(f"--seed must be >= 0; got {args.seed}")
    if "fps" in changes and not changes["fps"] > 0:
        raise UserError(f"--fps must be > 0; got {args.fps}")
    return dataclasses.replace(cfg.sim, **changes)


def _absolute_time(args) -> tuple[int | None, tuple[float, float, float] | None]:
    """``--utc`` as TAI ns and ``--observer-velocity-km-s`` checked; UserError if unusable."""
    if args.utc is None:
        if args.observer_velocity_km_s is not None:
            raise UserError("--observer-velocity-km-s needs --utc: aberration is applied only "
                            "at a known time")
        return None, None
    try:
        start = check_tai_ns(tai_ns_from_utc_iso(args.utc))
        velocity = (None if args.observer_velocity_km_s is None else
                    check_velocity(args.observer_velocity_km_s, "--observer-velocity-km-s"))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    return start, velocity


def simulate(args, cfg) -> int:
    if args.frames < 1:
        raise UserError(f"--frames must be >= 1; got {args.frames}")
    pointing = (args.ra, args.dec, args.roll)
    if any(v is not None for v in pointing) and any(v is None for v in pointing):
        raise UserError("give all of --ra, --dec and --roll, or none of them for a random "
                        "attitude")
    if args.dec is not None and not -90.0 <= args.dec <= 90.0:
        raise UserError(f"--dec must be in [-90, 90] degrees; got {args.dec}")
    sim = _sim_config(args, cfg)
    if not all(np.isfinite(v) for v in (*pointing, *sim.rate_deg_s) if v is not None):
        raise UserError("attitude and rate must be finite numbers")
    start, velocity = _absolute_time(args)
    catalogue_cfg = cfg.catalogue
    if start is not None:     # proper motion to the frames' epoch, as the tracker will do
        catalogue_cfg = dataclasses.replace(catalogue_cfg,
                                            epoch_year=julian_year_from_tai_ns(start))
    try:
        catalogue = Catalogue.from_config(catalogue_cfg)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    rng = np.random.default_rng(sim.seed)
    fixed = args.ra is not None
    R0 = (matrix_from_radec_roll(*np.radians(pointing)) if fixed else random_attitude(rng))
    slewing = any(sim.rate_deg_s)
    if slewing:
        frames = render_sequence(cfg.camera, catalogue, R0, sim, rng, args.frames,
                                 t_tai_ns=start, observer_velocity_km_s=velocity)
    else:
        frames = (render_sky(cfg.camera, catalogue,
                             R0 if fixed or i == 0 else random_attitude(rng), sim, rng,
                             t_s=i / sim.fps, observer_velocity_km_s=velocity,
                             t_tai_ns=None if start is None else start + round(i / sim.fps * 1e9))
                  for i in range(args.frames))
    progress = Progress(args.frames, "simulate")
    bright = []
    try:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        with open(Path(args.out) / METADATA_FILE, "w", encoding="utf-8") as index:
            for i, frame in enumerate(frames):
                path = write_frame(frame, args.out, f"{args.prefix}{i:04d}")
                record = {"file": path.name, "t_ns": round(frame.truth["t_s"] * 1e9),
                          "exposure_us": frame.truth["exposure_ms"] * 1e3}
                for key in ("utc", "observer_velocity_km_s"):
                    if frame.truth.get(key) is not None:
                        record[key] = frame.truth[key]
                index.write(json.dumps(record) + "\n")
                bright.append(int(np.sum(frame.stars["in_frame"]
                                         & (frame.stars["peak_snr"] >= 5))))
                progress.advance()
    except ValueError as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:
        raise UserError(f"{args.out}: cannot write frames ({exc.strerror or exc})") from None
    finally:
        progress.close()
    print(f"wrote {args.frames} frame(s) to {args.out} ({sim.noise_model}); stars with "
          f"peak SNR >= 5 per frame: mean {np.mean(bright):.1f}, min {min(bright)}",
          file=sys.stderr)
    return 0
