"""The pattern database: four-star patterns of the catalogue, looked up by their code.

Lost in space (tracker.identify.lost) takes four bright image stars,
computes their scale-free code (tracker.identify.patterns) and looks for
catalogue patterns with the same code. This module decides which catalogue
patterns exist, writes and checks the file, and indexes the patterns by code.

**Which patterns.** The sky is covered by a Fibonacci lattice of region
centres, dense enough that every direction is within ``lattice_deg`` of
one. For each centre the ``verify_stars`` brightest catalogue stars within
``region_radius_deg`` of it are kept; the first ``pattern_stars`` of them
(the region's brightest) give every four-star combination as a pattern.
The region is about the size of the camera's field, so the brightest stars
of any frame are, give or take a few at its edge, the brightest stars of a
nearby region, and four of them form a stored pattern. Stars with a
neighbour closer than ``blend_deg`` and at most 2.5 magnitudes fainter are
skipped: the detector sees the pair as one spot. Patterns with an edge
shorter than ``min_edge_deg`` are not stored (their code is mostly noise).
The magnitude limit follows the field: a region takes its brightest stars
however faint they are (the bundled catalogue reaches Hp 9.0), so a 5 deg
field goes deeper than a 60 deg one, and a sparse part of the sky deeper
than the Milky Way. The union of all regions' stars is also the set the
solver checks a hypothesis against (about ``verify_stars`` per field).

**The file** is an ``.npz`` with ``hip`` (int32, S: the stars, those in
patterns first, each part brightest first), ``patterns`` (uint32, P x 4:
indices into ``hip``) and a JSON
``meta`` entry (the design, counts, the catalogue's SHA-256 and the SHA-256
of the arrays, checked on every load). Positions and codes are not stored:
:meth:`PatternDatabase.bind` computes them from the catalogue at the
observation epoch (proper motion included), so nothing goes stale.

**The index.** Each code is quantised in bins of ``key_bin`` per component
to one integer key (the first component its least significant digit); the
patterns are sorted by key, and a lookup finds, by binary search, one run
of keys for each bin of the last four components its tolerance box
touches. A coarse histogram of the codes (10 cells per component) and one
of the patterns' sizes give what the false-match probability needs: how
many patterns a lookup's box holds by chance, and what share of them has a
size the focal-length prior allows.

Angles are radians inside, degrees in the design and in ``meta``.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tracker.config import ConfigError
from tracker.data import data_dir
from tracker.identify.patterns import codes, edge_angles
from tracker.identify.skyindex import DecSorted

__all__ = ["DatabaseError", "DatabaseDesign", "PatternDatabase", "BoundDatabase",
           "ProgressLines", "build_database", "save_database", "bundled_database_dir"]

FORMAT_VERSION = 2
_ARRAYS = ("hip", "patterns")
# Fibonacci lattice: the farthest any direction lies from the nearest of N
# points is 0.70-0.74 sqrt(4 pi / N) (measured with 20,000 random directions
# for N = 1,000-50,000); 0.75 is used to size it.
_LATTICE_COVER = 0.75
_BLEND_DMAG = 2.5
_MISSING = np.iinfo(np.int64).max
Progress = Callable[[str, float], None]
# Region radii databases are built for: fields of about 3-80 deg (below, the
# bundled catalogue's Hp 9.0 leaves regions with too few stars; above,
# there are too few regions and too much gnomonic stretch).
MIN_REGION_DEG = 1.5
MAX_REGION_DEG = 40.0


class ProgressLines:
    """Build progress as a line of text every ``1/steps`` of the way: ``emit(text)``."""

    def __init__(self, emit: Callable[[str], None], steps: int = 5,
                 prefix: str = "building the pattern database") -> None:
        self.emit, self.steps, self.prefix = emit, steps, prefix
        self._last = -1

    def __call__(self, stage: str, fraction: float) -> None:
        step = int(fraction * self.steps)
        if step != self._last:
            self._last = step
            self.emit(f"{self.prefix}: {stage}, {int(100 * fraction)} %")


class DatabaseError(ConfigError):
    """A pattern database that cannot be used; the message is one line naming it."""


def bundled_database_dir() -> Path:
    """The package's data folder: databases shipped with the package (:mod:`tracker.data`)."""
    return data_dir()


