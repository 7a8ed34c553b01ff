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
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

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
    try:
        catalogue = Catalogue.from_config(cfg.catalogue)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    rng = np.random.default_rng(sim.seed)
    fixed = args.ra is not None
    R0 = (matrix_from_radec_roll(*np.radians(pointing)) if fixed else random_attitude(rng))
    slewing = any(sim.rate_deg_s)
    if slewing:
        frames = render_sequence(cfg.camera, catalogue, R0, sim, rng, args.frames)
    else:
        frames = (render_sky(cfg.camera, catalogue,
                             R0 if fixed or i == 0 else random_attitude(rng), sim, rng,
                             t_s=i / sim.fps)
                  for i in range(args.frames))
    progress = Progress(args.frames, "simulate")
    bright = []
    try:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        with open(Path(args.out) / METADATA_FILE, "w", encoding="utf-8") as index:
            for i, frame in enumerate(frames):
                path = write_frame(frame, args.out, f"{args.prefix}{i:04d}")
                index.write(json.dumps({"file": path.name,
                                        "t_ns": round(frame.truth["t_s"] * 1e9),
                                        "exposure_us": frame.truth["exposure_ms"] * 1e3}) + "\n")
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
