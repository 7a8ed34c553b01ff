"""Star identification with a focal length that is off: lost in space and tracking, beside tetra3.

For each lens (default: an OV2311 behind 55, 25, 16, 8 and 4.2 mm lenses,
fields of 5 to 60 deg) the bench renders frames with tracker.sim at random
attitudes and along a constant-rate slew, takes centroids, and solves the
same centroids with our solver configured with the focal length off by
each of ``--focal-errors`` (default -5 % and +5 %), and with tetra3's
``solve_from_centroids`` (cedar-solve, its default database) given the
matching field-of-view estimate and ``fov_max_error``.

Conditions (``--conditions``; what a user cannot know is drawn at random):

* ``randomised`` (default): per frame a PSF sigma from 0.8-2.5 px, centroid
  noise 1-3 times the Cramer-Rao bound, 0-8 false stars, star fluxes
  scattered by 0.3 mag (colour, vignetting); per lens a radial distortion
  k1 whose displacement at the image corner is drawn from N(0, 2 px). None
  of this was tuned on.
* ``nominal``: PSF 1.2 px, 1.5 x the bound, 2 false stars, no distortion or
  flux scatter (the settings the solver was developed on).

Centroids (``--centroids``): ``truth`` takes every rendered star whose
expected matched-filter SNR reaches ``--snr-min``, at its true position plus
Gaussian noise of the drawn multiple of the bound sqrt(2) psf_sigma / SNR
per axis (floor 0.02 px); false stars are placed uniformly with fluxes drawn
from the frame's stars. ``detect`` runs the configured detector on the image.

A solve is false when its attitude is off (image centre more than 60
arcsec or 3 pixels from the truth, or roll more than 0.1 deg or 3 pixels at
the corner) and it names a wrong star (one that is not the centroid's
source nor within 2 px of it, as a blend partner would be, or a false
star): a wrong identification. "Outside" counts solves off by as much that
name only right stars (a tight cluster of five stars fixes the roll poorly;
the reported sigma says so); "mislabelled" counts solves within the
tolerances that name some wrong star (tetra3 matches within 1 % of the
field, so a false star near a catalogue star takes its name). Rates are by the number of detectable
stars (>= 8, 5-7, < 5); the focal length is scored on frames with at least
15 matched stars, against 0.1 % and against its own reported sigma. Times
are wall clock and the CPU time of the solving thread (the machine may be
shared). Lost-in-space frames are independent: the solver's
tracking state and lens filter are reset before each. The report gives
median and p99 times, and each database's size on disk and in memory.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from tracker.attitude import attitude_error, matrix_from_radec_roll
from tracker.bench.machine import describe_machine
from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.config import CameraConfig
from tracker.detect import STAR_DTYPE, make_detector
from tracker.identify import make_solver
from tracker.sim import random_attitude, render_sky
from tracker.sim.sequence import attitude_at

_ARCSEC = math.degrees(1.0) * 3600.0
_OUTSIDE_CROSS_ARCSEC = 60.0
_OUTSIDE_ROLL_DEG = 0.1
_FOCAL_MIN_STARS = 15
_BUCKETS = (">=8", "5-7", "<5")


def add_arguments(p) -> None:
    p.add_argument("--lenses", default="55,25,16,8,4.2",
                   help="true focal lengths in mm, comma separated (OV2311 sensor)")
    p.add_argument("--focal-errors", default="-0.05,0.05",
                   help="configured focal length = true x (1 + error), comma separated")
    p.add_argument("--conditions", choices=("randomised", "nominal"), default="randomised")
    p.add_argument("--frames", type=int, default=200, help="lost-in-space frames per lens")
    p.add_argument("--sparse", type=int, default=100,
                   help="extra lost-in-space frames keeping only the 5-7 brightest stars "
                        "(truth centroids only)")
    p.add_argument("--sequence", type=int, default=150, help="tracking frames per lens")
    p.add_argument("--fps", type=float, default=10.0, help="tracking sequence frame rate")
    p.add_argument("--rate-deg-s", type=float, default=1.0, help="slew rate of the sequence")
    p.add_argument("--centroids", choices=("truth", "detect"), default="truth")
    p.add_argument("--snr-min", type=float, default=5.0, help="detectable: expected mf SNR")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--no-tetra3", action="store_true", help="skip the tetra3 comparison")


@dataclasses.dataclass
class _Draw:
    """One frame's unknowns (module docstring)."""

    psf_sigma_px: float
    centroid_factor: float
    false_stars: int
    flux_scatter_mag: float

    @classmethod
    def make(cls, conditions: str, rng: np.random.Generator) -> _Draw:
        if conditions == "nominal":
            return cls(1.2, 1.5, 2, 0.0)
        return cls(float(rng.uniform(0.8, 2.5)), float(rng.uniform(1.0, 3.0)),
                   int(rng.integers(0, 9)), 0.3)


