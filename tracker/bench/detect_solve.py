"""Solving the scene sets of ``tracker bench detect``: do the detections still give the attitude?

For each frame of a set that carries a camera (the lunar sets), the
identification and attitude stage (tracker.identify, lost in space, reset
before every frame) solves:

* ``truth``: the true positions of the visible stars at peak SNR >= 5,
  with their true fluxes. A frame is *solvable* when these solve
  correctly: the stars needed are there, and whatever the detectors do
  is judged against that;
* ``default``: our detector's stars;
* the peers (sep, tetra3): their centroids, with fluxes summed in a 7x7
  aperture over the median of its border (tracker.bench.detect_peers
  gives positions only).

A solution is judged as ``tracker bench solve`` judges one
(tracker.bench.solve): it is *off* when its boresight is more than 60 arcsec
or 3 pixels from the truth, or its roll more than 0.1 deg or 3 pixels at the
corner; an off solution is *false* when it names a wrong star (one whose true
position is not within 2 px of the centroid it names, or a centroid on no
star): a wrong identification. An off solution that names only right stars
(few faint stars under a wide PSF fix the attitude poorly, and its reported
sigma says so) counts as neither solved nor false, in its own column. A frame
counts as solved when its solution is not off.
"""

from __future__ import annotations

import numpy as np

from tracker.bench.detect_peers import PEERS
from tracker.bench.solve import CentroidSources, outside_tolerances
from tracker.camera import CameraModel
from tracker.detect import STAR_DTYPE, make_detector
from tracker.identify import make_solver

__all__ = ["solve_sets", "aperture_flux"]

_APERTURE = 3      # half-width of the peers' flux aperture, px


def aperture_flux(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sum over a 7x7 box at each (x, y) less its border's median times its area, ADU."""
    img = np.asarray(image, np.float64)
    rows, cols = img.shape
    out = np.zeros(len(x))
    h = _APERTURE
    for i, (cx, cy) in enumerate(zip(np.rint(x).astype(int), np.rint(y).astype(int),
                                     strict=True)):
        box = img[max(cy - h, 0):min(cy + h + 1, rows), max(cx - h, 0):min(cx + h + 1, cols)]
        if box.size == 0:
            continue
        border = np.concatenate([box[0], box[-1], box[1:-1, 0], box[1:-1, -1]])
        out[i] = box.sum() - np.median(border) * box.size
    return out


def _stars(x, y, flux) -> np.ndarray:
    out = np.zeros(len(x), STAR_DTYPE)
    out["x"], out["y"], out["flux"] = x, y, flux
    order = np.argsort(-out["flux"], kind="stable")
    return out[order]


def _outcome(solver, stars: np.ndarray, frame, camera: CameraModel) -> str:
    """"unsolved", "solved", "off" or "false" (module docstring) for ``stars`` of ``frame``."""
    solver.reset()
    sol = solver.solve(stars, 0)
    if not sol.ok:
        return "unsolved"
    off = outside_tolerances(sol.R, frame.R, camera)[0]
    if not off:
        return "solved"
    named = np.flatnonzero(sol.hip > 0)
    wrong = CentroidSources.nearest(frame.stars, stars).wrong(named, sol.hip[named])
    return "false" if wrong else "off"


def solve_sets(sets, cfg, catalogue, methods) -> dict:
    """Per solved set and method: frames, solvable, solved (of the solvable), false."""
    results = {}
    for data in sets:
        if data.camera is None:
            continue
        camera = CameraModel.from_config(data.camera)
        solver = make_solver(cfg.identify, camera, catalogue)
        detector = make_detector(cfg.detect, (data.camera.height, data.camera.width),
                                 data.camera.bit_depth)
        tally = {m: {"frames": 0, "solvable": 0, "solved": 0, "off": 0, "false": 0}
                 for m in ["truth", *methods]}
        for frame in data.frames:
            s = frame.stars
            seen = s["in_frame"] & (s["peak_snr"] >= 5.0)
            truth = _outcome(solver, _stars(s["x"][seen], s["y"][seen], s["flux_e"][seen]),
                             frame, camera)
            solvable = truth == "solved"
            for m in tally:
                if m == "truth":
                    outcome = truth
                elif m == "default":
                    outcome = _outcome(solver, detector.detect(frame.image).stars.copy(),
                                       frame, camera)
                elif m in PEERS:
                    try:
                        x, y = (np.asarray(v, float) for v in PEERS[m](frame.image))
                    except Exception:  # a peer failing on a frame is a result, not a crash
                        x = y = np.zeros(0)
                    outcome = _outcome(solver, _stars(x, y, aperture_flux(frame.image, x, y)),
                                       frame, camera)
                else:
                    continue
                t = tally[m]
                t["frames"] += 1
                t["solvable"] += solvable
                t["solved"] += solvable and outcome == "solved"
                t["off"] += outcome == "off"
                t["false"] += outcome == "false"
        results[data.name] = {m: t for m, t in tally.items() if t["frames"]}
    return results
