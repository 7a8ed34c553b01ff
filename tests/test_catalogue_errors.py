"""A missing, corrupt, truncated or malformed catalogue gives a one-line CatalogueError."""

from __future__ import annotations

import hashlib
import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from tracker.catalogue import CatalogueError, default_catalogue_path, load_catalogue


def write_checksum(path: Path) -> None:
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    Path(f"{path}.sha256").write_text(f"{digest}  {path.name}\n", encoding="ascii")


@pytest.fixture(name="copy")
def fixture_copy(tmp_path: Path) -> Path:
    """A copy of the bundled catalogue and its checksum file in tmp_path."""
    src = default_catalogue_path()
    dst = tmp_path / "stars.npz"
    shutil.copyfile(src, dst)
    shutil.copyfile(f"{src}.sha256", f"{dst}.sha256")
    return dst


def bundled_arrays() -> dict[str, np.ndarray]:
    with np.load(default_catalogue_path()) as npz:
        return {name: npz[name] for name in npz.files}


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, **arrays)
    write_checksum(path)
    return path


def load_error(path: Path) -> str:
    with pytest.raises(CatalogueError) as info:
        load_catalogue(path, epoch_year=2000.0)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    return message


def test_the_copy_loads(copy):
    assert len(load_catalogue(copy, epoch_year=2000.0)) == 78352


def test_missing_file(tmp_path):
    path = tmp_path / "nothing.npz"
    assert load_error(path) == f"{path}: catalogue file not found"


def test_missing_checksum_file(copy):
    Path(f"{copy}.sha256").unlink()
    assert load_error(copy) == f"{copy}.sha256: checksum file not found"


def test_empty_checksum_file(copy):
    Path(f"{copy}.sha256").write_text("", encoding="ascii")
    assert load_error(copy) == f"{copy}.sha256: not a sha256sum line"


def test_one_flipped_byte_fails_the_checksum(copy):
    data = bytearray(copy.read_bytes())
    expected = hashlib.sha256(data).hexdigest()
    data[len(data) // 2] ^= 0x01
    found = hashlib.sha256(data).hexdigest()
    copy.write_bytes(bytes(data))
    assert load_error(copy) == (f"{copy}: SHA-256 mismatch, the file is corrupt or changed "
                                f"(expected {expected[:12]}..., found {found[:12]}...)")


def test_truncated_file_fails_the_checksum(copy):
    copy.write_bytes(copy.read_bytes()[:100_000])
    assert load_error(copy).startswith(f"{copy}: SHA-256 mismatch, the file is corrupt")


def test_truncated_file_with_its_own_checksum_is_not_an_npz(copy):
    copy.write_bytes(copy.read_bytes()[:100_000])
    write_checksum(copy)
    assert load_error(copy).startswith(f"{copy}: not a readable .npz file (")


def test_missing_array(tmp_path):
    arrays = bundled_arrays()
    del arrays["hp_mag"]
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'hp_mag' is missing"


def test_wrong_dtype(tmp_path):
    arrays = bundled_arrays()
    arrays["ra_rad"] = arrays["ra_rad"].astype(np.float32)
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'ra_rad' has dtype float32, expected float64"


def test_wrong_length(tmp_path):
    arrays = bundled_arrays()
    arrays["dec_rad"] = arrays["dec_rad"][:-1]
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'dec_rad' has shape (78351,), expected (78352,)"


def test_two_dimensional_hip(tmp_path):
    arrays = bundled_arrays()
    arrays["hip"] = arrays["hip"].reshape(-1, 2)
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'hip' has shape (39176, 2), expected (39176,)"


def test_scalar_that_is_not_a_scalar(tmp_path):
    arrays = bundled_arrays()
    arrays["epoch_year"] = np.array([1991.25, 2000.0])
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'epoch_year' has shape (2,), expected ()"


def test_nan_position(tmp_path):
    arrays = bundled_arrays()
    arrays["dec_rad"][5] = np.nan
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: array 'dec_rad' holds NaN or infinity"


def test_wrong_format_version(tmp_path):
    arrays = bundled_arrays()
    arrays["format_version"] = np.asarray(2, dtype=np.int32)
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: format version 2, expected 1"


def test_unsorted_magnitudes(tmp_path):
    arrays = bundled_arrays()
    arrays["hp_mag"] = arrays["hp_mag"][::-1].copy()
    path = save_npz(tmp_path / "c.npz", arrays)
    assert load_error(path) == f"{path}: stars are not sorted by magnitude"


def test_pickled_object_array_is_refused(tmp_path):
    """An object array would need pickle; the loader never unpickles."""
    arrays = bundled_arrays()
    arrays["hip"] = np.array([object()] * 3)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path = tmp_path / "c.npz"
    path.write_bytes(buf.getvalue())
    write_checksum(path)
    assert load_error(path).startswith(f"{path}: not a readable .npz file (")