def _lens_k1(conditions: str, camera: CameraModel, rng: np.random.Generator) -> float:
    """A radial distortion whose corner displacement is drawn from N(0, 2 px)."""
    if conditions == "nominal":
        return 0.0
    rho = math.hypot(camera.width / 2, camera.height / 2) / camera.f_px
    return float(rng.normal(0.0, 2.0) / (camera.f_px * rho ** 3))


class _Centroider:
    """Centroids (STAR_DTYPE) and the detectable-star count of a rendered frame."""

    def __init__(self, args, cfg, camera_cfg: CameraConfig, rng: np.random.Generator):
        self.args, self.cfg, self.rng = args, cfg, rng
        self.detector = None
        if args.centroids == "detect":
            self.detector = make_detector(cfg.detect, (camera_cfg.height, camera_cfg.width),
                                          camera_cfg.bit_depth)
        self.width, self.height = camera_cfg.width, camera_cfg.height

    def __call__(self, frame, draw: _Draw,
                 keep: int | None = None) -> tuple[np.ndarray, int, CentroidSources]:
        """Centroids, detectable count and identities; ``keep``: only that many brightest."""
        s = frame.stars
        det = s["in_frame"] & (s["mf_snr"] >= self.args.snr_min)
        n_det = int(np.count_nonzero(det))
        if self.detector is not None:
            found = self.detector.detect(frame.image).stars.copy()
            return found, n_det, CentroidSources.nearest(frame.stars, found)
        s = s[det]
        if keep is not None:
            s = s[np.argsort(-s["flux_e"])[:keep]]
            n_det = len(s)
        nf = draw.false_stars
        out = np.zeros(len(s) + nf, dtype=STAR_DTYPE)
        sigma = np.maximum(0.02, draw.centroid_factor * math.sqrt(2) * draw.psf_sigma_px
                           / s["mf_snr"])
        out["x"][:len(s)] = s["x"] + self.rng.normal(size=len(s)) * sigma
        out["y"][:len(s)] = s["y"] + self.rng.normal(size=len(s)) * sigma
        out["flux"][:len(s)] = s["flux_e"] * 10 ** (
            -0.4 * self.rng.normal(0.0, draw.flux_scatter_mag, len(s)))
        if nf:
            out["x"][len(s):] = self.rng.uniform(0, self.width - 1, nf)
            out["y"][len(s):] = self.rng.uniform(0, self.height - 1, nf)
            out["flux"][len(s):] = (self.rng.choice(s["flux_e"], nf) if len(s)
                                    else self.rng.uniform(100, 1000, nf))
        source = np.full((len(out), 2), np.nan)
        source[:len(s)] = np.column_stack((s["x"], s["y"]))
        return out, n_det, CentroidSources(frame.stars, source)


