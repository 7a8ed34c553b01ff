"""``tracker calibrate FRAMES --out CONFIG.yaml``: fit the lens from solved star fields.

Each frame (an image, run through the configured detector, or a
``*.centroids.json`` list with ``width``, ``height`` and ``stars: [{x, y,
flux}]``; an image and its centroid list count once, the list is used) is
solved lost in space with the focal length unknown within
+-``--scale-range`` of the configured one. The range is searched in pieces
of +-10 % (each with the pattern database for its field, built once into
the cache), the configured focal length first and then outward, so a lens
label 20 % off is found. The identified stars of all solved frames then fix
focal length, principal point and radial distortion by bundle adjustment
(tracker.identify.calibration); the frames are identified again with the
fitted lens and the fit repeated. The configuration is written with the
``camera`` section replaced (everything else as loaded). Progress goes to
standard error.
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
from tracker.identify import make_solver
from tracker.identify.calibration import CalibrationFrame, calibrate
from tracker.identify.database import ProgressLines

__all__ = ["register", "run", "load_stars", "expand_frames", "search_pieces",
           "CENTROIDS_SUFFIX"]

CENTROIDS_SUFFIX = ".centroids.json"
_PIECE = 0.1          # each piece of the search covers +-10 % of its centre
_STEP = 1.2           # centres of neighbouring pieces differ by this factor


def register(sub, common) -> None:
    p = sub.add_parser("calibrate", parents=[common], help="fit focal length, principal "
                       "point and distortion from star fields; write a config")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="images, *.centroids.json files, or folders of them")
    p.add_argument("--out", required=True, metavar="CONFIG.yaml", help="config to write")
    p.add_argument("--fix-centre", action="store_true",
                   help="keep the principal point (advised for a single frame)")
    p.add_argument("--fit-k2", action="store_true", help="fit the r^4 distortion term too")
    p.add_argument("--scale-range", type=non_negative, default=0.3,
                   help="search focal lengths within this fraction of camera.focal_length_mm: "
                        "the default 0.3 searches 0.7-1.3 times it (11.2-20.8 mm for 16 mm), "
                        "in pieces of +-10 %%, the configured value first")
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


def search_pieces(scale_range: float) -> list[float]:
    """Focal-length factors of the pieces' centres: 1 first, then outward, both sides.

    Each piece covers +-10 % of its centre; centres are a factor 1.2 apart
    (so neighbours overlap) until the range +-scale_range is covered.
    """
    out = [1.0]
    k = 1
    while True:
        added = False
        for c in (_STEP ** k, _STEP ** -k):
            if (c > 1 and c * (1 - _PIECE) < 1 + scale_range) or \
                    (c < 1 and c * (1 + _PIECE) > 1 - scale_range):
                out.append(c)
                added = True
        if not added:
            return out
        k += 1


def _frame(stars, sol, catalogue, by_hip) -> CalibrationFrame:
    ok = sol.hip > 0
    rows = by_hip[np.searchsorted(catalogue.hip[by_hip], sol.hip[ok])]
    xy = np.stack((stars["x"][ok], stars["y"][ok]), axis=1)
    return CalibrationFrame(xy=xy, ref=np.asarray(catalogue.vectors[rows]), R=sol.R)


def _progress() -> ProgressLines:
    return ProgressLines(lambda text: print(f"  {text}", file=sys.stderr), steps=4,
                         prefix="building the pattern database for this field")


class _Solvers:
    """One solver per piece of the focal-length search, made when first needed."""

    def __init__(self, cfg, nominal: CameraModel, catalogue, scale_range: float):
        self.cfg, self.nominal, self.catalogue = cfg, nominal, catalogue
        self.pieces = search_pieces(scale_range)
        self._made: dict[float, object] = {}

    def solver(self, centre: float):
        if centre not in self._made:
            cam = dataclasses.replace(self.nominal, f_px=self.nominal.f_px * centre)
            ident = dataclasses.replace(self.cfg.identify, focal_tolerance=_PIECE,
                                        focal_search=0.0)
            print(f"  searching {self._mm(cam.f_px * (1 - _PIECE))}-"
                  f"{self._mm(cam.f_px * (1 + _PIECE))}", file=sys.stderr)
            self._made[centre] = make_solver(ident, cam, self.catalogue, _progress())
        return self._made[centre]

    def _mm(self, f_px: float) -> str:
        return f"{f_px * self.cfg.camera.pixel_size_um / 1000:.2f} mm"

    def solve(self, stars):
        """The first piece's solution that holds (pieces in order), or the last failure."""
        sol = None
        for centre in self.pieces:
            solver = self.solver(centre)
            solver.reset()
            sol = solver.solve(stars, 0)
            if sol.ok:
                return sol
        return sol


