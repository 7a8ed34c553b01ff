"""``tracker calibrate FRAMES --out CONFIG.yaml``: fit the lens from solved star fields.

Each frame (an image, run through the configured detector, or a
``*.centroids.json`` list with ``width``, ``height`` and ``stars: [{x, y,
flux}]``) is solved lost in space with the configured camera; when that
fails the focal length is swept over +-``--scale-range`` in 0.5 % steps with
looser tolerances, because real lenses differ from nominal by percents.
The identified stars of all solved frames then fix focal length, principal
point and radial distortion by bundle adjustment
(tracker.identify.calibration); the frames are identified again with the
fitted lens and the fit repeated. The configuration is written with the
``camera`` section replaced (everything else as loaded).
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from tracker.camera import CameraModel
from tracker.capture.imagefile import IMAGE_SUFFIXES, read_image
from tracker.capture.input_paths import expand_inputs
from tracker.catalogue import Catalogue
from tracker.commands.argtypes import non_negative
from tracker.config import render_yaml
from tracker.detect import STAR_DTYPE, make_detector
from tracker.errors import UserError
from tracker.identify.calibration import CalibrationFrame, calibrate
from tracker.identify.database import PatternDatabase, find_database
from tracker.identify.solver import Solver

__all__ = ["register", "run", "load_stars", "expand_frames", "CENTROIDS_SUFFIX"]

_SCALE_STEP = 0.005
CENTROIDS_SUFFIX = ".centroids.json"


def register(sub, common) -> None:
    p = sub.add_parser("calibrate", parents=[common], help="fit focal length, principal "
                       "point and distortion from star fields; write a config")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="images, *.centroids.json files, or folders of them")
    p.add_argument("--out", required=True, metavar="CONFIG.yaml", help="config to write")
    p.add_argument("--fix-centre", action="store_true",
                   help="keep the principal point (advised for a single frame)")
    p.add_argument("--fit-k2", action="store_true", help="fit the r^4 distortion term too")
    p.add_argument("--scale-range", type=non_negative, default=0.08,
                   help="search the focal length within this fraction of nominal")
    p.set_defaults(func=run)


def expand_frames(paths: list[str]) -> list[Path]:
    """Images and centroid lists named, or in folders named (tracker.capture.input_paths).

    A folder holding an image and its ``<image>.centroids.json`` gives the list only.
    """
    return expand_inputs(paths, (*IMAGE_SUFFIXES, CENTROIDS_SUFFIX),
                         what="images or centroid lists", companion=CENTROIDS_SUFFIX)


def load_stars(path: Path, cfg) -> tuple[np.ndarray, int, int]:
    """(STAR_DTYPE stars, width, height) of an image or a centroid list."""
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
            rows = data["stars"]
            stars = np.zeros(len(rows), dtype=STAR_DTYPE)
            for key in ("x", "y", "flux"):
                stars[key] = [float(r[key]) for r in rows]
            return stars, int(data["width"]), int(data["height"])
        except (ValueError, KeyError, TypeError) as exc:
            raise UserError(f"{path}: not a centroid list ({exc})") from None
    image, bit_depth = read_image(path, bits16_depth=cfg.camera.bit_depth)
    height, width = image.shape[:2]
    det = make_detector(cfg.detect, (height, width), bit_depth).detect(image)
    return det.stars.copy(), width, height


def _scales(scale_range: float) -> list[float]:
    n = int(round(scale_range / _SCALE_STEP))
    out = [1.0]
    for k in range(1, n + 1):
        out += [1.0 + k * _SCALE_STEP, 1.0 - k * _SCALE_STEP]
    return out


def _solve_frame(stars, camera: CameraModel, cfg_id, bound, catalogue, scales):
    """(camera used, Solution) for the first scale that solves, or (None, last)."""
    sol = None
    for s in scales:
        cam = dataclasses.replace(camera, f_px=camera.f_px * s)
        loose = s != 1.0
        ident = dataclasses.replace(
            cfg_id, pair_tolerance_px=max(cfg_id.pair_tolerance_px, 4.0 if loose else 0.0),
            match_radius_px=max(cfg_id.match_radius_px, 4.0 if loose else 0.0),
            max_lis_ms=max(cfg_id.max_lis_ms, 2000.0))
        sol = Solver(ident, cam, bound, catalogue).solve(stars, 0)
        if sol.ok:
            return cam, sol
    return None, sol


def _frame(stars, sol, catalogue, by_hip) -> CalibrationFrame:
    ok = sol.hip > 0
    rows = by_hip[np.searchsorted(catalogue.hip[by_hip], sol.hip[ok])]
    xy = np.stack((stars["x"][ok], stars["y"][ok]), axis=1)
    return CalibrationFrame(xy=xy, ref=np.asarray(catalogue.vectors[rows]), R=sol.R)


def run(args, cfg) -> int:
    paths = expand_frames(args.frames)
    loaded = [(p, *load_stars(p, cfg)) for p in paths]
    sizes = {(w, h) for _, _, w, h in loaded}
    if len(sizes) != 1:
        raise UserError(f"frames of different sizes {sorted(sizes)}: calibrate one camera "
                        "at a time")
    width, height = sizes.pop()
    cam_cfg = dataclasses.replace(cfg.camera, width=width, height=height)
    nominal = CameraModel.from_config(cam_cfg)
    catalogue = Catalogue.from_config(cfg.catalogue)
    by_hip = np.argsort(catalogue.hip)
    db_path = cfg.identify.database or find_database(nominal.fov_diagonal_rad)
    bound = PatternDatabase.load(db_path).bind(catalogue)
    frames, camera = [], nominal
    for path, stars, _, _ in loaded:
        cam, sol = _solve_frame(stars, nominal, cfg.identify, bound, catalogue,
                                _scales(args.scale_range))
        if cam is None:
            print(f"{path.name}: not solved ({sol.reason})", file=sys.stderr)
            continue
        print(f"{path.name}: solved with f = {cam.f_px:.1f} px, {sol.matched} stars",
              file=sys.stderr)
        camera = cam
        frames.append((stars, _frame(stars, sol, catalogue, by_hip)))
    if not frames:
        raise UserError("no frame could be solved; check the camera section "
                        "(size, pixel_size_um, focal_length_mm)")
    result = calibrate(camera, [f for _, f in frames], fit_centre=not args.fix_centre,
                       fit_k2=args.fit_k2)
    # identify again with the fitted lens: more and surer matches
    again = []
    for stars, _ in frames:
        sol = Solver(cfg.identify, result.camera, bound, catalogue).solve(stars, 0)
        if sol.ok:
            again.append(_frame(stars, sol, catalogue, by_hip))
    if again:
        result = calibrate(result.camera, again, fit_centre=not args.fix_centre,
                           fit_k2=args.fit_k2)
    cam = result.camera
    new_camera = dataclasses.replace(
        cam_cfg, focal_length_mm=cam.f_px * cam_cfg.pixel_size_um / 1000.0,
        cx=round(cam.cx, 3), cy=round(cam.cy, 3), k1=float(f"{cam.k1:.6g}"),
        k2=float(f"{cam.k2:.6g}"))
    out_cfg = dataclasses.replace(cfg, camera=new_camera)
    Path(args.out).write_text(render_yaml(out_cfg), encoding="utf-8")
    scale = 206264.806 / cam.f_px
    print(f"{args.out}: {len(again) or len(frames)} frames, {result.stars} stars "
          f"({result.rejected} rejected), RMS {result.rms_px:.3f} px; f = {cam.f_px:.2f} px "
          f"({new_camera.focal_length_mm:.4f} mm, {scale:.3f} arcsec/px), cx {cam.cx:.2f}, "
          f"cy {cam.cy:.2f}, k1 {cam.k1:.4g}, k2 {cam.k2:.4g}; nominal f "
          f"{nominal.f_px:.2f} px ({100 * (cam.f_px / nominal.f_px - 1):+.2f} %), diagonal "
          f"FOV {math.degrees(cam.fov_diagonal_rad):.3f} deg", file=sys.stderr)
    return 0