class CentroidSources:
    """Which rendered star each centroid is (its noiseless position; NaN: a false star)."""

    BLEND_PX = 2.0

    def __init__(self, rendered: np.ndarray, source: np.ndarray) -> None:
        self.source = source
        known = rendered["hip"] > 0
        order = np.argsort(rendered["hip"][known])
        self.hip = rendered["hip"][known][order]
        self.xy = np.column_stack((rendered["x"], rendered["y"]))[known][order]

    @classmethod
    def nearest(cls, rendered: np.ndarray, found: np.ndarray) -> CentroidSources:
        """For detections: the rendered star within 2 px of each, if any."""
        xy = np.column_stack((rendered["x"], rendered["y"]))
        source = np.full((len(found), 2), np.nan)
        for i, (x, y) in enumerate(zip(found["x"], found["y"], strict=True)):
            d = np.hypot(xy[:, 0] - x, xy[:, 1] - y)
            if len(d) and d.min() <= cls.BLEND_PX:
                source[i] = xy[np.argmin(d)]
        return cls(rendered, source)

    def wrong(self, rows: np.ndarray, hips: np.ndarray) -> int:
        """How many of the named stars (centroid rows, HIP numbers) are not their source."""
        if len(hips) == 0:
            return 0
        if len(self.hip) == 0:
            return len(hips)
        pos = np.clip(np.searchsorted(self.hip, hips), 0, len(self.hip) - 1)
        known = self.hip[pos] == hips
        d = np.hypot(*(self.xy[pos] - self.source[rows]).T)   # NaN for false stars
        return int(np.count_nonzero(~(known & (d <= self.BLEND_PX))))


def _tetra3_solver():
    import logging

    import tetra3

    logging.getLogger("tetra3").setLevel(logging.WARNING)
    t3 = tetra3.Tetra3()
    logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
    return t3


def _tetra3_database(t3) -> dict:
    """tetra3's database: field range, size on disk and in memory."""
    import tetra3

    props = t3.database_properties
    path = Path(tetra3.__file__).parent / "data" / "default_database.npz"
    arrays = [v for v in vars(t3).values() if isinstance(v, np.ndarray)]
    return {"fov_deg": [float(props["min_fov"]), float(props["max_fov"])],
            "patterns": int(props["num_patterns"]),
            "disk_mb": path.stat().st_size / 1e6 if path.exists() else math.nan,
            "memory_mb": sum(a.nbytes for a in arrays) / 1e6}


def _tetra3_serves(t3, camera: CameraModel, fov_error: float) -> bool:
    """Does tetra3's database cover the field range it would be asked to search?"""
    fov = math.degrees(camera.fov_x_rad)
    props = t3.database_properties
    return props["min_fov"] <= fov * (1 - fov_error) and fov * (1 + fov_error) <= props["max_fov"]


def _tetra3_solve(t3, stars, camera: CameraModel, fov_error: float):
    """tetra3 on the same centroids ((y, x), +0.5 px origin).

    Returns (R or None, wall ms, CPU ms, centroid rows it named, their HIP numbers).
    """
    order = np.argsort(-stars["flux"])
    yx = np.stack((stars["y"][order] + 0.5, stars["x"][order] + 0.5), axis=1)
    fov = math.degrees(camera.fov_x_rad)
    t0, c0 = time.perf_counter(), time.thread_time()
    res = t3.solve_from_centroids(yx, (camera.height, camera.width), fov_estimate=fov,
                                  fov_max_error=fov * fov_error, return_matches=True)
    ms, cpu = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
    if res.get("RA") is None:
        return None, ms, cpu, np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64)
    matched = np.asarray(res.get("matched_centroids", np.empty((0, 2))), dtype=np.float64)
    rows = np.array([order[int(np.argmin(np.hypot(*(yx - m).T)))] for m in matched],
                    dtype=np.int64)
    hips = np.asarray(res.get("matched_catID", []), dtype=np.int64).reshape(-1)
    return (matrix_from_radec_roll(math.radians(res["RA"]), math.radians(res["Dec"]),
                                   math.radians(res["Roll"])), ms, cpu, rows, hips)


