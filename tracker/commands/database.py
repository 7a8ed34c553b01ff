"""``tracker database build | list``: the pattern databases lost in space needs.

``build`` makes, ahead of time, the database the configured camera needs
(what the service would otherwise build on its first start), in the cache
folder (``identify.cache_dir``; on the Pi the unit's state directory), with
progress; if it is already there it says so and stops. ``list`` shows the
databases found, which one is the camera's and which others would suit it
(they are not used: tracker.identify.cache).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.commands.progress import Progress
from tracker.identify import database_for
from tracker.identify.cache import cache_dir, database_file, design_for, serves
from tracker.identify.database import (
    DatabaseDesign,
    ProgressLines,
    bundled_database_dir,
    read_meta,
)

__all__ = ["register"]


def register(sub, common) -> None:
    p = sub.add_parser("database", parents=[common],
                       help="build or list the pattern databases lost in space uses")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    q = actions.add_parser("build", parents=[common],
                           help="build the database the configured camera needs (once)")
    q.add_argument("--cache-dir", metavar="DIR",
                   help="where to build it (default: identify.cache_dir, see "
                        "`tracker config`)")
    q.set_defaults(func=run_build)
    q = actions.add_parser("list", parents=[common],
                           help="list the databases found and which is the camera's")
    q.add_argument("--cache-dir", metavar="DIR", help="the cache folder to list")
    q.set_defaults(func=run_list)


def _camera_and_folder(args, cfg) -> tuple[CameraModel, Path, tuple[float, float]]:
    camera = CameraModel.from_config(cfg.camera)
    folder = Path(args.cache_dir) if args.cache_dir else cache_dir(cfg.identify.cache_dir)
    tol = cfg.identify.focal_tolerance
    return camera, folder, (camera.f_px * (1 - tol), camera.f_px * (1 + tol))


class _Bar:
    """Database build progress (stage, fraction): a bar on a terminal, else a line a fifth."""

    def __init__(self) -> None:
        self.bar = Progress(1000, "database")
        self.stage = ""
        self._lines = ProgressLines(self.bar.note)

    def __call__(self, stage: str, fraction: float) -> None:
        if stage != self.stage:
            self.stage = stage
            self.bar.label = f"database: {stage}"
        if not self.bar.enabled:
            self._lines(stage, fraction)
        self.bar.advance(max(0, int(1000 * fraction) - self.bar.count))


def run_build(args, cfg) -> int:
    camera, folder, _ = _camera_and_folder(args, cfg)
    identify = dataclasses.replace(cfg.identify, cache_dir=str(folder))
    if identify.database is not None:
        print(f"identify.database is set ({identify.database}): nothing to build",
              file=sys.stderr)
        return 0
    catalogue = Catalogue.from_config(cfg.catalogue)
    bar = _Bar()
    t0 = time.perf_counter()
    try:
        db = database_for(identify, camera, catalogue, bar)
    finally:
        bar.bar.close()
    meta = db.meta
    built = bar.stage != ""
    print(f"{db.path}: {'built' if built else 'already there'} "
          f"({time.perf_counter() - t0:.1f} s); serves {cfg.camera.width}x"
          f"{cfg.camera.height} at {cfg.camera.focal_length_mm:g} mm +- "
          f"{100 * cfg.identify.focal_tolerance:g} % ({math.degrees(camera.fov_x_rad):.2f} deg "
          f"wide); {meta['n_stars']:,} stars to Hp {meta['faintest_mag']:.2f}, "
          f"{meta['n_patterns']:,} patterns, {Path(db.path).stat().st_size / 1e6:.2f} MB",
          file=sys.stderr)
    return 0


def run_list(args, cfg) -> int:
    camera, folder, (f_low, f_high) = _camera_and_folder(args, cfg)
    own = database_file(design_for(camera), Catalogue.from_config(cfg.catalogue).sha256)
    rows = 0
    for where in (bundled_database_dir(), folder):
        for path in sorted(where.glob("patterns_*.npz")):
            meta = read_meta(path)
            if meta is None:
                print(f"{path}: not a current pattern database", file=sys.stdout)
                continue
            design = DatabaseDesign(**meta["design"])
            mark = ("  <- the camera's" if path.name == own else
                    "  (would suit the camera; not used)" if serves(design, camera, f_low, f_high)
                    else "")
            print(f"{path}: region radius {design.region_radius_deg:g} deg, "
                  f"{meta['n_stars']:,} stars to Hp {meta['faintest_mag']:.2f}, "
                  f"{meta['n_patterns']:,} patterns, {path.stat().st_size / 1e6:.2f} MB{mark}")
            rows += 1
    if not rows:
        print(f"no pattern database in {bundled_database_dir()} or {folder}; "
              "`tracker database build` makes the one the camera needs")
    return 0
