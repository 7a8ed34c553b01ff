"""Which pattern database a camera needs, and where it is kept: found, or built once.

A database is designed for a field (:func:`design_for`): its regions are
about the size of the camera's field and its thresholds a few of its
pixels. The design is a pure function of the camera's configuration (image
size, pixel size, focal length): no other database is ever taken in its
place, so the same frame and configuration solve the same way whatever
databases other cameras, lenses or earlier versions left in the folders.
:func:`serves` still says whether a design suits a camera over its whole
focal-length prior (+-12 % in region radius), for a database named
explicitly (``identify.database``) and for ``tracker database list``.

:func:`find_or_build` looks in the package's data folder (:mod:`tracker.data`)
and then in the cache folder (:func:`cache_dir`) for the file named by the
design and the catalogue's SHA-256 (:func:`database_file`) whose metadata
holds that very design and catalogue; when neither holds it, it builds it
from the catalogue into the cache folder, with progress, and the next start
finds it there. Builds are deterministic (a fixed epoch, elementwise
arithmetic), so a database built on a laptop equals the one built on the Pi.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict
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

__all__ = ["cache_dir", "design_for", "serves", "database_file", "find_database",
           "find_or_build", "BUILD_EPOCH"]

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


def serves(design: DatabaseDesign, camera: CameraModel, f_low_px: float, f_high_px: float
           ) -> bool:
    """True if the design suits the camera for every focal length in [f_low_px, f_high_px]."""
    rho = math.radians(design.region_radius_deg)
    wide, narrow = _region_radius(camera, f_low_px), _region_radius(camera, f_high_px)
    return rho / (1 + SERVE_MARGIN) <= narrow and wide <= rho * (1 + SERVE_MARGIN)


def database_file(design: DatabaseDesign, catalogue_sha256: str) -> str:
    """File name of a design built from a catalogue: the design's name and the
    first 12 hex digits of the catalogue's SHA-256."""
    return design.name.replace(".npz", f"_{catalogue_sha256[:12]}.npz")


def find_database(design: DatabaseDesign, catalogue_sha256: str, folders: list[Path]
                  ) -> Path | None:
    """The first of ``folders`` holding this design built from this catalogue, or None.

    Found by file name (:func:`database_file`) and checked in its metadata;
    databases of other designs are never looked at.
    """
    for folder in folders:
        path = Path(folder) / database_file(design, catalogue_sha256)
        meta = read_meta(path)
        if (meta is not None and meta.get("catalogue_sha256") == catalogue_sha256
                and meta.get("design") == asdict(design)):
            return path
    return None


def find_or_build(camera: CameraModel, catalogue_path, catalogue_sha256: str, folder: Path,
                  progress: Progress | None = None) -> Path:
    """The camera's database (:func:`design_for`): found (bundled, then ``folder``) or built.

    ``catalogue_path`` is the catalogue file the database is built from
    (None = the bundled one); ``progress(stage, fraction)`` follows a build.
    Raises :class:`DatabaseError` if the folder cannot be written.
    """
    design = design_for(camera)
    found = find_database(design, catalogue_sha256, [bundled_database_dir(), folder])
    if found is not None:
        return found
    try:    # before the build, so a folder that cannot take it costs nothing
        folder.mkdir(parents=True, exist_ok=True)
        if not os.access(folder, os.W_OK):
            raise PermissionError(13, "Permission denied")
    except OSError as exc:
        raise _unwritable(folder, exc) from None
    catalogue = load_catalogue(catalogue_path, epoch_year=BUILD_EPOCH)
    path = folder / database_file(design, catalogue_sha256)
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