def outside_tolerances(R, R_true, camera: CameraModel) -> tuple[bool, float, float]:
    """(beyond the tolerances?, cross-boresight and roll errors in arcsec); module docstring."""
    cross, roll = attitude_error(R, R_true)
    cross_as, roll_as = cross * _ARCSEC, roll * _ARCSEC
    pixel_as = _ARCSEC / camera.f_px
    corner_px = math.hypot(camera.width, camera.height) / 2
    roll_limit = max(_OUTSIDE_ROLL_DEG * 3600, 3 * _ARCSEC / corner_px)
    return (cross_as > max(_OUTSIDE_CROSS_ARCSEC, 3 * pixel_as) or abs(roll_as) > roll_limit,
            cross_as, roll_as)


def _judge(rec: dict, wrong: int, outside: bool, cross_as: float, roll_as: float) -> None:
    """Fill a solve's false / outside / mislabelled flags and errors (module docstring)."""
    rec.update(false=outside and wrong > 0, outside=outside and wrong == 0,
               mislabelled=wrong > 0 and not outside, cross_as=cross_as, roll_as=roll_as)


def _bucket(n: int) -> str:
    return ">=8" if n >= 8 else ("5-7" if n >= 5 else "<5")


def _stat(values, fn) -> float:
    values = np.asarray(values, dtype=np.float64)
    return float(fn(values)) if len(values) else math.nan


def _summary(rows: list[dict], key: str) -> dict:
    """Rates, times, errors and focal-length errors of one solver's results."""
    out = {}
    for b in _BUCKETS:
        sel = [r[key] for r in rows if r["bucket"] == b and key in r]
        ok = [r for r in sel if r["ok"] and not r["false"]]
        out[b] = {"frames": len(sel), "solved": len(ok),
                  "false": sum(r["false"] for r in sel),
                  "outside": sum(bool(r.get("outside")) for r in sel),
                  "mislabelled": sum(bool(r.get("mislabelled")) for r in sel),
                  "rate": len(ok) / len(sel) if sel else math.nan}
    done = [r[key] for r in rows if key in r]
    good = [r for r in done if r["ok"] and not r["false"]]
    for name in ("ms", "cpu_ms"):
        times = [r[name] for r in done]
        out[f"time_{name}"] = {"median": _stat(times, np.median),
                               "p99": _stat(times, lambda t: np.percentile(t, 99)),
                               "max": _stat(times, np.max)}
    out["sigma_check"] = _sigma_check(good)
    out["cross_arcsec_rms"] = _stat([g["cross_as"] for g in good],
                                    lambda v: np.sqrt(np.mean(v ** 2)))
    out["roll_arcsec_rms"] = _stat([g["roll_as"] for g in good],
                                   lambda v: np.sqrt(np.mean(v ** 2)))
    scored = [g for g in good if g.get("matched", 0) >= _FOCAL_MIN_STARS and "focal_error" in g]
    focal = [abs(g["focal_error"]) for g in scored]
    out["focal"] = {"frames": len(focal),
                    "within_0.1%": sum(f <= 1e-3 for f in focal),
                    "within_3_sigma": sum(abs(g["focal_error"]) <= 3 * g["focal_sigma"]
                                          for g in scored),
                    "p99_percent": _stat(focal, lambda v: 100 * np.percentile(v, 99)),
                    "max_percent": _stat(focal, lambda v: 100 * np.max(v))}
    return out


def _sigma_check(good: list[dict], min_matched: int = 8) -> dict:
    """RMS reported sigmas over RMS observed errors (cross, roll), solves with >= 8 matched."""
    sel = [g for g in good if g.get("matched", 0) >= min_matched and "sigma_cross" in g]
    if not sel:
        return {"frames": 0, "cross_ratio": math.nan, "roll_ratio": math.nan}

    def rms(key):
        return float(np.sqrt(np.mean(np.square([g[key] for g in sel]))))

    return {"frames": len(sel), "cross_ratio": rms("sigma_cross") / rms("cross_as"),
            "roll_ratio": rms("sigma_roll") / rms("roll_as")}


