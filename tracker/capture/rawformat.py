"""Raw mono pixel formats from the camera, and their conversion into frames.

Pure numpy, no hardware: the live backends (picamera2, V4L2) hand a mapped
camera buffer of shape (rows, stride) uint8 to :class:`RawConverter`, which
writes the pixels into a ring of preallocated 2-D frames without allocating
(a frame stays valid while the ring's other frames are written, so capture
can run ahead of processing: tracker.daemon.capture_ahead).

Formats (libcamera / picamera2 names):

- ``R8``: 8 bits per pixel, one byte each.
- ``R10``, ``R12``, ``R16``: unpacked, one little-endian 16-bit word per pixel.
  ``R16`` is what a Pi 5 grants for mono sensors; whether 10-bit data sits in
  the low or high bits of the word is not settled for the OV2311 (see
  docs/pi5.md), so the right shift is a setting (``capture.raw_shift``) and
  ``tracker selftest`` reports which bits vary.
- ``R10_CSI2P``: MIPI CSI-2 packed 10-bit, 4 pixels in 5 bytes: bytes 0..3
  hold bits 9..2 of pixels 0..3, byte 4 their two low bits (pixel 0 in bits
  1:0 ... pixel 3 in bits 7:6). Pi 4 and the V4L2 ``Y10P`` format.
- ``R8_CSI2P``: same as ``R8``.
- ``*_PISP_COMP*``: the Pi 5 back end's lossy compressed raw; refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RawFormat", "RawFormatError", "RawConverter", "parse_format", "unpack_raw10"]


class RawFormatError(ValueError):
    """A raw format the tracker cannot use; the message says which and why."""


@dataclass(frozen=True)
class RawFormat:
    """What a format name means: bits per pixel, bytes per pixel in memory."""

    name: str
    bit_depth: int
    packed: bool

    def row_bytes(self, width: int) -> int:
        """Bytes of pixel data in one row (the stride may be larger)."""
        if self.packed and self.bit_depth == 10:
            return width * 5 // 4
        return width if self.bit_depth == 8 else 2 * width


_FORMATS = {
    "R8": RawFormat("R8", 8, False),
    "R8_CSI2P": RawFormat("R8_CSI2P", 8, False),
    "R10": RawFormat("R10", 10, False),
    "R12": RawFormat("R12", 12, False),
    "R16": RawFormat("R16", 16, False),
    "R10_CSI2P": RawFormat("R10_CSI2P", 10, True),
}


def parse_format(name: str) -> RawFormat:
    """The :class:`RawFormat` for a granted format name, or RawFormatError."""
    if "PISP_COMP" in name:
        raise RawFormatError(f"camera granted {name}, a lossy compressed raw format; ask for "
                             "an unpacked one (capture.raw_format: R16)")
    try:
        return _FORMATS[name]
    except KeyError:
        known = ", ".join(_FORMATS)
        raise RawFormatError(f"camera granted raw format {name!r}, expected a mono format "
                             f"({known})") from None


def unpack_raw10(packed: np.ndarray, out: np.ndarray, tmp: np.ndarray) -> np.ndarray:
    """Unpack CSI-2 packed 10-bit rows into ``out`` without allocating.

    ``packed``: (rows, stride) uint8 with stride >= width*5/4; ``out``:
    (rows, width) uint16, width a multiple of 4; ``tmp``: (rows, width/4)
    uint16 scratch. Returns ``out``.
    """
    rows, width = out.shape
    groups = packed[:, : width * 5 // 4].reshape(rows, width // 4, 5)
    quads = out.reshape(rows, width // 4, 4)
    np.left_shift(groups[..., :4], 2, out=quads, dtype=np.uint16, casting="unsafe")
    for k in range(4):
        np.right_shift(groups[..., 4], 2 * k, out=tmp, dtype=np.uint16, casting="unsafe")
        np.bitwise_and(tmp, 3, out=tmp)
        np.bitwise_or(quads[..., k], tmp, out=quads[..., k])
    return out


class RawConverter:
    """Copies camera buffers of a given format into a ring of preallocated frames.

    ``shape`` is (rows, width). ``shift`` right-shifts 16-bit words (e.g. 6
    for 10-bit data stored in the high bits of ``R16``). ``bit_depth`` is the
    depth of the values written, which travels with the frame. Each
    successful :meth:`convert` writes the next of ``buffers`` frames in turn,
    so a frame is overwritten by the conversion ``buffers`` later.
    """

    def __init__(self, fmt: RawFormat, shape: tuple[int, int], shift: int = 0,
                 buffers: int = 1):
        rows, width = shape
        if fmt.packed and width % 4:
            raise RawFormatError(f"packed 10-bit rows need a width divisible by 4, got {width}")
        self.fmt = fmt
        self.shape = (rows, width)
        self.shift = shift if fmt.bit_depth > 8 else 0
        if fmt.bit_depth == 8:
            self.bit_depth = 8
        elif fmt.name == "R16":
            self.bit_depth = 16 - self.shift
        else:
            self.bit_depth = fmt.bit_depth
        dtype = np.uint8 if fmt.bit_depth == 8 else np.uint16
        self.frames = [np.zeros(self.shape, dtype) for _ in range(max(1, int(buffers)))]
        self._next = 0
        self._tmp = np.zeros((rows, width // 4), np.uint16) if fmt.packed else None

    @property
    def frame(self) -> np.ndarray:
        """The frame the next :meth:`convert` writes."""
        return self.frames[self._next]

    def convert(self, buf: np.ndarray) -> np.ndarray:
        """Write ``buf`` ((rows, stride) uint8, or an already typed 2-D array) into a frame.

        Raises RawFormatError if the buffer is too small for the frame (the
        ring does not move on). Returns the frame written, the next of the
        ring's arrays.
        """
        rows, width = self.shape
        if buf.dtype != np.uint8:   # e.g. OpenCV's 16UC1 Mat: already one word per pixel
            if buf.shape[:2] != self.shape:
                raise RawFormatError(f"buffer is {buf.shape[1]}x{buf.shape[0]}, "
                                     f"expected {width}x{rows}")
            return self._advance(self._store(buf))
        need = self.fmt.row_bytes(width)
        if buf.ndim != 2 or buf.shape[0] < rows or buf.shape[1] < need:
            raise RawFormatError(f"buffer of shape {buf.shape} is too small for {width}x{rows} "
                                 f"{self.fmt.name} ({need} bytes per row)")
        if self.fmt.packed:
            return self._advance(unpack_raw10(buf[:rows], self.frame, self._tmp))
        if self.fmt.bit_depth == 8:
            np.copyto(self.frame, buf[:rows, :width])
            return self._advance(self.frame)
        words = buf[:rows, : 2 * width].view("<u2")
        return self._advance(self._store(words))

    def _advance(self, written: np.ndarray) -> np.ndarray:
        self._next = (self._next + 1) % len(self.frames)
        return written

    def _store(self, words: np.ndarray) -> np.ndarray:
        if self.shift:
            np.right_shift(words, self.shift, out=self.frame, casting="unsafe")
        else:
            np.copyto(self.frame, words, casting="unsafe")
        return self.frame
