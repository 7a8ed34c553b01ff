"""``tracker validate FRAMES``: score identification against truth files.

Each frame (an image through the configured detector, or a
``*.centroids.json`` list) needs its truth beside it
(``<frame>.truth.json`` with ``stars: [{x, y, and ra_deg/dec_deg or
hip}]``, as written by ``tracker simulate`` or shipped with the real
frames). A centroid within ``--truth-px`` of a truth star is that star.

* ``--affine``: the seed method (docs/seed-method.md): the first ``--refs``
  truth stars are the hand-picked references; an affine map pixel ->
  (RA, Dec) is fitted to them; every centroid goes to the nearest catalogue
  star within ``--tolerance-deg`` (0.1).
* default: our solver (lost in space, each frame independent).

Per frame: centroids, centroids with truth, matches (right star), false
identifications (wrong star), FIR = N_false / (N_match + N_false), and the
angular error of the matched centroids' mapped directions against the true
star (mean and max, degrees; spherical law of cosines). Markdown on
stdout, ``--json FILE`` for the numbers.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from tracker.attitude import radec_to_vector, vector_to_radec
from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.commands.argtypes import positive, positive_count
from tracker.commands.calibrate import CENTROIDS_SUFFIX, expand_frames, load_stars
from tracker.commands.outputs import close_output, open_output
from tracker.errors import UserError
from tracker.identify import make_solver
from tracker.identify.affine import apply_affine, fit_affine, law_of_cosines, nearest_star
from tracker.truth import read_truth_json

__all__ = ["register", "run"]

_SAME_STAR_RAD = math.radians(30.0 / 3600.0)


def register(sub, common) -> None:
    p = sub.add_parser("validate", parents=[common], help="score star identification "
                       "against truth files (--affine: the seed method)")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="images or *.centroids.json files (truth beside each), or folders")
    p.add_argument("--affine", action="store_true",
                   help="the seed method: affine fit to reference stars, nearest HIP")
    p.add_argument("--refs", type=positive_count, default=3,
                   help="reference stars for --affine (>= 3)")
    p.add_argument("--tolerance-deg", type=positive, default=0.1,
                   help="--affine: nearest-star match tolerance")
    p.add_argument("--truth-px", type=positive, default=2.0,
                   help="a centroid this close to a truth star is that star")
    p.add_argument("--json", metavar="FILE", help="write the per-frame numbers here")
    p.set_defaults(func=run)


def _truth_file(path: Path) -> Path:
    name = path.name.removesuffix(CENTROIDS_SUFFIX)
    return path.with_name(name + ".truth.json")


def _read_truth(path: Path) -> dict:
    truth_path = _truth_file(path)
    if not truth_path.exists():
        raise UserError(f"{truth_path}: truth file not found")
    return read_truth_json(truth_path)


def _truth_vectors(truth: dict, catalogue) -> tuple[np.ndarray, np.ndarray]:
    """Truth star pixels (m, 2) and ICRS unit vectors (m, 3); stars without either dropped."""
    xy, vec = [], []
    rows = {int(h): i for i, h in enumerate(catalogue.hip)}
    for s in truth.get("stars", []):
        if s.get("ra_deg") is not None and s.get("dec_deg") is not None:
            v = radec_to_vector(math.radians(s["ra_deg"]), math.radians(s["dec_deg"]))
        elif int(s.get("hip", -1) or -1) in rows:
            v = catalogue.vectors[rows[int(s["hip"])]]
        else:
            continue
        xy.append((float(s["x"]), float(s["y"])))
        vec.append(v)
    return np.reshape(xy, (-1, 2)), np.reshape(vec, (-1, 3))


def _score(xy, mapped, picked, truth_xy, truth_vec, cat_vectors, truth_px) -> dict:
    """Matches, false identifications and errors of one frame.

    ``mapped`` (n, 3): each centroid's direction under the method; ``picked``
    (n,): the catalogue row it was identified with, -1 for none.
    """
    if len(truth_xy) == 0 or len(xy) == 0:
        return {"centroids": len(xy), "with_truth": 0, "matched": 0, "false": 0,
                "fir": math.nan, "mean_err_deg": math.nan, "max_err_deg": math.nan}
    d = np.hypot(xy[:, None, 0] - truth_xy[None, :, 0], xy[:, None, 1] - truth_xy[None, :, 1])
    t = np.argmin(d, axis=1)
    has_truth = d[np.arange(len(xy)), t] <= truth_px
    ident = has_truth & (picked >= 0)
    true_vec = truth_vec[t[ident]]
    same = np.einsum("ij,ij->i", cat_vectors[picked[ident]], true_vec) > math.cos(_SAME_STAR_RAD)
    n_match, n_false = int(same.sum()), int((~same).sum())
    ra1, dec1 = vector_to_radec(mapped[ident][same])
    ra2, dec2 = vector_to_radec(true_vec[same])
    err = np.degrees(law_of_cosines(ra1, dec1, ra2, dec2))
    return {"centroids": len(xy), "with_truth": int(has_truth.sum()), "matched": n_match,
            "false": n_false,
            "fir": n_false / (n_match + n_false) if n_match + n_false else math.nan,
            "mean_err_deg": float(err.mean()) if len(err) else math.nan,
            "max_err_deg": float(err.max()) if len(err) else math.nan}


def _affine_frame(xy, truth_xy, truth_vec, catalogue, args):
    if len(truth_xy) < args.refs:
        raise UserError(f"--affine needs {args.refs} reference stars, the truth has "
                        f"{len(truth_xy)}")
    ra, dec = vector_to_radec(truth_vec[:args.refs])
    coef, ra0 = fit_affine(truth_xy[:args.refs], ra, dec)
    ra_c, dec_c = apply_affine(coef, ra0, xy)
    picked, _ = nearest_star(catalogue.vectors, ra_c, dec_c, math.radians(args.tolerance_deg))
    return radec_to_vector(ra_c, dec_c), picked


def _solver_frame(stars, xy, solver, catalogue):
    solver.reset()
    sol = solver.solve(stars, 0)
    rows = {int(h): i for i, h in enumerate(catalogue.hip)}
    picked = np.array([rows.get(int(h), -1) if h else -1 for h in sol.hip], dtype=np.int64)
    if not sol.ok:
        return np.zeros((len(xy), 3)), picked
    return solver.camera.pixel_to_vector(xy) @ sol.R, picked


def run(args, cfg) -> int:
    if args.affine and args.refs < 3:
        raise UserError(f"--refs must be >= 3 for the affine fit, got {args.refs}")
    catalogue = Catalogue.from_config(cfg.catalogue)
    solver = None
    rows = []
    for path in expand_frames(args.frames):
        truth = _read_truth(path)
        stars, width, height = load_stars(path, cfg)
        try:
            truth_xy, truth_vec = _truth_vectors(truth, catalogue)
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise UserError(f"{_truth_file(path)}: a star without usable x, y and ra_deg/"
                            f"dec_deg or hip ({type(exc).__name__}: {str(exc)[:40]})") from None
        xy = np.column_stack([stars["x"], stars["y"]])
        if args.affine:
            mapped, picked = _affine_frame(xy, truth_xy, truth_vec, catalogue, args)
        else:
            if solver is None:
                camera = CameraModel.from_config(cfg.camera)
                if (camera.width, camera.height) != (width, height):
                    raise UserError(f"{path.name}: {width}x{height} frame, the camera "
                                    f"config says {camera.width}x{camera.height}")
                solver = make_solver(cfg.identify, camera, catalogue)
            mapped, picked = _solver_frame(stars, xy, solver, catalogue)
        row = _score(xy, mapped, picked, truth_xy, truth_vec, catalogue.vectors,
                     args.truth_px)
        rows.append({"frame": path.name, **row})
    method = "affine (seed method)" if args.affine else "lost in space (tracker.identify)"
    lines = [f"# tracker validate: {method}", "",
             "| frame | centroids | with truth | matched | false | FIR % | mean err deg "
             "| max err deg |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['frame']} | {r['centroids']} | {r['with_truth']} | {r['matched']} "
                     f"| {r['false']} | {100 * r['fir']:.1f} | {r['mean_err_deg']:.4f} "
                     f"| {r['max_err_deg']:.4f} |")
    sys.stdout.write("\n".join(lines) + "\n")
    if args.json:
        out = open_output(args.json, "--json")
        out.write(json.dumps({"method": method, "frames": rows}, indent=1))
        close_output(out)
    return 0
