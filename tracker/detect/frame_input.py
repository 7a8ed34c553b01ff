"""Checking a frame and copying it into a detector's working buffer.

Every detection method starts here, so bad input is handled in one place and
the same way: :meth:`FrameInput.load` never raises; it returns a reason code
(see :class:`~tracker.detect.result.Detections`) or None, and on None the
frame's pixels are in ``FrameInput.work`` as float32 ADU.

Accepted frames are 2-D arrays of the detector's shape, of an unsigned or
signed integer or a floating dtype (floats are taken as ADU, the same scale as
the integer frames). Non-contiguous and read-only arrays are fine: the frame
is only read, and the copy into ``work`` takes any strides. The copy
allocates nothing.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout

__all__ = ["FrameInput", "Reason"]


class Reason:
    """Reason codes for frames that give no or flagged results."""

    BAD_DTYPE = "bad_dtype"          # not a real-valued numeric array
    WRONG_SHAPE = "wrong_shape"      # not 2-D, or not the detector's shape
    TOO_SMALL = "too_small"          # fewer rows or columns than a star needs
    NON_FINITE = "non_finite"        # NaN or infinity in a float frame
    EMPTY = "empty"                  # every pixel <= 0
    FLAT = "flat"                    # every pixel the same value
    SATURATED = "saturated"          # every pixel at full scale
    TOO_MANY = "too_many"            # more candidates than max_stars; brightest kept
    CROWDED = "crowded"              # too many pixels above threshold; threshold raised


_KINDS = ("u", "i", "f")


class FrameInput:
    """Validates frames of one shape and holds their copy.

    ``shape`` is (rows, cols); ``bit_depth`` sets full scale,
    ``2**bit_depth - 1`` ADU. ``min_size`` is the smallest number of rows and
    columns a frame must have to be searched at all (smaller detectors return
    ``too_small`` for every frame). With a ``layout``, ``work`` is the
    interior view of the padded buffer ``padded``; without, both are one
    contiguous array.

    ``work`` is of ``dtype``: float32 ADU, or uint16 ADU (half the memory
    traffic of float32, and faster OpenCV filters). A uint16 ``work`` holds
    other frames clipped to 0..full scale (values outside it cannot come
    from the sensor) and rounded to whole ADU.
    """

    def __init__(self, shape: tuple[int, int], bit_depth: int, min_size: int = 3,
                 layout: PaddedLayout | None = None, dtype: type = np.float32) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.full_scale = float(2 ** int(bit_depth) - 1)
        self.min_size = int(min_size)
        self.integer = np.dtype(dtype) == np.uint16
        self.top = np.uint16(min(self.full_scale, 65535.0))   # full scale as a uint16
        if layout is None:
            self.padded = self.work = np.zeros(self.shape, dtype)
        else:
            self.padded, self.work = layout.buffer(dtype)
        # float copy of float frames (and, for a uint16 work, of any unusual frame)
        self.staging = np.zeros(self.shape, np.float32) if self.integer else self.work

    def load(self, image: object,
             rows: Callable[[Callable[[int, int], object]], None] | None = None) -> str | None:
        """Copy ``image`` into ``work``; a reason code if it cannot be searched.

        ``rows``: runs a function of a row range [first, end) over the frame's rows
        (e.g. tracker.detect.slabs.SlabRunner.rows, in parallel threads); a uint8 or
        uint16 frame is copied through it (the copy is memory-bound, and two cores
        move it in little more than half the time of one).
        """
        if not isinstance(image, np.ndarray) or image.dtype.kind not in _KINDS:
            return Reason.BAD_DTYPE
        if image.ndim != 2 or image.shape != self.shape:
            return Reason.WRONG_SHAPE
        if min(self.shape) < self.min_size:
            return Reason.TOO_SMALL
        if self.integer and image.dtype in (np.uint8, np.uint16):
            return self._load_unsigned(image, rows)
        if image.dtype.kind == "f":
            np.copyto(self.staging, image, casting="unsafe")
            if not cv2.checkRange(self.staging)[0]:
                return Reason.NON_FINITE
            src = self.staging
        else:
            src = image
        # numpy's SIMD reductions, on the narrow integer frame where there is one, take a
        # sixth of cv2.minMaxLoc's time on the float copy
        hi = float(src.max())
        if hi <= 0.0:
            return Reason.EMPTY
        # the lowest value only tells a saturated or flat frame: with every pixel at or
        # under full scale, a first row holding a value under the highest says neither
        # (no pass over the whole frame for it)
        if hi > self.full_scale or float(src[0].min()) == hi:
            lo = float(src.min())
            if lo >= self.full_scale:
                return Reason.SATURATED
            if hi == lo:
                return Reason.FLAT
        if not self.integer:
            if src is not self.work:
                np.copyto(self.work, image, casting="unsafe")
        else:
            self._round(image, src)
        return None

    def _load_unsigned(self, image: np.ndarray,
                       rows: Callable[[Callable[[int, int], object]], None] | None) -> str | None:
        """A uint8 or uint16 frame into the uint16 ``work``, clipped at full scale in the
        same pass as the copy (whole numbers already: the rounding of :meth:`_round`
        changes none; OpenCV's min takes a plain copy's time, numpy's a third more, a max
        pass then a copy two thirds more). The reasons come from the first row where it
        tells them (a positive value and two different ones: neither empty, flat nor
        saturated), else from the copy: clipping changes none of them (a frame flat only
        once clipped reads full scale everywhere, so saturated)."""
        work = self.work
        if rows is None:
            self._copy_unsigned(image, 0, self.shape[0])
        else:
            rows(lambda a, b: self._copy_unsigned(image, a, b))
        first = work[0]
        if first.max() > 0 and first.min() < first.max():
            return None
        hi = float(work.max())
        if hi <= 0.0:
            return Reason.EMPTY
        lo = float(work.min())
        if lo >= self.full_scale:
            return Reason.SATURATED
        if hi == lo:
            return Reason.FLAT
        return None

    def _copy_unsigned(self, image: np.ndarray, a: int, b: int) -> None:
        """Rows [a, b) of a uint8 or uint16 ``image`` into ``work``, clipped at full scale."""
        work, image = self.work[a:b], image[a:b]
        if image.dtype == np.uint8 and self.full_scale >= 255.0:
            np.copyto(work, image)                      # nothing lies above full scale
        elif image.dtype == np.uint16 and image.strides[1] == image.itemsize:
            cv2.min(image, self.full_scale, dst=work)   # in a plain copy's time
        else:
            np.minimum(image, self.top, out=work)       # other strides: numpy's (slower)

    def _round(self, image: np.ndarray, src: np.ndarray) -> None:
        """Clip and round any other frame into the uint16 ``work`` via ``staging``."""
        stage = self.staging
        if src is not stage:
            np.copyto(stage, image, casting="unsafe")
        np.clip(stage, 0.0, self.full_scale, out=stage)
        np.rint(stage, out=stage)
        np.copyto(self.work, stage, casting="unsafe")
