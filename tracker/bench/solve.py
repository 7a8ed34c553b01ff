"""Star identification: lost-in-space and tracking on simulated skies, beside tetra3.

For each lens (default 16 mm and 8 mm on the OV2311) the bench renders
frames with tracker.sim at random attitudes (lost in space, solver reset
before each) and along constant-rate slews (tracking), takes centroids, and
solves them with our solver and with tetra3's ``solve_from_centroids``
(cedar-solve, default database) on the same centroids in the same run.

Centroids (``--centroids``):

* ``truth`` (default): every rendered star whose expected matched-filter
  SNR reaches ``--snr-min`` is "detectable"; its centroid is the true
  position plus Gaussian noise of ``--centroid-factor`` times the
  Cramer-Rao bound sqrt(2) * psf_sigma / mf_snr per axis (floor 0.02 px);
  ``--false-stars`` uniformly placed false stars (planets, satellites; the
  detector is assumed to reject single hot pixels) get fluxes drawn from the
  frame's own stars.
* ``detect``: the configured detector runs on the rendered image.

A solve is false when its boresight is more than 60 arcsec from the truth
(or roll off by more than 0.1 deg). Rates are reported by the number of
detectable stars (>= 8, 5-7, < 5). Errors are cross-boresight (angle between
boresights) and roll (about the boresight), in arcsec.
"""

from __future__ import annotations

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
_FALSE_CROSS_ARCSEC = 60.0
_FALSE_ROLL_DEG = 0.1


def add_arguments(p) -> None:
    p.add_argument("--lenses", default="16,8", help="focal lengths in mm, comma separated")
    p.add_argument("--frames", type=int, default=200, help="lost-in-space frames per lens")
    p.add_argument("--sparse", type=int, default=100,
                   help="extra lost-in-space frames keeping only the 5-7 brightest stars "
                        "(truth centroids only)")
    p.add_argument("--sequence", type=int, default=150, help="tracking frames per lens")
    p.add_argument("--fps", type=float, default=10.0, help="tracking sequence frame rate")
    p.add_argument("--rate-deg-s", type=float, default=1.0, help="slew rate of the sequence")
    p.add_argument("--centroids", choices=("truth", "detect"), default="truth")
    p.add_argument("--snr-min", type=float, default=5.0, help="detectable: expected mf SNR")
    p.add_argument("--centroid-factor", type=float, default=1.5,
                   help="centroid noise as a multiple of the Cramer-Rao bound")
    p.add_argument("--false-stars", type=int, default=2, help="false stars per frame")
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--no-tetra3", action="store_true", help="skip the tetra3 comparison")


class _Centroider:
    """Centroids (STAR_DTYPE) and the detectable-star count of a rendered frame."""

    def __init__(self, args, cfg, camera_cfg: CameraConfig, rng: np.random.Generator):
        self.args, self.cfg, self.rng = args, cfg, rng
        self.detector = None
        if args.centroids == "detect":
            self.detector = make_detector(cfg.detect, (camera_cfg.height, camera_cfg.width),
                                          camera_cfg.bit_depth)
        self.width, self.height = camera_cfg.width, camera_cfg.height

    def __call__(self, frame, keep: int | None = None) -> tuple[np.ndarray, int]:
        """Centroids and detectable count; ``keep``: only that many brightest stars."""
        s = frame.stars
        det = s["in_frame"] & (s["mf_snr"] >= self.args.snr_min)
        n_det = int(np.count_nonzero(det))
        if self.detector is not None:
            return self.detector.detect(frame.image).stars.copy(), n_det
        s = s[det]
        if keep is not None:
            s = s[np.argsort(-s["flux_e"])[:keep]]
            n_det = len(s)
        nf = self.args.false_stars
        out = np.zeros(len(s) + nf, dtype=STAR_DTYPE)
        sigma = np.maximum(0.02, self.args.centroid_factor * math.sqrt(2)
                           * self.cfg.sim.psf_sigma_px / s["mf_snr"])
        out["x"][:len(s)] = s["x"] + self.rng.normal(size=len(s)) * sigma
        out["y"][:len(s)] = s["y"] + self.rng.normal(size=len(s)) * sigma
        out["flux"][:len(s)] = s["flux_e"]
        if nf:
            out["x"][len(s):] = self.rng.uniform(0, self.width - 1, nf)
            out["y"][len(s):] = self.rng.uniform(0, self.height - 1, nf)
            out["flux"][len(s):] = (self.rng.choice(s["flux_e"], nf) if len(s)
                                    else self.rng.uniform(100, 1000, nf))
        return out, n_det


