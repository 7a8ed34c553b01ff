"""The bundled star catalogue: load it, check it, move it to the epoch.

The bundled file ``stars.npz`` (package data in ``tracker/data/``, built by
``tools/build_catalogue.py`` from ESA's Hipparcos new reduction, van Leeuwen
2007, CDS I/311; see ``tracker/data/README.md``) holds, per star, the HIP number, ICRS RA/Dec at
epoch J1991.25, proper motion, parallax and Hp magnitude, sorted brightest
first. Beside it, ``stars.npz.sha256`` holds its SHA-256 in ``sha256sum``
format; :func:`load_catalogue` refuses a file whose bytes do not match.

Proper motion is applied rigorously as uniform straight-line space motion
(ESA SP-1200, Vol. 1, Sect. 1.5.5; Butkevich & Lindegren 2014, A&A 570,
A62) with the radial velocity unknown and taken as zero. With zero radial
velocity the star's velocity is perpendicular to the epoch-1991.25 line of
sight, so the direction at epoch t is::

    u(t) = (r0 + mu0 * dt) / |r0 + mu0 * dt|,   dt = t - 1991.25 (Julian years)

where r0 is the unit vector at J1991.25 and mu0 = pmRA* p + pmDE q the
proper-motion vector (p, q: unit vectors toward +RA and +Dec). The parallax
then cancels out of the direction (it enters only through the radial
proper motion, which is zero here), so it is not needed for positions.
Positions stay barycentric: annual parallax (< 0.77 arcsec, not applied)
and aberration (~20 arcsec: the solver applies it for each frame's observer,
tracker.astrometry) depend on the observer. The epoch follows the frames'
absolute time when they have one (tracker.pipeline).

Angles are radians; epochs are decimal Julian years (J2000.0 = 2000.0 =
JD 2451545.0 TT; the system clock's UTC is used for "now", a difference of
about a minute, irrelevant for proper motion).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import math
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracker.attitude import vector_to_radec
from tracker.config import CatalogueConfig
from tracker.data import data_dir
from tracker.errors import UserError

__all__ = [
    "Catalogue", "CatalogueError", "default_catalogue_path", "julian_year_now",
    "load_catalogue", "propagate",
]

_MAS_TO_RAD = math.pi / (180.0 * 3600.0 * 1000.0)
_UNIX_EPOCH_JD = 2440587.5
_J2000_JD = 2451545.0
_JULIAN_YEAR_DAYS = 365.25

# Arrays the file must hold: name -> dtype. Scalars have shape (), the
# per-star arrays (N,); bv_mag alone may hold NaN (colour unknown).
_SCALARS = {"format_version": np.int32, "epoch_year": np.float64, "mag_limit": np.float64}
_STAR_ARRAYS = {
    "hip": np.int32,
    "ra_rad": np.float64,
    "dec_rad": np.float64,
    "parallax_mas": np.float32,
    "pmra_mas_per_yr": np.float32,
    "pmdec_mas_per_yr": np.float32,
    "hp_mag": np.float32,
    "bv_mag": np.float32,
}
_FORMAT_VERSION = 1


class CatalogueError(UserError, ValueError):
    """A catalogue file that cannot be used; the message is one line naming it."""


@dataclass(frozen=True, eq=False)
class Catalogue:
    """Stars at one epoch, sorted by Hp magnitude, brightest first.

    Attributes
    ----------
    hip : int32 (N,)
        Hipparcos catalogue number.
    ra, dec : float64 (N,)
        ICRS right ascension in [0, 2 pi) and declination, radians, at
        ``epoch_year``.
    vectors : float64 (N, 3)
        ICRS unit vectors of (ra, dec).
    mag : float32 (N,)
        Hipparcos Hp magnitude (non-decreasing).
    bv : float32 (N,)
        Johnson B-V colour index, magnitudes.
    epoch_year : float
        Decimal Julian year the positions are for.
    mag_limit : float
        Faintest Hp kept (the file's own limit when none was asked for).
    sha256 : str
        SHA-256 (hex) of the catalogue file, to tie derived data to it.
    path : str
        The file it was read from.
    follow_field : bool
        True when no magnitude limit was asked for: users of the catalogue
        (the solver) may keep only the stars their field needs.

    The arrays are read-only.
    """

    hip: np.ndarray
    ra: np.ndarray
    dec: np.ndarray
    vectors: np.ndarray
    mag: np.ndarray
    bv: np.ndarray
    epoch_year: float
    mag_limit: float
    sha256: str
    path: str = ""
    follow_field: bool = False

    def __len__(self) -> int:
        return int(self.hip.shape[0])

    @classmethod
    def from_config(cls, cfg: CatalogueConfig) -> Catalogue:
        """Load the catalogue the ``catalogue`` config section describes."""
        return load_catalogue(cfg.path, epoch_year=cfg.epoch_year, mag_limit=cfg.mag_limit)

    def brightest(self, mag_limit: float) -> Catalogue:
        """The stars with Hp <= mag_limit (a prefix: views, no copies), as a fixed limit."""
        n = int(np.searchsorted(self.mag, np.float32(mag_limit), side="right"))
        return dataclasses.replace(
            self, hip=self.hip[:n], ra=self.ra[:n], dec=self.dec[:n], vectors=self.vectors[:n],
            mag=self.mag[:n], bv=self.bv[:n], mag_limit=min(self.mag_limit, float(mag_limit)),
            follow_field=False)


def default_catalogue_path() -> Path:
    """The bundled ``stars.npz``, package data of :mod:`tracker.data`."""
    return data_dir() / "stars.npz"


def julian_year_now() -> float:
    """The current epoch as a decimal Julian year, from the system clock."""
    jd = time.time() / 86400.0 + _UNIX_EPOCH_JD
    return 2000.0 + (jd - _J2000_JD) / _JULIAN_YEAR_DAYS


def propagate(ra0: np.ndarray, dec0: np.ndarray, pmra_mas_per_yr: np.ndarray,
              pmdec_mas_per_yr: np.ndarray, dt_years: float) -> np.ndarray:
    """ICRS unit vectors (N, 3) after ``dt_years`` of space motion.

    ``ra0``, ``dec0`` in radians; ``pmra_mas_per_yr`` includes cos(dec)
    (Hipparcos pmRA*). Radial velocity is taken as zero (module docstring).
    """
    ra0 = np.asarray(ra0, dtype=np.float64)
    dec0 = np.asarray(dec0, dtype=np.float64)
    sin_ra, cos_ra = np.sin(ra0), np.cos(ra0)
    sin_dec, cos_dec = np.sin(dec0), np.cos(dec0)
    step_ra = np.asarray(pmra_mas_per_yr, dtype=np.float64) * (_MAS_TO_RAD * dt_years)
    step_dec = np.asarray(pmdec_mas_per_yr, dtype=np.float64) * (_MAS_TO_RAD * dt_years)
    # r0 + dt * (pmRA* p + pmDE q), p = (-sin ra, cos ra, 0),
    # q = (-sin dec cos ra, -sin dec sin ra, cos dec).
    u = np.empty(ra0.shape + (3,), dtype=np.float64)
    u[..., 0] = cos_dec * cos_ra - step_ra * sin_ra - step_dec * sin_dec * cos_ra
    u[..., 1] = cos_dec * sin_ra + step_ra * cos_ra - step_dec * sin_dec * sin_ra
    u[..., 2] = sin_dec + step_dec * cos_dec
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return u


def _read_checked(path: Path) -> tuple[bytes, str]:
    """The file's bytes and SHA-256, verified against ``<path>.sha256``."""
    sum_path = Path(f"{path}.sha256")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CatalogueError(f"{path}: catalogue file not found") from None
    except OSError as exc:
        raise CatalogueError(f"{path}: cannot read catalogue file ({exc.strerror})") from None
    try:
        expected = sum_path.read_text(encoding="ascii").split()[0].lower()
    except FileNotFoundError:
        raise CatalogueError(f"{sum_path}: checksum file not found") from None
    except (OSError, UnicodeDecodeError, IndexError):
        raise CatalogueError(f"{sum_path}: not a sha256sum line") from None
    digest = hashlib.sha256(data).hexdigest()
    if digest != expected:
        raise CatalogueError(f"{path}: SHA-256 mismatch, the file is corrupt or changed "
                             f"(expected {expected[:12]}..., found {digest[:12]}...)")
    return data, digest


def _read_arrays(path: Path, data: bytes) -> dict[str, np.ndarray]:
    """The arrays of the .npz bytes, checked for names, dtypes and shapes."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise CatalogueError(f"{path}: not a readable .npz file ({exc})") from None
    for name, dtype in {**_SCALARS, **_STAR_ARRAYS}.items():
        if name not in arrays:
            raise CatalogueError(f"{path}: array {name!r} is missing")
        if arrays[name].dtype != dtype:
            raise CatalogueError(f"{path}: array {name!r} has dtype {arrays[name].dtype}, "
                                 f"expected {np.dtype(dtype)}")
    n = len(arrays["hip"]) if arrays["hip"].ndim else 0
    for name in {**_SCALARS, **_STAR_ARRAYS}:
        shape = () if name in _SCALARS else (n,)
        if arrays[name].shape != shape:
            raise CatalogueError(f"{path}: array {name!r} has shape {arrays[name].shape}, "
                                 f"expected {shape}")
        if name != "bv_mag" and not np.all(np.isfinite(arrays[name])):
            raise CatalogueError(f"{path}: array {name!r} holds NaN or infinity")
    version = int(arrays["format_version"])
    if version != _FORMAT_VERSION:
        raise CatalogueError(f"{path}: format version {version}, expected {_FORMAT_VERSION}")
    if np.any(np.diff(arrays["hp_mag"]) < 0):
        raise CatalogueError(f"{path}: stars are not sorted by magnitude")
    return arrays


def load_catalogue(path: str | Path | None = None, epoch_year: float | None = None,
                   mag_limit: float | None = None) -> Catalogue:
    """Load, verify and propagate the star catalogue.

    Parameters
    ----------
    path : file, or None for :func:`default_catalogue_path`.
    epoch_year : decimal Julian year of the positions; None = now.
    mag_limit : faintest Hp magnitude kept; None = every star in the file,
        with ``follow_field`` set. Asking for fainter stars than the file
        holds is an error.

    Raises
    ------
    CatalogueError
        Missing file or checksum, checksum mismatch, unreadable or truncated
        file, wrong or missing arrays, or a magnitude limit beyond the file's.
    """
    path = default_catalogue_path() if path is None else Path(path)
    data, digest = _read_checked(path)
    arrays = _read_arrays(path, data)
    file_limit = float(arrays["mag_limit"])
    follow_field = mag_limit is None
    if mag_limit is None:
        mag_limit = file_limit
    elif not math.isfinite(mag_limit):
        raise ValueError(f"mag_limit must be finite, got {mag_limit!r}")
    elif mag_limit > file_limit:
        raise CatalogueError(f"{path}: holds stars to Hp {file_limit:g}, cannot give "
                             f"mag_limit {mag_limit:g}; rebuild it with "
                             f"tools/build_catalogue.py --mag-limit {mag_limit:g}")
    epoch = julian_year_now() if epoch_year is None else float(epoch_year)
    if not math.isfinite(epoch):
        raise ValueError(f"epoch_year must be finite, got {epoch_year!r}")
    n = int(np.searchsorted(arrays["hp_mag"], np.float32(mag_limit), side="right"))
    vectors = propagate(arrays["ra_rad"][:n], arrays["dec_rad"][:n],
                        arrays["pmra_mas_per_yr"][:n], arrays["pmdec_mas_per_yr"][:n],
                        epoch - float(arrays["epoch_year"]))
    ra, dec = vector_to_radec(vectors)
    fields = {"hip": arrays["hip"][:n], "ra": ra, "dec": dec, "vectors": vectors,
              "mag": arrays["hp_mag"][:n], "bv": arrays["bv_mag"][:n]}
    for array in fields.values():
        array.flags.writeable = False
    return Catalogue(**fields, epoch_year=epoch, mag_limit=float(mag_limit), sha256=digest,
                     path=str(path), follow_field=follow_field)