def _ours(solver, stars, truth: CentroidSources, t_ns, R_true, f_true_mm: float,
          camera: CameraModel) -> dict:
    t0, c0 = time.perf_counter(), time.thread_time()
    sol = solver.solve(stars, t_ns)
    ms, cpu = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
    rec = {"ok": sol.ok, "ms": ms, "cpu_ms": cpu, "mode": sol.mode, "false": False,
           "reason": sol.reason,
           "matched": sol.matched, "patterns": sol.patterns, "hypotheses": sol.hypotheses}
    if sol.ok:
        named = np.flatnonzero(sol.hip)
        _judge(rec, truth.wrong(named, sol.hip[named]),
               *outside_tolerances(sol.R, R_true, camera))
        rec["sigma_cross"], rec["sigma_roll"] = sol.sigma_cross_arcsec, sol.sigma_roll_arcsec
        rec["focal_error"] = sol.focal_length_mm / f_true_mm - 1.0
        rec["focal_sigma"] = sol.sigma_focal_length_mm / f_true_mm
        rec["lens_focal_error"] = sol.lens.focal_length_mm / f_true_mm - 1.0
    return rec


def _theirs(t3, stars, truth: CentroidSources, configured: CameraModel, R_true,
            fov_error: float, camera: CameraModel) -> dict:
    R, ms, cpu, rows, hips = _tetra3_solve(t3, stars, configured, fov_error)
    rec = {"ok": R is not None, "ms": ms, "cpu_ms": cpu, "false": False}
    if R is not None:
        _judge(rec, truth.wrong(rows, hips), *outside_tolerances(R, R_true, camera))
    return rec


