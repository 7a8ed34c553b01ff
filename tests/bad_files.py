"""Test helper: image files that lie about their size, made in a few bytes of memory."""

from __future__ import annotations

import struct
import zlib


def _chunk(kind: bytes, body: bytes) -> bytes:
    return (struct.pack(">I", len(body)) + kind + body
            + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))


def png_claiming(width: int, height: int) -> bytes:
    """A tiny PNG (about 65 bytes) whose IHDR claims width x height 8-bit grey pixels."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(b""))
            + _chunk(b"IEND", b""))


def black_png(width: int, height: int) -> bytes:
    """A valid black 8-bit grey PNG, compressed row by row: 20000 x 20000 is ~400 KB."""
    packer = zlib.compressobj(1, zlib.DEFLATED, 15, 9, zlib.Z_RLE)
    rows = 256
    block = bytes(width + 1) * rows             # each row: filter type 0, then the pixels
    parts = [packer.compress(block) for _ in range(height // rows)]
    parts.append(packer.compress(bytes(width + 1) * (height % rows)))
    data = b"".join(parts) + packer.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", data)
            + _chunk(b"IEND", b""))


def npy_claiming(shape: tuple[int, ...], descr: str = "<u2") -> bytes:
    """A .npy header (129 bytes for 2-D shapes) with no data after it."""
    header = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}".encode()
    header = header.ljust(118, b" ") + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header