@dataclass(frozen=True)
class DatabaseDesign:
    """How a database is built (module docstring); angles in degrees.

    ``key_bin`` is the width of the code bins of the index.
    """

    region_radius_deg: float
    lattice_deg: float
    pattern_stars: int = 8
    verify_stars: int = 30
    blend_deg: float = 0.0
    min_edge_deg: float = 0.0
    key_bin: float = 0.02

    def __post_init__(self) -> None:
        if not (MIN_REGION_DEG <= self.region_radius_deg <= MAX_REGION_DEG):
            # a region has the area of the field: a 4:3 field is 2 region radii wide
            raise DatabaseError(
                f"a {2 * self.region_radius_deg:.1f} deg field is outside the 3-80 deg "
                "that pattern databases are built for; check camera.focal_length_mm and "
                "camera.pixel_size_um")
        if not 4 <= self.pattern_stars <= min(self.verify_stars, 16):
            raise DatabaseError("pattern_stars must be 4-16 and at most verify_stars")

    @property
    def name(self) -> str:
        """File name: the region radius and a digest of the whole design."""
        digest = hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode())
        return f"patterns_r{self.region_radius_deg:.3f}_{digest.hexdigest()[:10]}.npz"


def _fibonacci_lattice(n: int) -> np.ndarray:
    """n near-uniform unit vectors (n, 3), z decreasing (Gonzalez 2010, Math. Geosci. 42)."""
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    phi = i * (math.pi * (3.0 - math.sqrt(5.0)))
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack((r * np.cos(phi), r * np.sin(phi), z), axis=1)


