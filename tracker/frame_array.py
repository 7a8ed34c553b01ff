"""Arrays people hand in -> frames the detector takes: 2-D, uint8 or uint16, with a bit depth.

One rule for every way a frame arrives (a decoded file in replay, an array
given to :func:`tracker.solve`, a frame reaching :class:`tracker.pipeline.
Pipeline`):

* colour (rows x cols x 3 or 4, OpenCV's BGR(A) order, as ``cv2.imread``
  gives) becomes grey with OpenCV's luma weights (0.299 R + 0.587 G +
  0.114 B); a single channel (rows x cols x 1) is taken as grey. An RGB
  array from another library swaps the R and B weights: the stars are found
  all the same;
* uint8 is 8-bit; uint16 holding values below ``2**bits16_depth`` (10 for
  the OV2311) is ``bits16_depth``-bit, otherwise 16-bit;
* other integer types (int32, int64...) must hold values in 0..65535 and
  become uint16 by the same rule; bool becomes uint8 0/1;
* floats in 0..1 are fractions of full scale, rounded to 16-bit uint16;
  larger floats are ADU in 0..65535, rounded to uint16 by the rule above.
  NaN, infinity and negative values are refused.
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.errors import UserError

__all__ = ["FrameArrayError", "to_grey", "bit_depth_of", "as_frame"]


class FrameArrayError(UserError, ValueError):
    """An array that cannot be a frame; the message says why in one line."""


def to_grey(image: np.ndarray) -> np.ndarray:
    """A 2-D view or grey conversion of a 2-D, rows x cols x 1, x 3 (BGR) or x 4 (BGRA) array."""
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    if image.ndim == 3 and image.shape[2] in (3, 4) and image.dtype in (
            np.uint8, np.uint16, np.float32):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(np.ascontiguousarray(image), code)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        weights = np.array([0.114, 0.587, 0.299])
        return image[:, :, :3].astype(np.float64) @ weights
    raise FrameArrayError(f"an array of shape {image.shape}, expected rows x columns, "
                          "optionally x 1, 3 or 4 colour channels")


def bit_depth_of(image: np.ndarray, bits16_depth: int) -> int:
    """8 for uint8; ``bits16_depth`` for uint16 whose values all fit in it, else 16."""
    if image.dtype == np.uint8:
        return 8
    if image.size and int(image.max()) < (1 << bits16_depth):
        return bits16_depth
    return 16


def as_frame(array: object, bits16_depth: int = 10) -> tuple[np.ndarray, int]:
    """(C-contiguous 2-D uint8/uint16 frame, bit depth) from any array; see the module doc."""
    image = np.asarray(array)
    if image.dtype.kind not in "buif":
        raise FrameArrayError(f"an array of {image.dtype}, expected integer or float pixels")
    image = to_grey(image)
    if image.size == 0:
        raise FrameArrayError(f"an array of shape {image.shape} has no pixels")
    if image.dtype.kind == "b":
        image = image.astype(np.uint8)
    elif image.dtype.kind == "f":
        if not np.isfinite(image).all():
            raise FrameArrayError("NaN or infinity among the pixels")
        lo, hi = float(image.min()), float(image.max())
        if lo < 0 or hi > 65535:
            raise FrameArrayError(f"float pixels in [{lo:g}, {hi:g}], expected 0..1 (fractions "
                                  "of full scale) or 0..65535 (ADU)")
        if hi <= 1.0:
            return np.ascontiguousarray(np.rint(image * 65535.0).astype(np.uint16)), 16
        image = np.rint(image).astype(np.uint16)
    elif image.dtype not in (np.uint8, np.uint16):
        lo, hi = int(image.min()), int(image.max())
        if lo < 0 or hi > 65535:
            raise FrameArrayError(f"{image.dtype} pixels in [{lo}, {hi}], expected 0..65535")
        image = image.astype(np.uint16)
    image = np.ascontiguousarray(image)
    return image, bit_depth_of(image, bits16_depth)
