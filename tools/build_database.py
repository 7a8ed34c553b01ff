"""Build the pattern databases in catalogue/ (tracker.identify.database).

Usage::

    .venv/bin/python tools/build_database.py            # the four OV2311 lenses
    .venv/bin/python tools/build_database.py --focal-mm 35 --width 1024 \
        --height 768 --pixel-um 6.9 --out build/patterns_x.npz

For each lens the design field of view is the camera's diagonal; the
database serves diagonals within +-``--fov-margin`` of it. Stars down to
``--mag-limit`` (default per lens below) are thinned brightest first to at
most ``--per-region`` in any circle of half the vertical field, and every
pair closer than the diagonal is stored. Each file's SHA-256 is written
beside it (``<file>.sha256``) and its arrays' digest inside it.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path

from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.config import CameraConfig
from tracker.identify.database import build_database, default_database_dir, save_database

# focal length (mm) -> faintest Hp used: about 35-45 database stars per frame
OV2311_LENSES = {8: 5.8, 12: 6.4, 16: 6.8, 25: 7.3}
EPOCH = 2025.0


def build_one(camera: CameraModel, mag_limit: float, per_region: int, fov_margin: float,
              out: Path, name: str, catalogue) -> dict:
    diag = math.degrees(camera.fov_diagonal_rad)
    fov_y = 2 * math.degrees(math.atan(camera.height / 2 / camera.f_px))
    built = build_database(catalogue, fov_min_deg=diag * (1 - fov_margin),
                           fov_max_deg=diag * (1 + fov_margin), mag_limit=mag_limit,
                           max_pair_deg=diag, stars_per_region=per_region,
                           region_radius_deg=fov_y / 2, name=name)
    save_database(out, built)
    digest = hashlib.sha256(out.read_bytes()).hexdigest()
    Path(f"{out}.sha256").write_text(f"{digest}  {out.name}\n", encoding="ascii")
    return built["meta"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--focal-mm", type=float, help="one lens instead of the OV2311 set")
    p.add_argument("--width", type=int, default=1600)
    p.add_argument("--height", type=int, default=1300)
    p.add_argument("--pixel-um", type=float, default=3.0)
    p.add_argument("--mag-limit", type=float, help="faintest Hp (default: per lens, or 7.0)")
    p.add_argument("--per-region", type=int, default=25,
                   help="most stars in a circle of half the vertical field")
    p.add_argument("--fov-margin", type=float, default=0.18,
                   help="served diagonal range, as a fraction of the design diagonal")
    p.add_argument("--out", type=Path, help="output file (with --focal-mm)")
    args = p.parse_args(argv)
    catalogue = load_catalogue(epoch_year=EPOCH)
    if args.focal_mm is not None:
        lenses = {args.focal_mm: args.mag_limit if args.mag_limit is not None else 7.0}
    else:
        lenses = OV2311_LENSES
    for focal, mag in lenses.items():
        cam = CameraModel.from_config(CameraConfig(
            width=args.width, height=args.height, pixel_size_um=args.pixel_um,
            focal_length_mm=focal))
        name = f"ov2311_{focal:g}mm" if args.focal_mm is None else f"custom_{focal:g}mm"
        out = args.out if args.out is not None else (
            default_database_dir() / f"patterns_{name}.npz")
        t0 = time.perf_counter()
        meta = build_one(cam, mag, args.per_region, args.fov_margin, out, name, catalogue)
        print(f"{out}: {meta['n_stars']} stars, {meta['n_pairs']} pairs, "
              f"{out.stat().st_size / 1e6:.2f} MB, diagonal {meta['fov_min_deg']:.2f}-"
              f"{meta['fov_max_deg']:.2f} deg, {time.perf_counter() - t0:.1f} s",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
