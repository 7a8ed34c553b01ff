"""Star identification and attitude: pattern database, lost in space, tracking, the lens.

Usage::

    solver = make_solver(cfg.identify, camera, catalogue)
    sol = solver.solve(detections.stars, t_ns, observer)   # observer: aberration (optional)
    if sol.ok: sol.q, sol.ra_deg, sol.dec_deg, sol.roll_deg, sol.hip,
               sol.focal_length_mm, sol.lens ...

Modules: ``patterns`` (four-star codes), ``database`` (the pattern table and
its files), ``cache`` (which database a camera needs; found or built),
``lost`` (the lost-in-space search and its work budget), ``verify``
(prediction, matching, false-match probability), ``lens`` (focal length
and distortion, per frame and filtered), ``solver`` (the state machine and
the :class:`Solution`), ``skyindex`` (declination-sorted cone search);
``calibration`` and ``affine`` serve ``tracker calibrate`` and
``tracker validate``.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from tracker.camera import CameraModel
from tracker.config import IdentifyConfig
from tracker.identify.cache import cache_dir, find_or_build, serves
from tracker.identify.database import DatabaseError, PatternDatabase, Progress, ProgressLines
from tracker.identify.solver import LensReport, Solution, Solver

__all__ = ["make_solver", "database_for", "field_mag_limit", "Solver", "Solution",
           "LensReport", "DatabaseError"]

_log = logging.getLogger(__name__)

# With catalogue.mag_limit null the solver keeps the stars an average frame
# holds this many of (between Hp 6.0 and the file's limit).
FIELD_STARS = 150
_MIN_FIELD_MAG = 6.0


def field_mag_limit(catalogue, camera: CameraModel) -> float:
    """The Hp limit at which an average frame of this camera holds FIELD_STARS stars."""
    solid_angle = camera.width * camera.height / camera.f_px ** 2     # steradians, small field
    wanted = int(math.ceil(FIELD_STARS * 4 * math.pi / max(solid_angle, 1e-12)))
    if wanted >= len(catalogue.mag):
        return float(catalogue.mag_limit)
    return max(_MIN_FIELD_MAG, float(catalogue.mag[wanted]))


def database_for(cfg: IdentifyConfig, camera: CameraModel, catalogue,
                 progress: Progress | None = None) -> PatternDatabase:
    """The pattern database for this camera: the configured file, or found or built.

    With ``cfg.database`` null the camera's database (its design a function
    of the camera's configuration alone, tracker.identify.cache) is looked
    for in the package's data folder and the cache folder and built into the
    cache folder when neither holds it (logged, or reported to
    ``progress(stage, fraction)``). A cached database that fails its
    checksum is built again.
    """
    if cfg.database is not None:
        return PatternDatabase.load(cfg.database)
    folder = cache_dir(cfg.cache_dir)
    progress = progress or ProgressLines(
        _log.info, prefix="building the pattern database (once; `tracker database build` "
        "does it ahead of time)")
    path = find_or_build(camera, catalogue.path or None, catalogue.sha256, folder, progress)
    try:
        return PatternDatabase.load(path)
    except DatabaseError as exc:
        if path.parent != folder:
            raise                     # not ours to replace
        _log.warning("%s; building it again", exc)
        path.unlink()
        path = find_or_build(camera, catalogue.path or None, catalogue.sha256, folder,
                             progress)
        return PatternDatabase.load(path)


def make_solver(cfg: IdentifyConfig, camera: CameraModel, catalogue,
                progress: Progress | None = None) -> Solver:
    """A solver for this camera with its pattern database (:func:`database_for`).

    A database named explicitly that does not serve the camera is loaded
    anyway and every solve returns ``reason="wrong_fov"`` (logged once here).
    With ``catalogue.follow_field`` (``catalogue.mag_limit`` null) the
    solver keeps the catalogue's stars to :func:`field_mag_limit`, and at
    least those of the database.
    """
    db = database_for(cfg, camera, catalogue, progress)
    f_low = camera.f_px * (1.0 - cfg.focal_tolerance)
    f_high = camera.f_px * (1.0 + cfg.focal_tolerance)
    fov_error = None
    if not serves(db.design, camera, f_low, f_high):
        fov_error = (f"{db.path}: built for fields with a region radius of "
                     f"{db.design.region_radius_deg:g} deg, this camera needs "
                     f"{math.degrees(camera.fov_diagonal_rad):.2f} deg diagonal")
        _log.warning("pattern database does not fit the camera: %s", fov_error)
    bound = db.bind(catalogue)
    refine = catalogue
    if getattr(catalogue, "follow_field", False):
        limit = max(field_mag_limit(catalogue, camera), float(np.max(bound.mag, initial=0.0)))
        refine = catalogue.brightest(limit)
    return Solver(cfg, camera, bound, refine, fov_error)
