"""Read star-field images from files: PNG, TIFF, JPEG (8 or 16 bit) and .npy.

Colour images are converted to grey (OpenCV's luma weights). A 16-bit image
whose values all fit in ``bits16_depth`` bits (10 for the OV2311) is reported
with that bit depth, otherwise 16. Truncated or corrupt files raise
:class:`ImageReadError` with a one-line reason; nothing half-decoded is
returned.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["ImageReadError", "IMAGE_SUFFIXES", "read_image"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".npy")

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_JPEG_MAGIC = b"\xff\xd8"
_JPEG_END = b"\xff\xd9"
_TIFF_MAGICS = (b"II*\x00", b"MM\x00*")


class ImageReadError(ValueError):
    """A file that does not hold a usable image; the message says why."""


def _check_complete(path: Path, data: bytes) -> None:
    """Refuse files whose container says they were cut short."""
    suffix = path.suffix.lower()
    if not data:
        raise ImageReadError(f"{path.name}: empty file")
    if suffix == ".png":
        if not data.startswith(_PNG_MAGIC):
            raise ImageReadError(f"{path.name}: not a PNG file (bad signature)")
        if not data.rstrip(b"\x00").endswith(_PNG_END):
            raise ImageReadError(f"{path.name}: truncated PNG (no IEND chunk)")
    elif suffix in (".jpg", ".jpeg"):
        if not data.startswith(_JPEG_MAGIC):
            raise ImageReadError(f"{path.name}: not a JPEG file (bad signature)")
        if _JPEG_END not in data[-64:]:
            raise ImageReadError(f"{path.name}: truncated JPEG (no end-of-image marker)")
    elif suffix in (".tif", ".tiff") and data[:4] not in _TIFF_MAGICS:
        raise ImageReadError(f"{path.name}: not a TIFF file (bad signature)")


def _to_grey(image: np.ndarray, name: str) -> np.ndarray:
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(image, code)
    raise ImageReadError(f"{name}: unsupported image shape {image.shape}")


def _from_npy(path: Path) -> np.ndarray:
    try:
        image = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ImageReadError(f"{path.name}: unreadable .npy ({exc})") from None
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"{path.name}: .npy dtype {image.dtype} is not uint8 or uint16")
    return image


def read_image(path: str | Path, bits16_depth: int = 10) -> tuple[np.ndarray, int]:
    """Return (grey image, bit depth) for an image file.

    The image is a C-contiguous 2-D uint8 or uint16 array.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ImageReadError(f"{path.name}: unsupported file type {suffix or '(none)'}; "
                             f"expected one of {', '.join(IMAGE_SUFFIXES)}")
    if suffix == ".npy":
        image = _from_npy(path)
    else:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise ImageReadError(f"{path.name}: cannot read ({exc.strerror or exc})") from None
        _check_complete(path, data)
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ImageReadError(f"{path.name}: corrupt or undecodable image data")
    image = _to_grey(image, path.name)
    if image.dtype == np.uint8:
        depth = 8
    elif image.dtype == np.uint16:
        depth = bits16_depth if image.size and int(image.max()) < (1 << bits16_depth) else 16
    else:
        raise ImageReadError(f"{path.name}: pixel type {image.dtype} is not 8 or 16 bit")
    if image.size == 0:
        raise ImageReadError(f"{path.name}: image has no pixels")
    return np.ascontiguousarray(image), depth