def _run_lens(args, cfg, focal_mm: float, catalogue, t3) -> dict:
    """Every configured focal length for one lens, on the same frames."""
    rng = np.random.default_rng([args.seed, int(round(focal_mm * 1000))])
    nominal = CameraConfig(focal_length_mm=focal_mm, bit_depth=cfg.camera.bit_depth)
    k1 = _lens_k1(args.conditions, CameraModel.from_config(nominal), rng)
    true_cfg = dataclasses.replace(nominal, k1=k1)
    true_cam = CameraModel.from_config(true_cfg)
    errors = [float(e) for e in args.focal_errors.split(",")]
    solvers = {}
    for e in errors:
        cam_cfg = dataclasses.replace(nominal, focal_length_mm=focal_mm * (1 + e))
        t0 = time.perf_counter()
        solver = make_solver(cfg.identify, CameraModel.from_config(cam_cfg), catalogue)
        db = solver.bound
        solvers[e] = (solver, CameraModel.from_config(cam_cfg), {
            "file": Path(db.path).name, "disk_mb": Path(db.path).stat().st_size / 1e6,
            "memory_mb": db.nbytes / 1e6, "patterns": len(db.patterns),
            "stars": len(db.vectors), "faintest_mag": db.meta["faintest_mag"],
            "build_s": db.meta.get("build_seconds"),
            "load_s": time.perf_counter() - t0})
    centroids = _Centroider(args, cfg, true_cfg, rng)
    lis = []
    sparse = args.sparse if args.centroids == "truth" else 0
    for i in range(args.frames + sparse):
        R = random_attitude(rng)
        draw = _Draw.make(args.conditions, rng)
        keep = None if i < args.frames else 5 + i % 3
        sim = dataclasses.replace(cfg.sim, psf_sigma_px=draw.psf_sigma_px)
        stars, n_det, truth = centroids(render_sky(true_cfg, catalogue, R, sim, rng), draw,
                                        keep)
        row = {"bucket": _bucket(n_det), "detectable": n_det}
        for e, (solver, cam, _) in solvers.items():
            solver.reset()
            solver.lens.reset()
            row[f"ours{e:+g}"] = _ours(solver, stars, truth, 0, R, focal_mm, true_cam)
            if t3 is not None and _tetra3_serves(t3, cam, cfg.identify.focal_tolerance):
                row[f"tetra3{e:+g}"] = _theirs(t3, stars, truth, cam, R,
                                               cfg.identify.focal_tolerance, true_cam)
        lis.append(row)
    # a slew with the first configured focal length: tracking and the lens filter
    e0 = errors[0]
    solver = solvers[e0][0]
    solver.reset()
    solver.lens.reset()
    R0 = random_attitude(rng)
    axis = rng.normal(size=3)
    rate = axis / np.linalg.norm(axis) * math.radians(args.rate_deg_s)
    draw = _Draw.make(args.conditions, rng)
    sim = dataclasses.replace(cfg.sim, psf_sigma_px=draw.psf_sigma_px)
    seq = []
    for i in range(args.sequence):
        t = i / args.fps
        R = attitude_at(R0, rate, t)
        frame = render_sky(true_cfg, catalogue, R, sim, rng, t_s=t,
                           rate_deg_s=np.degrees(rate))
        stars, n_det, truth = centroids(frame, draw)
        seq.append({"bucket": _bucket(n_det), "detectable": n_det,
                    "ours": _ours(solver, stars, truth, int(t * 1e9), R, focal_mm, true_cam)})
    track = [r["ours"] for r in seq if r["ours"]["ok"] and r["ours"]["mode"] == "tracking"]
    last = next((r["ours"] for r in reversed(seq) if r["ours"]["ok"]), None)
    lens = solver.lens.state()
    return {
        "focal_mm": focal_mm, "k1": k1, "fov_x_deg": math.degrees(true_cam.fov_x_rad),
        "databases": {f"{e:+g}": info for e, (_, _, info) in solvers.items()},
        "lost_in_space": {name: _summary(lis, name) for name in lis[0]
                          if name.startswith(("ours", "tetra3"))} if lis else {},
        "sequence": {
            "frames": len(seq), "tracking_frames": len(track),
            "solved": sum(r["ours"]["ok"] and not r["ours"]["false"] for r in seq),
            "false": sum(r["ours"]["false"] for r in seq),
            "track_ms_median": _stat([r["ms"] for r in track], np.median),
            "track_ms_p99": _stat([r["ms"] for r in track], lambda t: np.percentile(t, 99)),
            "lens_focal_error_percent": (100 * last["lens_focal_error"]) if last else math.nan,
            "lens_sigma_percent": 100 * lens.sigma_f_px / true_cam.f_px,
            "lens_k1": lens.k1, "lens_sigma_k1": lens.sigma_k1,
            "errors": _summary(seq, "ours")},
    }


def _cell(d: dict) -> str:
    if not d["frames"]:
        return "-"
    return f"{d['solved']}/{d['frames']} ({100 * d['rate']:.1f} %)"


