"""Which pattern database a camera needs, and where it is kept: found, or built once.

A database is designed for a field (:func:`design_for`): its regions are
about the size of the camera's field and its thresholds a few of its
pixels. It serves every camera whose ideal region radius, over the whole
focal-length prior, lies within +-12 % of its own (:func:`serves`), so a
lens a few percent off, or a similar camera, reuses it.

:func:`find_or_build` looks in the package's data folder (:mod:`tracker.data`) and
then in the cache folder (:func:`cache_dir`) for a database that serves the
camera and was built from the same catalogue (SHA-256 equal); when none
does it builds one from the bundled catalogue into the cache folder, with
progress, and the next start finds it there. Builds are deterministic (a
fixed epoch, elementwise arithmetic), so a database built on a laptop
equals the one built on the Pi.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.identify.database import (
    DatabaseDesign,
    DatabaseError,
    Progress,
    build_database,
    bundled_database_dir,
    read_meta,
    save_database,
)

__all__ = ["cache_dir", "design_for", "serves", "find_database", "find_or_build",
           "BUILD_EPOCH"]

# Design constants (angles from the camera):
REGION_SCALE = 1.0      # region radius / radius of the disc with the frame's area
LATTICE_FRACTION = 0.35  # region centres lie within this fraction of the radius of any point
BLEND_PX = 2.5          # stars this close to a comparable one are one spot
MIN_EDGE_PX = 5.0       # shorter pattern edges carry little shape
PATTERN_STARS = 8       # a region's brightest stars forming its patterns
VERIFY_STARS = 30       # a region's brightest stars checked against hypotheses
KEY_BIN = 0.02          # code bin width of the index
SERVE_MARGIN = 0.12     # a database serves region radii within +-12 % of its own
BUILD_EPOCH = 2025.0    # positions used to choose regions (proper motion is irrelevant)


def cache_dir(configured: str | None = None) -> Path:
    """Where built databases are kept.

    ``configured`` (``identify.cache_dir``) wins; else ``$STATE_DIRECTORY``
    (systemd sets it from the unit's StateDirectory=, /var/lib/startracker on
    the Pi); else ``$XDG_CACHE_HOME/startracker``; else ``~/.cache/startracker``.
    """
    if configured:
        return Path(configured).expanduser()
    state = os.environ.get("STATE_DIRECTORY")
    if state:
        return Path(state.split(":")[0])
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "startracker"


def _region_radius(camera: CameraModel, f_px: float) -> float:
    """Ideal region radius (radians) for the camera at focal length f_px."""
    return REGION_SCALE * math.atan(math.sqrt(camera.width * camera.height / math.pi) / f_px)


def design_for(camera: CameraModel) -> DatabaseDesign:
    """The database design for a camera at its focal length (module docstring)."""
    return design_for_radius(math.degrees(_region_radius(camera, camera.f_px)),
                             math.degrees(1.0 / camera.f_px))


def design_for_radius(region_radius_deg: float, pixel_deg: float) -> DatabaseDesign:
    """The design for a region radius and a pixel size (both degrees)."""
    return DatabaseDesign(region_radius_deg=round(region_radius_deg, 4),
                          lattice_deg=round(LATTICE_FRACTION * region_radius_deg, 4),
                          pattern_stars=PATTERN_STARS, verify_stars=VERIFY_STARS,
                          blend_deg=round(BLEND_PX * pixel_deg, 6),
                          min_edge_deg=round(MIN_EDGE_PX * pixel_deg, 6), key_bin=KEY_BIN)


def _current(design: DatabaseDesign) -> bool:
    """Was the design made by this version's rules (the same choices but the field)?"""
    made = design_for_radius(design.region_radius_deg, 1.0)
    return (math.isclose(design.lattice_deg / design.region_radius_deg,
                         made.lattice_deg / made.region_radius_deg, rel_tol=1e-3)
            and (design.pattern_stars, design.verify_stars, design.key_bin)
            == (made.pattern_stars, made.verify_stars, made.key_bin))


def serves(design: DatabaseDesign, camera: CameraModel, f_low_px: float, f_high_px: float
           ) -> bool:
    """True if the design suits the camera for every focal length in [f_low_px, f_high_px]."""
    rho = math.radians(design.region_radius_deg)
    wide, narrow = _region_radius(camera, f_low_px), _region_radius(camera, f_high_px)
    return rho / (1 + SERVE_MARGIN) <= narrow and wide <= rho * (1 + SERVE_MARGIN)


def find_database(camera: CameraModel, f_low_px: float, f_high_px: float, catalogue_sha256: str,
                  folders: list[Path]) -> Path | None:
    """The database in ``folders`` that serves the camera best, or None.

    Best: region radius nearest the camera's at its focal length; ties go
    to the earlier folder and then the file name, so the choice is fixed.
    """
    ideal = math.degrees(_region_radius(camera, camera.f_px))
    best, best_score = None, math.inf
    for folder in folders:
        for path in sorted(Path(folder).glob("patterns_*.npz")):
            meta = read_meta(path)
            if meta is None or meta.get("catalogue_sha256") != catalogue_sha256:
                continue
            try:
                design = DatabaseDesign(**meta["design"])
            except (TypeError, DatabaseError):
                continue
            if not _current(design):
                continue
            score = abs(math.log(design.region_radius_deg / ideal))
            if serves(design, camera, f_low_px, f_high_px) and score < best_score:
                best, best_score = path, score
    return best


def find_or_build(camera: CameraModel, f_low_px: float, f_high_px: float, catalogue_path,
                  catalogue_sha256: str, folder: Path, progress: Progress | None = None
                  ) -> Path:
    """A database serving the camera: found (bundled, then ``folder``) or built into ``folder``.

    ``catalogue_path`` is the catalogue file the database is built from
    (None = the bundled one); ``progress(stage, fraction)`` follows a build.
    Raises :class:`DatabaseError` if the folder cannot be written.
    """
    found = find_database(camera, f_low_px, f_high_px, catalogue_sha256,
                          [bundled_database_dir(), folder])
    if found is not None:
        return found
    design = design_for(camera)
    try:    # before the build, so a folder that cannot take it costs nothing
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK):
            raise PermissionError(13, "Permission denied")
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    catalogue = load_catalogue(catalogue_path, epoch_year=BUILD_EPOCH)
    path = folder / design.name
    t0 = time.perf_counter()
    built = build_database(catalogue, design, progress)
    built["meta"]["build_seconds"] = round(time.perf_counter() - t0, 2)
    try:
        save_database(path, built)
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    return path


def _unwritable(folder: Path, exc: OSError) -> DatabaseError:
    return DatabaseError(f"{folder}: cannot write the pattern database ({exc.strerror or exc});"
                         " set identify.cache_dir to a writable folder")
