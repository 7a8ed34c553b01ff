"""Star identification and attitude: pattern database, lost in space, tracking.

Usage::

    solver = make_solver(cfg.identify, camera, catalogue)
    sol = solver.solve(detections.stars, t_ns)
    if sol.ok: sol.q, sol.ra_deg, sol.dec_deg, sol.roll_deg, sol.hip ...

Modules: ``database`` (the pair table and its files), ``lost`` (triangle
search), ``verify`` (prediction, matching, false-match probability),
``solver`` (the state machine and the :class:`Solution`).
"""

from __future__ import annotations

import logging
import math

from tracker.camera import CameraModel
from tracker.config import IdentifyConfig
from tracker.identify.database import DatabaseError, PatternDatabase, find_database
from tracker.identify.solver import Solution, Solver

__all__ = ["make_solver", "Solver", "Solution", "DatabaseError"]

_log = logging.getLogger(__name__)


def make_solver(cfg: IdentifyConfig, camera: CameraModel, catalogue) -> Solver:
    """A solver for this camera with the fitting pattern database.

    With ``cfg.database`` null the committed database whose field-of-view
    range holds the camera's diagonal FOV is loaded; if none fits a
    :class:`DatabaseError` (a ConfigError) is raised. A database named
    explicitly that does not fit the camera is loaded anyway and every solve
    returns ``reason="wrong_fov"`` (logged once here).
    """
    fov = camera.fov_diagonal_rad
    path = cfg.database if cfg.database is not None else find_database(fov)
    db = PatternDatabase.load(path)
    fov_error = None
    if not db.fits(fov):
        fov_error = (f"{path}: built for {db.meta['fov_min_deg']:g}-{db.meta['fov_max_deg']:g}"
                     f" deg diagonal, the camera has {math.degrees(fov):.2f} deg")
        _log.warning("pattern database does not fit the camera: %s", fov_error)
    return Solver(cfg, camera, db.bind(catalogue), catalogue, fov_error)