def _markdown(machine: dict, args, results: list[dict], tetra: dict | None) -> str:
    lines = ["# tracker bench solve", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()), "",
             f"Conditions: {args.conditions}; centroids: {args.centroids}; {args.frames} "
             f"lost-in-space frames (+ {args.sparse if args.centroids == 'truth' else 0} "
             f"keeping the 5-7 brightest stars) and {args.sequence} tracking frames "
             f"({args.rate_deg_s} deg/s at {args.fps} fps) per lens; configured focal "
             f"length = true x (1 + {args.focal_errors}); seed {args.seed}.", ""]
    if tetra:
        lines += [f"tetra3 (cedar-solve) default database: {tetra['fov_deg'][0]:g}-"
                  f"{tetra['fov_deg'][1]:g} deg, {tetra['patterns']:,} patterns, "
                  f"{tetra['disk_mb']:.1f} MB on disk, {tetra['memory_mb']:.1f} MB in memory; "
                  "given fov_estimate from the configured focal length and fov_max_error "
                  "of identify.focal_tolerance times it; not run on lenses whose field range "
                  "its database does not cover.", ""]
    for res in results:
        lines += [f"## {res['focal_mm']:g} mm (horizontal field {res['fov_x_deg']:.1f} deg, "
                  f"k1 {res['k1']:+.3g})", ""]
        for name, d in res["databases"].items():
            lines.append(f"- database for focal error {name}: `{d['file']}`, {d['stars']:,} "
                         f"stars to Hp {d['faintest_mag']:.2f}, {d['patterns']:,} patterns, "
                         f"{d['disk_mb']:.2f} MB on disk, {d['memory_mb']:.1f} MB in memory, "
                         f"built in {d['build_s']} s")
        lines += ["", "| solver, focal error | >=8 stars | 5-7 | <5 | false | outside "
                  "| mislabelled | median ms | p99 ms | CPU median / p99 ms "
                  "| focal within 0.1 % (>=15 matched) | within 3 reported sigma "
                  "| focal p99 % | cross RMS arcsec | roll RMS arcsec "
                  "| reported / observed sigma, cross and roll |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for name, s in res["lost_in_space"].items():
            false = sum(s[b]["false"] for b in _BUCKETS)
            outside = sum(s[b]["outside"] for b in _BUCKETS)
            mislabelled = sum(s[b]["mislabelled"] for b in _BUCKETS)
            f = s["focal"]
            focal = f"{f['within_0.1%']}/{f['frames']}" if f["frames"] else "-"
            honest = f"{f['within_3_sigma']}/{f['frames']}" if f["frames"] else "-"
            lines.append(f"| {name} | {_cell(s['>=8'])} | {_cell(s['5-7'])} | {_cell(s['<5'])} "
                         f"| {false} | {outside} | {mislabelled} | {s['time_ms']['median']:.2f} "
                         f"| {s['time_ms']['p99']:.2f} "
                         f"| {s['time_cpu_ms']['median']:.2f} / {s['time_cpu_ms']['p99']:.2f} "
                         f"| {focal} | {honest} | {f['p99_percent']:.3f} "
                         f"| {s['cross_arcsec_rms']:.2f} | {s['roll_arcsec_rms']:.2f} "
                         f"| {s['sigma_check']['cross_ratio']:.2f}, "
                         f"{s['sigma_check']['roll_ratio']:.2f} |")
        sq = res["sequence"]
        lines += ["", f"Tracking (configured focal error {args.focal_errors.split(',')[0]}): "
                  f"{sq['solved']}/{sq['frames']} frames solved, {sq['tracking_frames']} in "
                  f"tracking mode, {sq['false']} false; tracking time median "
                  f"{sq['track_ms_median']:.2f} ms, p99 {sq['track_ms_p99']:.2f} ms; the lens "
                  f"filter's focal length after the slew is {sq['lens_focal_error_percent']:+.4f}"
                  f" % from the truth (sigma {sq['lens_sigma_percent']:.4f} %), k1 "
                  f"{sq['lens_k1']:+.4f} +- {sq['lens_sigma_k1']:.4f} (true {res['k1']:+.4f}).",
                  ""]
    return "\n".join(lines)


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    catalogue = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    t3 = None if args.no_tetra3 else _tetra3_solver()
    tetra = _tetra3_database(t3) if t3 is not None else None
    machine = describe_machine()
    results = [_run_lens(args, cfg, float(f), catalogue, t3) for f in args.lenses.split(",")]
    text = _markdown(machine, args, results, tetra)
    (out / "solve.md").write_text(text, encoding="utf-8")
    (out / "solve.json").write_text(json.dumps({"machine": machine, "args": vars(args) | {
        "func": None}, "tetra3_database": tetra, "results": results}, indent=1, default=str),
        encoding="utf-8")
    print(text)
    return 0
