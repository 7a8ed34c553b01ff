"""The solve's per-star weights describe the centroids' real errors on a tracked slew.

Wahba's weights (tracker.identify.solver, refinement) are 1 / the centroid's
variance (tracker.identify.predict.centroid_variance). Against the
simulator's truth, on a 16 mm slew at 3 deg/s with 20 ms of exposure (trails
of about 5 px), the squared errors of the matched stars over that variance
must average about 1 for the bright stars and the faint alike: a weight's
floor far above the bright stars' errors (0.25 px until ea288bd, against
their 0.05-0.1 px) gives the faint stars nearly the bright ones' weight.
"""

import dataclasses

import numpy as np
from identify_sim import catalogue

from tracker.config import Config
from tracker.identify.predict import centroid_variance
from tracker.identify.solver import Solver
from tracker.pipeline import Pipeline
from tracker.sim import random_attitude, render_sequence


def test_weights_match_the_errors_of_bright_and_faint_trailed_stars(monkeypatch):
    cfg = Config()
    cam = dataclasses.replace(cfg.camera, focal_length_mm=16.0)
    cfg = dataclasses.replace(cfg, camera=cam)
    sim = dataclasses.replace(cfg.sim, psf_sigma_px=1.3, exposure_ms=20.0)
    rng = np.random.default_rng(21)
    pipeline = Pipeline(cfg)
    seen = {}
    solve = Solver.solve

    def recording(self, stars, *args, **kwargs):
        seen["stars"] = np.array(stars, copy=True)
        return solve(self, stars, *args, **kwargs)

    monkeypatch.setattr(Solver, "solve", recording)
    snr, normalised = [], []
    frames = render_sequence(cam, catalogue(), random_attitude(rng), sim, rng, 14, fps=10.0,
                             rate_deg_s=(1.2, -2.4, 1.3))
    for i, frame in enumerate(frames):
        t_ns = int(i * 1e8)
        result = pipeline.process(frame.image, cam.bit_depth, t_ns, exposure_s=0.02)
        sol = result.solution
        if i < 3 or sol is None or not sol.ok or sol.mode != "tracking":
            continue
        stars = seen["stars"]
        truth = {int(h): (x, y) for h, x, y in zip(frame.stars["hip"], frame.stars["x"],
                                                     frame.stars["y"], strict=True)}
        rows = np.flatnonzero(sol.hip > 0)
        xy = np.c_[stars["x"][rows], stars["y"][rows]]
        true_xy = np.array([truth[int(h)] for h in sol.hip[rows]])
        trail2 = np.square(pipeline.solver.smear_px(xy, t_ns, 0.02)).sum(axis=1)
        variance = centroid_variance(stars["snr"][rows], trail2)
        snr.append(stars["snr"][rows])
        normalised.append(np.square(xy - true_xy).mean(axis=1) / variance)
    snr, normalised = np.concatenate(snr), np.concatenate(normalised)
    assert len(snr) >= 100
    bands = [snr < 10, (snr >= 10) & (snr < 30), snr >= 30]
    assert min(band.sum() for band in bands) >= 10
    means = [normalised[band].mean() for band in bands]
    assert max(means) < 2.0 * min(means), means