def _tetra3_solver():
    import logging

    import tetra3

    logging.getLogger("tetra3").setLevel(logging.WARNING)
    t3 = tetra3.Tetra3()
    logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
    return t3


def _tetra3_solve(t3, stars, camera: CameraModel):
    """(R or None, ms): tetra3 on the same centroids, (y, x) with +0.5 pixel origin."""
    order = np.argsort(-stars["flux"])
    yx = np.stack((stars["y"][order] + 0.5, stars["x"][order] + 0.5), axis=1)
    t0 = time.perf_counter()
    res = t3.solve_from_centroids(yx, (camera.height, camera.width),
                                  fov_estimate=math.degrees(camera.fov_x_rad),
                                  fov_max_error=0.5)
    ms = (time.perf_counter() - t0) * 1e3
    if res.get("RA") is None:
        return None, ms
    return matrix_from_radec_roll(math.radians(res["RA"]), math.radians(res["Dec"]),
                                  math.radians(res["Roll"])), ms


def _is_false(R, R_true) -> tuple[bool, float, float]:
    cross, roll = attitude_error(R, R_true)
    cross_as, roll_as = cross * _ARCSEC, roll * _ARCSEC
    return (cross_as > _FALSE_CROSS_ARCSEC or abs(roll_as) > _FALSE_ROLL_DEG * 3600,
            cross_as, roll_as)


def _bucket(n: int) -> str:
    return ">=8" if n >= 8 else ("5-7" if n >= 5 else "<5")


def _summary(rows: list[dict], key: str) -> dict:
    """Rates, times and errors of one solver's results."""
    out = {}
    for b in (">=8", "5-7", "<5"):
        sel = [r for r in rows if r["bucket"] == b]
        ok = [r for r in sel if r[key]["ok"] and not r[key]["false"]]
        false = [r for r in sel if r[key]["false"]]
        out[b] = {"frames": len(sel), "solved": len(ok), "false": len(false),
                  "rate": len(ok) / len(sel) if sel else math.nan}
    times = np.array([r[key]["ms"] for r in rows])
    good = [r[key] for r in rows if r[key]["ok"] and not r[key]["false"]]
    cross = np.array([g["cross_as"] for g in good])
    roll = np.array([g["roll_as"] for g in good])
    out["time_ms"] = {"median": float(np.median(times)) if len(times) else math.nan,
                      "p95": float(np.percentile(times, 95)) if len(times) else math.nan,
                      "max": float(times.max()) if len(times) else math.nan}
    out["cross_arcsec"] = {"median": float(np.median(cross)) if len(cross) else math.nan,
                           "rms": float(np.sqrt(np.mean(cross ** 2))) if len(cross)
                           else math.nan}
    out["roll_arcsec"] = {"median": float(np.median(np.abs(roll))) if len(roll) else math.nan,
                          "rms": float(np.sqrt(np.mean(roll ** 2))) if len(roll)
                          else math.nan}
    return out


