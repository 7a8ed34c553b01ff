"""The pattern database: catalogue star pairs sorted by their angular separation.

Lost-in-space identification (tracker.identify.lost) needs, for a measured
angle between two image stars, every catalogue pair whose separation lies
within a tolerance of it. The database holds that table for one range of
fields of view:

* ``hip`` (int32, S): the database stars, a subset of the catalogue chosen
  brightest first with at most ``stars_per_region`` stars in any circle of
  radius ``region_radius`` (sky-uniform thinning, so the Milky Way does not
  flood the table while sparse regions keep their faint stars), down to
  ``mag_limit``;
* ``pair_a``, ``pair_b`` (uint16, P): indices into ``hip`` of every pair
  closer than ``max_pair_angle``, sorted by separation.

Separations themselves are not stored: :meth:`PatternDatabase.bind` recomputes
them from the catalogue's vectors at the observation epoch (proper motion
included) and sorts once, so the table on disk stays small (4 bytes a pair)
and never goes stale. A binary search in the sorted separations does the job of
Mortari's k-vector (Mortari, Samaan, Bruccoleri, Junkins 2004, "The Pyramid
Star Identification Technique", Navigation 51(3)) in O(log P).

Files are ``.npz`` with a JSON ``meta`` entry (design field of view, limits,
build parameters, catalogue checksum) and the SHA-256 of the arrays' bytes,
checked on load. Angles are radians inside, degrees in ``meta``.
"""

from __future__ import annotations

import hashlib
import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracker.config import ConfigError

__all__ = ["DatabaseError", "PatternDatabase", "BoundDatabase", "build_database",
           "default_database_dir", "find_database"]

FORMAT_VERSION = 1
_ARRAYS = ("hip", "pair_a", "pair_b")
_CHUNK = 512


class DatabaseError(ConfigError):
    """A pattern database that cannot be used; the message is one line naming it."""


def default_database_dir() -> Path:
    """The repository's ``catalogue/`` folder, where the committed databases live."""
    return Path(__file__).resolve().parents[2] / "catalogue"


