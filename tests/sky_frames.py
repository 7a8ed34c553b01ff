"""Test helper: simulated frames of the default camera (OV2311, 16 mm) at given pointings."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tracker.attitude import matrix_from_radec_roll
from tracker.catalogue import load_catalogue
from tracker.config import load_config
from tracker.sim import SimFrame, render_sky, write_frame


def sky_frames(pointings_deg: list[tuple[float, float, float]], seed: int,
               folder: Path | None = None) -> list[SimFrame]:
    """One realistic frame per (RA, Dec, roll) in degrees, in order, from one generator;
    written as ``folder/fNNNN.png`` with its truth JSON when ``folder`` is given."""
    cfg = load_config(None)
    catalogue = load_catalogue(epoch_year=2026.0, mag_limit=cfg.catalogue.mag_limit)
    rng = np.random.default_rng(seed)
    frames = []
    for i, pointing in enumerate(pointings_deg):
        R = matrix_from_radec_roll(*np.radians(pointing))
        frame = render_sky(cfg.camera, catalogue, R, cfg.sim, rng)
        if folder is not None:
            write_frame(frame, folder, f"f{i:04d}")
        frames.append(frame)
    return frames
