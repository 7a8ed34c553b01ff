"""Synthetic star-field frames with ground truth.

Render what the OV2311 behind a 16 mm M12 lens would record from a given
attitude, or from explicit point sources, under a realistic sensor model
or under the seed method's four noise models, with the truth beside it::

    import numpy as np
    from tracker.catalogue import load_catalogue
    from tracker.config import load_config
    from tracker.sim import random_attitude, render_sky, write_frame

    cfg = load_config(None)
    rng = np.random.default_rng(cfg.sim.seed)
    frame = render_sky(cfg.camera, load_catalogue(), random_attitude(rng), cfg.sim, rng)
    write_frame(frame, "out", "f0000")   # out/f0000.png + out/f0000.png.truth.json

Modules: psf (pixel-integrated Gaussian), photometry (magnitudes to
electrons), sensor (realistic noise and ADC), seednoise (the seed method's
models and the SNR definition), frame (core renderer, SimFrame), sky
(catalogue projection, slews), sequence (attitude helpers), io (files).
Everything is deterministic for a given ``np.random.Generator`` state;
hot pixels depend on ``SimConfig.seed`` only (one seed = one sensor).
"""

from tracker.sim.frame import SIM_STAR_DTYPE, SimFrame, render_points
from tracker.sim.io import truth_path, write_frame
from tracker.sim.seednoise import SNR_DEFINITION, apply_seed_noise, noise_power, snr_db
from tracker.sim.sequence import attitude_at, random_attitude
from tracker.sim.sky import render_sequence, render_sky

__all__ = [
    "SIM_STAR_DTYPE", "SNR_DEFINITION", "SimFrame", "apply_seed_noise", "attitude_at",
    "noise_power", "random_attitude", "render_points", "render_sequence", "render_sky",
    "snr_db", "truth_path", "write_frame",
]