def _dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot products (len(a), len(b)) computed elementwise, so equal on every machine."""
    return (a[:, None, 0] * b[None, :, 0] + a[:, None, 1] * b[None, :, 1]
            + a[:, None, 2] * b[None, :, 2])


def _blended(vectors: np.ndarray, mag: np.ndarray, angle: float) -> np.ndarray:
    """Stars with a neighbour within ``angle`` no more than 2.5 mag fainter than themselves."""
    out = np.zeros(len(vectors), dtype=bool)
    if angle <= 0 or len(vectors) < 2:
        return out
    index = DecSorted(vectors)
    z = index.z
    lo = np.searchsorted(z, z - angle, side="left")
    hi = np.searchsorted(z, z + angle, side="right")
    counts = hi - lo
    first = np.repeat(np.arange(len(z)), counts)
    second = np.repeat(lo, counts) + (np.arange(int(counts.sum()))
                                      - np.repeat(np.cumsum(counts) - counts, counts))
    keep = first != second
    first, second = first[keep], second[keep]
    va, vb = index.vectors[first], index.vectors[second]
    near = (va[:, 0] * vb[:, 0] + va[:, 1] * vb[:, 1] + va[:, 2] * vb[:, 2]) >= math.cos(angle)
    star = index.order[first[near]]
    other = index.order[second[near]]
    out[star[mag[other] <= mag[star] + _BLEND_DMAG]] = True
    return out


def _region_members(centres: np.ndarray, vectors: np.ndarray, radius: float, count: int
                    ) -> np.ndarray:
    """For each centre, the ``count`` smallest indices of ``vectors`` within ``radius``.

    ``vectors`` are sorted brightest first, so these are the brightest stars
    of the region; rows are padded with _MISSING. Computed in declination
    bands: centres in chunks, each against the stars of its band.
    """
    index = DecSorted(vectors)
    members = np.full((len(centres), count), _MISSING, dtype=np.int64)
    cos_r = math.cos(radius)
    order = np.argsort(centres[:, 2], kind="stable")
    budget = 4_000_000
    start = 0
    while start < len(order):
        # up to 256 centres, fewer while centres x band stars exceed the budget
        size = max(1, min(len(order) - start, 256))
        rows = order[start:start + size]
        z_lo, z_hi = centres[rows[0], 2], centres[rows[-1], 2]
        band_lo = index.band(z_lo, radius).start
        band_hi = index.band(z_hi, radius).stop
        while size > 1 and size * (band_hi - band_lo) > budget:
            size //= 2
            rows = order[start:start + size]
            band_hi = index.band(centres[rows[-1], 2], radius).stop
        band = slice(band_lo, band_hi)
        ranks = np.where(_dots(centres[rows], index.vectors[band]) >= cos_r,
                         index.order[band][None, :], _MISSING)
        k = min(count, ranks.shape[1])
        if k:
            part = np.partition(ranks, k - 1, axis=1)[:, :k] if k < ranks.shape[1] else ranks
            members[rows, :k] = np.sort(part, axis=1)[:, :k]
        start += size
    return members


def _unique_rows(rows: np.ndarray) -> np.ndarray:
    """Distinct rows of an integer array, in lexicographic order."""
    if len(rows) == 0:
        return rows
    order = np.lexsort(rows.T[::-1])
    rows = rows[order]
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.any(rows[1:] != rows[:-1], axis=1)
    return rows[keep]


def build_database(catalogue, design: DatabaseDesign, progress: Progress | None = None) -> dict:
    """Build the arrays and metadata of a database (module docstring).

    ``catalogue`` is a :class:`tracker.catalogue.Catalogue` sorted brightest
    first (its epoch barely matters: regions are degrees wide, proper
    motions arcseconds per decade). ``progress(stage, fraction)`` is called
    as the work advances, with the fraction of the whole build done (0-1).
    Returns a dict ready for :func:`save_database`.
    """
    report = progress or (lambda stage, fraction: None)
    vectors = np.asarray(catalogue.vectors, dtype=np.float64)
    mag = np.asarray(catalogue.mag, dtype=np.float64)
    report("blends", 0.0)
    usable = np.flatnonzero(~_blended(vectors, mag, math.radians(design.blend_deg)))
    radius = math.radians(design.region_radius_deg)
    n_regions = math.ceil(4 * math.pi * (_LATTICE_COVER / math.radians(design.lattice_deg)) ** 2)
    centres = _fibonacci_lattice(n_regions)
    # regions take from the brightest stars; sparse ones are redone with all of them
    cap = len(usable)
    per_sky = design.verify_stars * 4 * math.pi / (math.pi * radius * radius)
    first = min(cap, max(2000, int(8 * per_sky)))
    members = np.full((n_regions, design.verify_stars), _MISSING, dtype=np.int64)
    chunk = max(1, n_regions // 20)
    for start in range(0, n_regions, chunk):
        report("regions", 0.05 + 0.75 * start / n_regions)
        rows = slice(start, start + chunk)
        members[rows] = _region_members(centres[rows], vectors[usable[:first]], radius,
                                        design.verify_stars)
    short = np.flatnonzero(members[:, -1] == _MISSING)
    if len(short) and first < cap:
        members[short] = _region_members(centres[short], vectors[usable], radius,
                                         design.verify_stars)
    report("patterns", 0.8)
    pattern_rows = members[:, :design.pattern_stars]
    combos = np.array(list(itertools.combinations(range(design.pattern_stars), 4)))
    quads = []
    for start in range(0, n_regions, 4096):
        block = pattern_rows[start:start + 4096][:, combos].reshape(-1, 4)
        quads.append(_unique_rows(block[np.all(block != _MISSING, axis=1)]))
        report("patterns", 0.8 + 0.2 * start / n_regions)
    quads = _unique_rows(np.concatenate(quads))
    # indices so far are into `usable`; the database's stars are every member,
    # those in patterns first (so pattern indices stay small), each part brightest first
    in_patterns = np.unique(pattern_rows[pattern_rows != _MISSING])
    others = np.setdiff1d(np.unique(members[members != _MISSING]), in_patterns)
    used = np.concatenate((in_patterns, others))
    stars = usable[used]
    quads = np.searchsorted(in_patterns, quads)
    edges = edge_angles(vectors[stars][quads])
    quads = quads[edges.min(axis=1) >= math.radians(design.min_edge_deg)]
    arrays = {"hip": np.asarray(catalogue.hip[stars], dtype=np.int32),
              "patterns": quads.astype(np.uint32)}
    faintest = float(mag[stars].max()) if len(stars) else math.nan
    meta = {
        "format_version": FORMAT_VERSION, "design": asdict(design),
        "regions": n_regions, "short_regions": int(len(short)),
        "n_stars": len(stars), "n_patterns": len(quads), "faintest_mag": faintest,
        "catalogue_sha256": getattr(catalogue, "sha256", ""),
        "sha256": _arrays_digest(arrays),
    }
    report("done", 1.0)
    return {"meta": meta, **arrays}


def _arrays_digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in _ARRAYS:
        h.update(name.encode())
        h.update(np.ascontiguousarray(arrays[name]).tobytes())
    return h.hexdigest()


def save_database(path: str | Path, built: dict) -> None:
    """Write a database built by :func:`build_database`, atomically, with ``<file>.sha256``.

    The file appears complete or not at all (written beside it, then renamed),
    so two processes building the same database cannot leave half a file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = json.dumps(built["meta"], sort_keys=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez_compressed(fh, meta=np.array(meta), **{k: built[k] for k in _ARRAYS})
        digest = hashlib.sha256(Path(tmp).read_bytes()).hexdigest()
        Path(f"{tmp}.sha256").write_text(f"{digest}  {path.name}\n", encoding="ascii")
        os.replace(f"{tmp}.sha256", f"{path}.sha256")
        os.replace(tmp, path)
    finally:
        for leftover in (tmp, f"{tmp}.sha256"):
            if os.path.exists(leftover):
                os.unlink(leftover)


def read_meta(path: str | Path) -> dict | None:
    """The ``meta`` of a database file, or None if it is not a readable database."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            meta = json.loads(str(npz["meta"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    return meta if meta.get("format_version") == FORMAT_VERSION else None


@dataclass(frozen=True, eq=False)
class PatternDatabase:
    """A loaded, checksummed database (arrays read-only; see the module docstring)."""

    path: str
    meta: dict
    hip: np.ndarray
    patterns: np.ndarray

    @property
    def design(self) -> DatabaseDesign:
        return DatabaseDesign(**self.meta["design"])

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
                                f"expected {FORMAT_VERSION}; rebuild it with "
                                "`tracker database build`")
        if _arrays_digest(arrays) != meta.get("sha256"):
            raise DatabaseError(f"{path}: SHA-256 of the arrays does not match its metadata; "
                                "the file is corrupt, rebuild it with `tracker database build`")
        for array in arrays.values():
            array.flags.writeable = False
        return cls(path=str(path), meta=meta, **arrays)

    def bind(self, catalogue) -> BoundDatabase:
        """Attach the catalogue's epoch positions and index the patterns by code."""
        by_hip = np.argsort(catalogue.hip)
        index = by_hip[np.clip(np.searchsorted(catalogue.hip, self.hip, sorter=by_hip), 0,
                               len(by_hip) - 1)]
        missing = catalogue.hip[index] != self.hip
        if np.any(missing):
            raise DatabaseError(
                f"{self.path}: {int(missing.sum())} database stars (e.g. HIP "
                f"{int(self.hip[missing][0])}) are not in the catalogue; its mag_limit "
                f"must be >= {self.meta['faintest_mag']:.2f}")
        vectors = np.ascontiguousarray(catalogue.vectors[index], dtype=np.float64)
        small = len(self.patterns) == 0 or int(self.patterns.max()) < 65536
        patterns = self.patterns.astype(np.uint16 if small else np.uint32)
        key_bin = self.design.key_bin
        keys = np.empty(len(patterns), dtype=np.int64)
        density = np.zeros(DENSITY_CELLS ** 5, dtype=np.int32)
        sizes = np.zeros(SIZE_BINS, dtype=np.int64)
        for start in range(0, len(patterns), 65536):
            block = patterns[start:start + 65536]
            edges = edge_angles(vectors[block])
            code = codes(edges)
            keys[start:start + len(block)] = code_keys(np.floor(code / key_bin).astype(np.int64),
                                                       key_bin)
            np.add.at(density, _density_cell(code), 1)
            np.add.at(sizes, _size_bin(edges.max(axis=1)), 1)
        order = np.argsort(keys, kind="stable")
        key_type = np.uint32 if code_keys(np.full(5, 1.0 / key_bin), key_bin) < 2**32 else np.int64
        return BoundDatabase(path=self.path, meta=self.meta, hip=self.hip, vectors=vectors,
                             mag=np.asarray(catalogue.mag[index]),
                             keys=keys[order].astype(key_type), patterns=patterns[order],
                             key_bin=key_bin, density=density,
                             size_cdf=np.concatenate(([0.0], np.cumsum(sizes)))
                             / max(1, len(patterns)))


# The density of codes is counted in a coarse grid of DENSITY_CELLS^5 cells
# over the unit cube (an estimate of how many patterns a box holds by chance),
# and the patterns' sizes (largest edge) in SIZE_BINS bins per factor of two.
DENSITY_CELLS = 10
SIZE_BINS = 400
_SIZE_PER_OCTAVE = 20
_SIZE_SMALLEST = 1e-5   # radians; the first bin holds everything smaller


def _size_bin(angle: np.ndarray) -> np.ndarray:
    """Histogram bin of pattern sizes (largest edge, radians), log-spaced."""
    pos = np.log2(np.maximum(angle, _SIZE_SMALLEST) / _SIZE_SMALLEST) * _SIZE_PER_OCTAVE
    return np.clip(pos.astype(np.int64), 0, SIZE_BINS - 1)


def _density_cell(code: np.ndarray) -> np.ndarray:
    """Index (...) of the coarse density cell holding each code (..., 5)."""
    cell = np.clip((code * DENSITY_CELLS).astype(np.int64), 0, DENSITY_CELLS - 1)
    return (cell * (DENSITY_CELLS ** np.arange(5, dtype=np.int64))).sum(axis=-1)


def code_keys(bins: np.ndarray, key_bin: float) -> np.ndarray:
    """Integer keys (...) of quantised codes (..., 5): one base-L digit per component."""
    base = int(math.ceil(1.0 / key_bin)) + 2
    weights = base ** np.arange(5, dtype=np.int64)
    return (np.clip(bins, 0, base - 1) * weights).sum(axis=-1)


@dataclass(frozen=True, eq=False)
class BoundDatabase:
    """A database tied to catalogue positions: what the solver searches.

    ``path``, ``meta`` and ``hip`` are the file's; ``vectors`` (S, 3) ICRS
    unit vectors of the database stars at the epoch, ``mag`` their Hp
    magnitudes; ``patterns`` (P, 4) star indices (uint16 when they fit)
    sorted by ``keys`` (P,), the quantised codes (bin width ``key_bin``);
    ``density`` the coarse histogram of the codes.
    """

    path: str
    meta: dict
    hip: np.ndarray
    vectors: np.ndarray
    mag: np.ndarray
    keys: np.ndarray
    patterns: np.ndarray
    key_bin: float
    density: np.ndarray
    size_cdf: np.ndarray

    def size_fraction(self, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Share of the patterns whose largest edge lies in [low, high] (radians), per row.

        From the size histogram, whole bins (a bin is 3.5 % wide): slightly
        more than the exact share, never less.
        """
        return (self.size_cdf[_size_bin(np.asarray(high)) + 1]
                - self.size_cdf[_size_bin(np.asarray(low))])

    @property
    def design(self) -> DatabaseDesign:
        return DatabaseDesign(**self.meta["design"])

    @property
    def nbytes(self) -> int:
        """Memory held by the arrays, bytes."""
        return sum(a.nbytes for a in (self.hip, self.vectors, self.mag, self.keys,
                                      self.patterns, self.density, self.size_cdf))

    def lookup(self, low: np.ndarray, high: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Patterns whose codes may lie in the boxes [low, high] (B, 5), and the boxes' shares.

        Returns, for all B boxes at once: the indices of the patterns in every
        bin a box touches (all those inside the box and some near it; the
        caller checks them exactly), the box each belongs to (both ordered by
        box, then by key), and per box the expected number of patterns a box
        of its volume holds by chance where it is: its volume times the
        density of codes in the coarse cell of its centre.
        """
        top = int(math.ceil(1.0 / self.key_bin))
        lo = np.clip(np.floor(low / self.key_bin).astype(np.int64), 0, top)
        hi = np.clip(np.floor(high / self.key_bin).astype(np.int64), 0, top)
        span = hi - lo
        # the first component is the key's least significant digit: one run of
        # keys per combination of bins of the other four
        size = int(span[:, 1:].max(initial=0)) + 1
        grid = np.stack(np.meshgrid(*[np.arange(size)] * 4, indexing="ij"),
                        axis=-1).reshape(-1, 4)
        valid = np.all(grid[None, :, :] <= span[:, None, 1:], axis=2)
        box, cell = np.nonzero(valid)
        digits = np.column_stack((lo[box, 0], lo[box, 1:] + grid[cell]))
        start = code_keys(digits, self.key_bin)
        # queries in the keys' own type, or numpy would convert the whole table
        first = np.searchsorted(self.keys, start.astype(self.keys.dtype), side="left")
        last = np.searchsorted(self.keys, (start + span[box, 0]).astype(self.keys.dtype),
                               side="right")
        counts = last - first
        total = int(counts.sum())
        volume = np.prod(np.clip(high, 0.0, 1.0) - np.clip(low, 0.0, 1.0), axis=1)
        share = self.density[_density_cell(0.5 * (low + high))] * volume * DENSITY_CELLS ** 5
        index = np.repeat(first, counts) + (np.arange(total)
                                            - np.repeat(np.cumsum(counts) - counts, counts))
        return index, np.repeat(box, counts), share
