"""Read star-field images from files: PNG, TIFF, JPEG (8 or 16 bit) and .npy.

Nothing is decoded before it is known to be safe and whole:

1. the path must be a regular file (a named pipe, a device or a folder is
   refused without being opened) no larger than a frame of the allowed size
   could be (8 bytes per pixel, 16-bit RGBA, plus 1 MiB of metadata);
2. the size in the header (tracker.capture.image_header) must fit
   ``max_size`` (the configured camera's width and height: a larger frame
   could never be solved with that camera) or, without one,
   :data:`tracker.config.MAX_SENSOR_PIXELS`; a truncated PNG or JPEG is
   refused here;
3. only then is it decoded; a JPEG whose last rows are libjpeg's mid-grey
   fill (its data ran out before the image did) is refused too.

Colour images become grey and the bit depth follows the rule of
:mod:`tracker.frame_array`. Every refusal is an :class:`ImageReadError`
with a one-line reason; nothing half-decoded is returned.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tracker.capture.image_header import HeaderError, image_size, npy_header
from tracker.config import MAX_SENSOR_PIXELS
from tracker.errors import UserError
from tracker.frame_array import FrameArrayError, bit_depth_of, to_grey
from tracker.regular_file import FileRefused, read_regular_file

__all__ = ["ImageReadError", "IMAGE_SUFFIXES", "read_image"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".npy")

_BYTES_PER_PIXEL = 8           # the most a frame file needs: 16-bit RGBA, uncompressed
_METADATA_BYTES = 1 << 20      # EXIF, ICC profiles, thumbnails
_JPEG_FILL = 128               # what libjpeg decodes where the entropy-coded data ran out
_JPEG_FILL_ROWS = 8            # one block row


class ImageReadError(UserError, ValueError):
    """A file that does not hold a usable image; the message says why."""


def _check_size(name: str, width: int, height: int, max_size: tuple[int, int] | None) -> None:
    if width <= 0 or height <= 0:
        raise ImageReadError(f"{name}: the header says {width}x{height} px, an image with no "
                             "pixels")
    if max_size is not None:
        max_w, max_h = max_size
        if width > max_w or height > max_h:
            raise ImageReadError(
                f"{name}: image is {width}x{height} px, larger than the configured camera's "
                f"{max_w}x{max_h} (set camera.width and camera.height for this camera)")
    elif width * height > MAX_SENSOR_PIXELS:
        raise ImageReadError(f"{name}: image is {width}x{height} px, more than the "
                             f"{MAX_SENSOR_PIXELS:,} pixels a frame may have")


def _decode(name: str, suffix: str, data: bytes) -> np.ndarray:
    if suffix == ".npy":
        shape, dtype, fortran, offset = npy_header(data)
        if dtype.kind != "u" or dtype.itemsize not in (1, 2):
            raise ImageReadError(f"{name}: .npy dtype {dtype} is not uint8 or uint16")
        count = int(np.prod(shape))
        if len(data) - offset < count * dtype.itemsize:
            raise ImageReadError(f"{name}: truncated .npy (the header says {shape} {dtype})")
        flat = np.frombuffer(data, dtype, count=count, offset=offset)
        image = flat.reshape(shape, order="F" if fortran else "C")
        return image.astype(image.dtype.newbyteorder("="), copy=False)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise ImageReadError(f"{name}: the decoder refused it "
                             f"({str(exc).strip().splitlines()[-1][:80]})") from None
    if image is None:
        raise ImageReadError(f"{name}: corrupt or undecodable image data")
    if suffix in (".jpg", ".jpeg") and image.shape[0] > 2 * _JPEG_FILL_ROWS \
            and bool(np.all(image[-_JPEG_FILL_ROWS:] == _JPEG_FILL)):
        raise ImageReadError(f"{name}: truncated JPEG (the image data ends early; the last rows "
                             "are the decoder's grey fill)")
    return image


def read_image(path: str | Path, bits16_depth: int = 10,
               max_size: tuple[int, int] | None = None) -> tuple[np.ndarray, int]:
    """Return (grey image, bit depth) for an image file; see the module docstring.

    ``max_size`` is (width, height), the largest frame accepted. The image is
    a C-contiguous 2-D uint8 or uint16 array.
    """
    path = Path(path)
    name = path.name
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ImageReadError(f"{name}: unsupported file type {suffix or '(none)'}; "
                             f"expected one of {', '.join(IMAGE_SUFFIXES)}")
    pixels = max_size[0] * max_size[1] if max_size is not None else MAX_SENSOR_PIXELS
    try:
        data = read_regular_file(path, _BYTES_PER_PIXEL * pixels + _METADATA_BYTES)
    except FileRefused as exc:
        raise ImageReadError(f"{name}: {exc}") from None
    if not data:
        raise ImageReadError(f"{name}: empty file")
    try:
        width, height = image_size(data, suffix)
    except HeaderError as exc:
        raise ImageReadError(f"{name}: {exc}") from None
    _check_size(name, width, height, max_size)
    try:
        image = to_grey(_decode(name, suffix, data))
    except FrameArrayError as exc:
        raise ImageReadError(f"{name}: {exc}") from None
    if image.dtype not in (np.uint8, np.uint16):
        raise ImageReadError(f"{name}: pixel type {image.dtype} is not 8 or 16 bit")
    if image.shape != (height, width):
        raise ImageReadError(f"{name}: decoded {image.shape[1]}x{image.shape[0]} px, the "
                             f"header says {width}x{height}")
    return np.ascontiguousarray(image), bit_depth_of(image, bits16_depth)