def run(args, cfg) -> int:
    if not 0.0 <= args.scale_range <= 0.6:
        raise UserError(f"--scale-range: found {args.scale_range}, expected 0-0.6")
    paths = expand_frames(args.frames)
    if not paths:
        raise UserError("no frames: give images, *.centroids.json files or folders of them")
    loaded = []
    for i, p in enumerate(paths, 1):
        print(f"[{i}/{len(paths)}] reading {p.name}", file=sys.stderr)
        loaded.append((p, *load_stars(p, cfg)))
    sizes = {(w, h) for _, _, w, h in loaded}
    if len(sizes) != 1:
        raise UserError(f"frames of different sizes {sorted(sizes)}: calibrate one camera "
                        "at a time")
    width, height = sizes.pop()
    cam_cfg = dataclasses.replace(cfg.camera, width=width, height=height)
    nominal = CameraModel.from_config(cam_cfg)
    catalogue = Catalogue.from_config(cfg.catalogue)
    by_hip = np.argsort(catalogue.hip)
    solvers = _Solvers(dataclasses.replace(cfg, camera=cam_cfg), nominal, catalogue,
                       args.scale_range)
    frames = []
    camera = nominal
    for i, (path, stars, _, _) in enumerate(loaded, 1):
        sol = solvers.solve(stars)
        if not sol.ok:
            print(f"[{i}/{len(loaded)}] {path.name}: not solved ({sol.reason})", file=sys.stderr)
            continue
        print(f"[{i}/{len(loaded)}] {path.name}: solved, {sol.matched} stars, f = "
              f"{sol.focal_length_mm:.3f} mm", file=sys.stderr)
        camera = dataclasses.replace(nominal, f_px=sol.focal_length_mm * 1000
                                     / cam_cfg.pixel_size_um)
        frames.append((stars, _frame(stars, sol, catalogue, by_hip)))
    if not frames:
        raise UserError("no frame could be solved; check the camera section "
                        "(size, pixel_size_um, focal_length_mm) or widen --scale-range")
    print(f"fitting the lens to {len(frames)} frames", file=sys.stderr)
    result = calibrate(camera, [f for _, f in frames], fit_centre=not args.fix_centre,
                       fit_k2=args.fit_k2)
    # identify again with the fitted lens: more and surer matches
    fitted = dataclasses.replace(cam_cfg, focal_length_mm=result.camera.f_px
                                 * cam_cfg.pixel_size_um / 1000.0, cx=result.camera.cx,
                                 cy=result.camera.cy, k1=result.camera.k1, k2=result.camera.k2)
    again_solver = make_solver(dataclasses.replace(cfg.identify, focal_search=0.0),
                               CameraModel.from_config(fitted), catalogue, _progress())
    again = []
    for stars, _ in frames:
        again_solver.reset()
        sol = again_solver.solve(stars, 0)
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
          f"cy {cam.cy:.2f}, k1 {cam.k1:.4g}, k2 {cam.k2:.4g}; configured f "
          f"{nominal.f_px:.2f} px ({100 * (cam.f_px / nominal.f_px - 1):+.2f} %), diagonal "
          f"FOV {math.degrees(cam.fov_diagonal_rad):.3f} deg", file=sys.stderr)
    return 0