def _sigma_check(rows: list[dict], min_matched: int = 8) -> dict:
    """Observed RMS errors against RMS reported sigmas, frames with >= min_matched."""
    sel = [r["ours"] for r in rows if r["ours"]["ok"] and not r["ours"]["false"]
           and r["ours"]["matched"] >= min_matched]
    if not sel:
        return {"frames": 0}

    def rms(k):
        return float(np.sqrt(np.mean(np.square([s[k] for s in sel]))))

    out = {"frames": len(sel), "cross_rms": rms("cross_as"), "roll_rms": rms("roll_as"),
           "sigma_cross_rms": rms("sigma_cross"), "sigma_roll_rms": rms("sigma_roll")}
    out["cross_ratio"] = out["sigma_cross_rms"] / out["cross_rms"]
    out["roll_ratio"] = out["sigma_roll_rms"] / out["roll_rms"]
    return out


def _ours(solver, stars, t_ns, R_true) -> dict:
    t0 = time.perf_counter()
    sol = solver.solve(stars, t_ns)
    ms = (time.perf_counter() - t0) * 1e3
    rec = {"ok": sol.ok, "ms": ms, "mode": sol.mode, "false": False, "reason": sol.reason,
           "matched": sol.matched}
    if sol.ok:
        rec["false"], rec["cross_as"], rec["roll_as"] = _is_false(sol.R, R_true)
        rec["sigma_cross"], rec["sigma_roll"] = sol.sigma_cross_arcsec, sol.sigma_roll_arcsec
    return rec


def _theirs(t3, stars, camera, R_true) -> dict:
    R, ms = _tetra3_solve(t3, stars, camera)
    rec = {"ok": R is not None, "ms": ms, "false": False}
    if R is not None:
        rec["false"], rec["cross_as"], rec["roll_as"] = _is_false(R, R_true)
    return rec


def _run_lens(args, cfg, focal_mm: float, catalogue, t3) -> dict:
    """Both sequences for one lens; ``catalogue`` (all stars) is what the sky shows."""
    camera_cfg = CameraConfig(focal_length_mm=focal_mm, bit_depth=cfg.camera.bit_depth)
    camera = CameraModel.from_config(camera_cfg)
    solver = make_solver(cfg.identify, camera, load_catalogue(
        cfg.catalogue.path, catalogue.epoch_year, cfg.catalogue.mag_limit))
    rng = np.random.default_rng(args.seed)
    centroids = _Centroider(args, cfg, camera_cfg, rng)
    lis = []
    sparse = args.sparse if args.centroids == "truth" else 0
    for i in range(args.frames + sparse):
        R = random_attitude(rng)
        keep = None if i < args.frames else 5 + i % 3
        stars, n_det = centroids(render_sky(camera_cfg, catalogue, R, cfg.sim, rng), keep)
        solver.reset()
        row = {"bucket": _bucket(n_det), "detectable": n_det,
               "ours": _ours(solver, stars, 0, R)}
        if t3 is not None:
            row["tetra3"] = _theirs(t3, stars, camera, R)
        lis.append(row)
    # a slew: random start and axis, constant rate
    solver.reset()
    R0 = random_attitude(rng)
    axis = rng.normal(size=3)
    rate = axis / np.linalg.norm(axis) * math.radians(args.rate_deg_s)
    seq = []
    for i in range(args.sequence):
        t = i / args.fps
        R = attitude_at(R0, rate, t)
        frame = render_sky(camera_cfg, catalogue, R, cfg.sim, rng, t_s=t,
                           rate_deg_s=np.degrees(rate))
        stars, n_det = centroids(frame)
        seq.append({"bucket": _bucket(n_det), "detectable": n_det,
                    "ours": _ours(solver, stars, int(t * 1e9), R)})
    track = [r["ours"] for r in seq if r["ours"]["ok"] and r["ours"]["mode"] == "tracking"]
    track_ms = np.array([r["ms"] for r in track]) if track else np.array([math.nan])
    result = {
        "focal_mm": focal_mm, "fov_x_deg": math.degrees(camera.fov_x_rad),
        "lost_in_space": {"ours": _summary(lis, "ours"), "sigma_check": _sigma_check(lis)},
        "sequence": {"frames": len(seq), "tracking_frames": len(track),
                     "solved": sum(r["ours"]["ok"] and not r["ours"]["false"] for r in seq),
                     "false": sum(r["ours"]["false"] for r in seq),
                     "track_ms_median": float(np.median(track_ms)),
                     "track_ms_p95": float(np.percentile(track_ms, 95)),
                     "track_ms_max": float(np.max(track_ms)),
                     "errors": _summary(seq, "ours"), "sigma_check": _sigma_check(seq)},
    }
    if t3 is not None:
        result["lost_in_space"]["tetra3"] = _summary(lis, "tetra3")
    return result