def _arrays_digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in _ARRAYS:
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def _neighbour_pairs(vectors: np.ndarray, max_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (a < b) of unit vectors separated by less than max_angle (radians)."""
    cos_max = math.cos(max_angle)
    va, vb = [], []
    v32 = vectors.astype(np.float32)
    for start in range(0, len(vectors), _CHUNK):
        dots = v32[start:start + _CHUNK] @ v32.T
        rows, cols = np.nonzero(dots > cos_max - 1e-6)
        rows += start
        keep = cols > rows
        va.append(rows[keep])
        vb.append(cols[keep])
    return np.concatenate(va), np.concatenate(vb)


def _thin(vectors: np.ndarray, radius: float, per_region: int) -> np.ndarray:
    """Indices kept brightest first with fewer than per_region kept within radius."""
    if per_region <= 0:
        return np.arange(len(vectors))
    a, b = _neighbour_pairs(vectors, radius)
    # neighbours of each star that are brighter (smaller index; input is sorted)
    order = np.argsort(b, kind="stable")
    a, b = a[order], b[order]
    starts = np.searchsorted(b, np.arange(len(vectors) + 1))
    kept = np.zeros(len(vectors), dtype=bool)
    for s in range(len(vectors)):
        if np.count_nonzero(kept[a[starts[s]:starts[s + 1]]]) < per_region:
            kept[s] = True
    return np.flatnonzero(kept)


def build_database(catalogue, *, fov_min_deg: float, fov_max_deg: float, mag_limit: float,
                   max_pair_deg: float, stars_per_region: int, region_radius_deg: float,
                   name: str = "") -> dict:
    """Build the arrays and metadata of a database (see the module docstring).

    ``catalogue`` is a :class:`tracker.catalogue.Catalogue` (brightest first).
    ``fov_min_deg``..``fov_max_deg`` is the range of diagonal fields of view
    the database serves. Returns a dict ready for :func:`save_database`.
    """
    n = int(np.searchsorted(catalogue.mag, np.float32(mag_limit), side="right"))
    vectors = np.asarray(catalogue.vectors[:n], dtype=np.float64)
    keep = _thin(vectors, math.radians(region_radius_deg), stars_per_region)
    if len(keep) > 65535:
        raise DatabaseError(f"{name or 'database'}: {len(keep)} stars do not fit uint16 "
                            "indices; lower mag_limit or stars_per_region")
    vectors = vectors[keep]
    a, b = _neighbour_pairs(vectors, math.radians(max_pair_deg))
    sep = np.arccos(np.clip(np.einsum("ij,ij->i", vectors[a], vectors[b]), -1.0, 1.0))
    order = np.argsort(sep, kind="stable")
    arrays = {"hip": np.asarray(catalogue.hip[:n][keep], dtype=np.int32),
              "pair_a": a[order].astype(np.uint16), "pair_b": b[order].astype(np.uint16)}
    meta = {
        "format_version": FORMAT_VERSION, "name": name,
        "fov_min_deg": float(fov_min_deg), "fov_max_deg": float(fov_max_deg),
        "mag_limit": float(mag_limit), "max_pair_deg": float(max_pair_deg),
        "stars_per_region": int(stars_per_region), "region_radius_deg": float(region_radius_deg),
        "n_stars": len(keep), "n_pairs": len(a),
        "catalogue_sha256": getattr(catalogue, "sha256", ""),
        "sha256": _arrays_digest(arrays),
    }
    return {"meta": meta, **arrays}


def save_database(path: str | Path, built: dict) -> None:
    """Write a database built by :func:`build_database` (compressed .npz)."""
    meta = json.dumps(built["meta"], sort_keys=True)
    np.savez_compressed(path, meta=np.array(meta), **{k: built[k] for k in _ARRAYS})


@dataclass(frozen=True, eq=False)
class PatternDatabase:
    """A loaded, checksummed database (arrays read-only; see the module docstring)."""

    path: str
    meta: dict
    hip: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray

    @property
    def max_pair_angle(self) -> float:
        return math.radians(self.meta["max_pair_deg"])

    def fits(self, fov_diagonal_rad: float) -> bool:
        """True if a camera with this diagonal field of view is in the design range."""
        deg = math.degrees(fov_diagonal_rad)
        return self.meta["fov_min_deg"] <= deg <= self.meta["fov_max_deg"]

    @classmethod
    def load(cls, path: str | Path) -> PatternDatabase:
        """Read and verify a database file; raises :class:`DatabaseError`."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as npz:
                meta = json.loads(str(npz["meta"]))
                arrays = {name: npz[name] for name in _ARRAYS}
        except FileNotFoundError:
            raise DatabaseError(f"{path}: pattern database not found") from None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            raise DatabaseError(f"{path}: not a readable pattern database ({exc})") from None
        if meta.get("format_version") != FORMAT_VERSION:
            raise DatabaseError(f"{path}: format version {meta.get('format_version')}, "
                                f"expected {FORMAT_VERSION}")
        if _arrays_digest(arrays) != meta.get("sha256"):
            raise DatabaseError(f"{path}: SHA-256 of the arrays does not match its metadata; "
                                "the file is corrupt, rebuild it with tools/build_database.py")
        for array in arrays.values():
            array.flags.writeable = False
        return cls(path=str(path), meta=meta, **arrays)

    def bind(self, catalogue) -> BoundDatabase:
        """Attach the catalogue's epoch positions; sort the pairs by separation."""
        index = np.searchsorted(catalogue.hip, self.hip, sorter=np.argsort(catalogue.hip))
        by_hip = np.argsort(catalogue.hip)
        index = by_hip[np.clip(index, 0, len(by_hip) - 1)]
        missing = catalogue.hip[index] != self.hip
        if np.any(missing):
            raise DatabaseError(
                f"{self.path}: {int(missing.sum())} database stars (e.g. HIP "
                f"{int(self.hip[missing][0])}) are not in the catalogue; its mag_limit "
                f"must be >= {self.meta['mag_limit']:g}")
        vectors = np.ascontiguousarray(catalogue.vectors[index], dtype=np.float64)
        a = self.pair_a.astype(np.int32)
        b = self.pair_b.astype(np.int32)
        sep = np.arccos(np.clip(np.einsum("ij,ij->i", vectors[a], vectors[b]), -1.0, 1.0))
        order = np.argsort(sep, kind="stable")
        return BoundDatabase(db=self, vectors=vectors, mag=np.asarray(catalogue.mag[index]),
                             sep=sep[order], a=a[order], b=b[order])


@dataclass(frozen=True, eq=False)
class BoundDatabase:
    """A database tied to catalogue positions: what the solver searches.

    ``vectors`` (S, 3) ICRS unit vectors of the database stars at the epoch,
    ``mag`` their Hp magnitudes; ``sep`` (P,) ascending pair separations
    (radians) with star indices ``a``, ``b`` (int32).
    """

    db: PatternDatabase
    vectors: np.ndarray
    mag: np.ndarray
    sep: np.ndarray
    a: np.ndarray
    b: np.ndarray

    @property
    def hip(self) -> np.ndarray:
        return self.db.hip


def find_database(fov_diagonal_rad: float, folder: str | Path | None = None) -> Path:
    """The committed database whose design range holds this field of view.

    When several fit, the one whose range centre is nearest wins. Raises
    :class:`DatabaseError` naming the available ranges if none fits.
    """
    folder = default_database_dir() if folder is None else Path(folder)
    deg = math.degrees(fov_diagonal_rad)
    best, best_dist, ranges = None, math.inf, []
    for path in sorted(folder.glob("patterns_*.npz")):
        try:
            with np.load(path, allow_pickle=False) as npz:
                meta = json.loads(str(npz["meta"]))
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):
            continue
        lo, hi = meta["fov_min_deg"], meta["fov_max_deg"]
        ranges.append(f"{path.name} {lo:g}-{hi:g}")
        if lo <= deg <= hi and abs(deg - (lo + hi) / 2) < best_dist:
            best, best_dist = path, abs(deg - (lo + hi) / 2)
    if best is None:
        have = "; ".join(ranges) if ranges else "none"
        raise DatabaseError(f"{folder}: no pattern database for a {deg:.2f} deg diagonal field "
                            f"of view (have: {have}); build one with tools/build_database.py")
    return best
