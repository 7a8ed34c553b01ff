"""Image sizes read from file headers, and the container checks, before any decoding.

A decoder allocates what the header says: a 69-byte PNG can claim
60000 x 60000 pixels, a 129-byte ``.npy`` 100000 x 100000 uint16, and a
389 KB PNG of 20000 x 20000 really decodes to 400 MB. So the size is read
here from the header, by the format's specification, and checked against the
caller's limit before a decoder sees the bytes:

* PNG (ISO/IEC 15948): the signature, then IHDR (first chunk, 13 bytes:
  width, height, bit depth, colour type); the file must end with IEND.
* JPEG (ITU-T T.81): markers from SOI; the frame header SOFn (C0-CF except
  C4 DHT, C8 JPG, CC DAC) holds precision, height, width, components. Each
  scan's entropy-coded data runs to the next marker (FF followed by neither
  00, a stuffed byte, nor D0-D7, a restart); after the last scan must come
  EOI. A file cut short has no EOI there and is refused.
* TIFF (TIFF 6.0): byte order, 42, the first IFD's ImageWidth (256) and
  ImageLength (257), SHORT or LONG.
* NPY (numpy's format 1.0-3.0): magic, version, header length, then the
  header dict read with numpy's own parser (a literal, never executed):
  dtype, order and shape.

:func:`image_size` returns (width, height) or raises :class:`HeaderError`
with a one-line reason (without the file name; the caller adds it).
"""

from __future__ import annotations

import io
import re
import struct

import numpy as np

__all__ = ["HeaderError", "image_size", "npy_header"]

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_TIFF_WIDTH, _TIFF_HEIGHT = 256, 257
_SOF = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# the next marker inside entropy-coded data: FF, then not 00 (stuffing), not
# D0-D7 (restart) and not FF (fill before a marker)
_NEXT_MARKER = re.compile(rb"\xff[\x01-\xcf\xd8-\xfe]")


class HeaderError(ValueError):
    """A header that is missing, cut short or inconsistent; the message says why."""


def _png_size(data: bytes) -> tuple[int, int]:
    if not data.startswith(_PNG_MAGIC):
        raise HeaderError("not a PNG file (bad signature)")
    if not data.rstrip(b"\x00").endswith(_PNG_END):
        raise HeaderError("truncated PNG (no IEND chunk)")
    if len(data) < 33 or data[12:16] != b"IHDR" or struct.unpack(">I", data[8:12])[0] != 13:
        raise HeaderError("corrupt PNG (no IHDR chunk first)")
    return struct.unpack(">II", data[16:24])


def _jpeg_size(data: bytes) -> tuple[int, int]:
    """The SOF's size, after walking every segment and scan to EOI (T.81 B.1)."""
    if not data.startswith(b"\xff\xd8"):
        raise HeaderError("not a JPEG file (bad signature)")
    size = None
    pos = 2
    while True:
        while pos < len(data) and data[pos] == 0xFF and pos + 1 < len(data) \
                and data[pos + 1] == 0xFF:
            pos += 1                                  # fill bytes before a marker
        if pos + 2 > len(data):
            raise HeaderError("truncated JPEG (no end-of-image marker)")
        if data[pos] != 0xFF:
            raise HeaderError(f"corrupt JPEG (no marker at byte {pos})")
        marker = data[pos + 1]
        pos += 2
        if marker == 0xD9:                            # EOI
            break
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # no length field
            continue
        if pos + 2 > len(data):
            raise HeaderError("truncated JPEG (segment header cut)")
        length = struct.unpack(">H", data[pos:pos + 2])[0]
        if length < 2 or pos + length > len(data):
            raise HeaderError("truncated JPEG (segment longer than the file)")
        if marker in _SOF:
            if length < 8:
                raise HeaderError("corrupt JPEG (short frame header)")
            height, width = struct.unpack(">HH", data[pos + 3:pos + 7])
            size = (width, height)
        pos += length
        if marker == 0xDA:                            # SOS: entropy-coded data follows
            if size is None:
                raise HeaderError("corrupt JPEG (scan before the frame header)")
            found = _NEXT_MARKER.search(data, pos)
            if found is None:
                raise HeaderError("truncated JPEG (no end-of-image marker)")
            pos = found.start()
    if size is None:
        raise HeaderError("corrupt JPEG (no frame header)")
    if size[1] == 0:
        raise HeaderError("unsupported JPEG (height given after the scan, DNL)")
    return size


def _tiff_size(data: bytes) -> tuple[int, int]:
    order = {b"II*\x00": "<", b"MM\x00*": ">"}.get(data[:4])
    if order is None:
        if data[:4] in (b"II+\x00", b"MM\x00+"):
            raise HeaderError("BigTIFF is not supported")
        raise HeaderError("not a TIFF file (bad signature)")
    try:
        (ifd,) = struct.unpack(order + "I", data[4:8])
        (count,) = struct.unpack(order + "H", data[ifd:ifd + 2])
        found = {}
        for k in range(count):
            entry = data[ifd + 2 + 12 * k: ifd + 14 + 12 * k]
            tag, kind, n = struct.unpack(order + "HHI", entry[:8])
            if tag in (_TIFF_WIDTH, _TIFF_HEIGHT) and n == 1 and kind in (3, 4):
                fmt = order + ("H" if kind == 3 else "I")
                found[tag] = struct.unpack(fmt, entry[8:8 + struct.calcsize(fmt)])[0]
    except struct.error:
        raise HeaderError("truncated TIFF (first image directory cut)") from None
    if _TIFF_WIDTH not in found or _TIFF_HEIGHT not in found:
        raise HeaderError("corrupt TIFF (no image width and length)")
    return found[_TIFF_WIDTH], found[_TIFF_HEIGHT]


def npy_header(data: bytes) -> tuple[tuple[int, ...], np.dtype, bool, int]:
    """(shape, dtype, fortran_order, offset of the data) of a ``.npy`` file's bytes."""
    stream = io.BytesIO(data)
    try:
        major, _minor = np.lib.format.read_magic(stream)
        readers = {1: np.lib.format.read_array_header_1_0,
                   2: np.lib.format.read_array_header_2_0}
        if major not in readers:
            raise HeaderError(f"unreadable .npy header (format version {major}, expected 1 or 2)")
        shape, fortran, dtype = readers[major](stream)
    except HeaderError:
        raise
    except Exception as exc:    # numpy's parser of an untrusted header raises many kinds
        # (ValueError, SyntaxError, tokenize.TokenError, EOFError ...): all mean unreadable
        text = " ".join(str(exc).split())
        raise HeaderError(f"unreadable .npy header ({text[:80]})") from None
    return tuple(int(n) for n in shape), dtype, bool(fortran), stream.tell()


def image_size(data: bytes, suffix: str) -> tuple[int, int]:
    """(width, height) in pixels from the header of a file with this suffix."""
    suffix = suffix.lower()
    if suffix == ".png":
        return _png_size(data)
    if suffix in (".jpg", ".jpeg"):
        return _jpeg_size(data)
    if suffix in (".tif", ".tiff"):
        return _tiff_size(data)
    if suffix == ".npy":
        shape = npy_header(data)[0]
        if len(shape) not in (2, 3):
            raise HeaderError(f".npy array of shape {shape}, expected rows x columns")
        return shape[1], shape[0]
    raise HeaderError(f"unsupported file type {suffix or '(none)'}")