def _markdown(machine: dict, args, results: list[dict]) -> str:
    lines = ["# tracker bench solve", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()), "",
             f"Centroids: {args.centroids}; {args.frames} lost-in-space frames (+ "
             f"{args.sparse if args.centroids == 'truth' else 0} keeping the 5-7 brightest "
             "stars) and "
             f"{args.sequence} tracking frames ({args.rate_deg_s} deg/s at {args.fps} fps) "
             f"per lens; seed {args.seed}.", ""]
    for res in results:
        lines += [f"## {res['focal_mm']:g} mm (horizontal FOV {res['fov_x_deg']:.1f} deg)", "",
                  "| solver | >=8 stars | 5-7 | <5 | false | median ms | p95 ms | max ms "
                  "| cross RMS arcsec | roll RMS arcsec |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for name, s in res["lost_in_space"].items():
            if name == "sigma_check":
                continue

            def cell(b, s=s):
                d = s[b]
                return f"{d['solved']}/{d['frames']}" + (
                    f" ({100 * d['rate']:.1f} %)" if d["frames"] else "")

            false = sum(s[b]["false"] for b in (">=8", "5-7", "<5"))
            lines.append(f"| {name} | {cell('>=8')} | {cell('5-7')} | {cell('<5')} | {false} "
                         f"| {s['time_ms']['median']:.2f} | {s['time_ms']['p95']:.2f} "
                         f"| {s['time_ms']['max']:.2f} | {s['cross_arcsec']['rms']:.2f} "
                         f"| {s['roll_arcsec']['rms']:.2f} |")
        sc = res["lost_in_space"]["sigma_check"]
        if sc.get("frames"):
            lines += ["", f"Reported vs observed (lost in space, >= 8 matched, {sc['frames']} "
                      f"frames): cross {sc['sigma_cross_rms']:.2f} vs {sc['cross_rms']:.2f} "
                      f"arcsec (ratio {sc['cross_ratio']:.2f}), roll "
                      f"{sc['sigma_roll_rms']:.2f} vs {sc['roll_rms']:.2f} arcsec (ratio "
                      f"{sc['roll_ratio']:.2f})."]
        sq = res["sequence"]
        lines += ["", f"Tracking: {sq['solved']}/{sq['frames']} frames solved, "
                  f"{sq['tracking_frames']} in tracking mode, {sq['false']} false; "
                  f"tracking time median {sq['track_ms_median']:.2f} ms, p95 "
                  f"{sq['track_ms_p95']:.2f} ms, max {sq['track_ms_max']:.2f} ms; cross RMS "
                  f"{sq['errors']['cross_arcsec']['rms']:.2f} arcsec, roll RMS "
                  f"{sq['errors']['roll_arcsec']['rms']:.2f} arcsec.", ""]
    return "\n".join(lines)


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    catalogue = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    t3 = None if args.no_tetra3 else _tetra3_solver()
    machine = describe_machine()
    results = [_run_lens(args, cfg, float(f), catalogue, t3) for f in args.lenses.split(",")]
    text = _markdown(machine, args, results)
    (out / "solve.md").write_text(text, encoding="utf-8")
    (out / "solve.json").write_text(json.dumps({"machine": machine, "args": vars(args) | {
        "func": None}, "results": results}, indent=1, default=str), encoding="utf-8")
    print(text)
    return 0
