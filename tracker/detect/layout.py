"""Padded frame buffers, sparse pixel lists and a frame's square windows as one view.

Every full-size buffer of a detector has the same layout: the frame's
(rows, cols) pixels sit inside a zero border of ``pad`` pixels, and rows are
``stride`` elements long, a multiple of 8 so that a uint8 mask can be
scanned eight pixels at a time as uint64 words. A pixel is addressed by its
flat index into such a buffer, the same number in every buffer, so that
windows around stars near the edge need no bounds checks.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PaddedLayout", "window_view"]


def window_view(image: np.ndarray, size: int) -> np.ndarray:
    """Every ``size`` x ``size`` window of ``image`` as one read-only view (rows - size + 1,
    cols - size + 1, size, size), indexed by the window's top-left pixel (no copy): indexing
    it with arrays of top-left rows and columns copies those windows in one gather."""
    image = np.ascontiguousarray(image)
    step = image.strides
    return np.ndarray((image.shape[0] - size + 1, image.shape[1] - size + 1, size, size),
                      image.dtype, image, 0, step + step)


class PaddedLayout:
    """Geometry of padded buffers for frames of ``shape`` (rows, cols)."""

    def __init__(self, shape: tuple[int, int], pad: int) -> None:
        self.rows, self.cols = int(shape[0]), int(shape[1])
        self.pad = int(pad)
        self.stride = -(-(self.cols + 2 * self.pad) // 8) * 8
        self.full_shape = (self.rows + 2 * self.pad, self.stride)
        self.word_hits = np.zeros(self.full_shape[0] * self.stride // 8, np.bool_)

    def buffer(self, dtype: type) -> tuple[np.ndarray, np.ndarray]:
        """A zeroed padded array and its (rows, cols) interior view."""
        full = np.zeros(self.full_shape, dtype)
        p = self.pad
        return full, full[p:p + self.rows, p:p + self.cols]

    def flat_index(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Flat indices of frame pixels (row, col) in a padded buffer."""
        return (np.asarray(row) + self.pad) * self.stride + np.asarray(col) + self.pad

    def frame_position(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) in the frame of padded flat indices."""
        rows, cols = np.divmod(flat, self.stride)
        return rows - self.pad, cols - self.pad

    def word_marks(self) -> np.ndarray:
        """A bool buffer of one mark per eight bytes of a padded uint8 mask (zeroed), for
        :meth:`mark_words` and :meth:`nonzero`."""
        return np.zeros_like(self.word_hits)

    def mark_words(self, mask_full: np.ndarray, first: int, end: int,
                   marks: np.ndarray) -> None:
        """Mark in ``marks`` (:meth:`word_marks`) the words of padded rows [first, end) of
        the uint8 mask ``mask_full`` holding a nonzero byte: a caller that writes the
        mask a few rows at a time marks them while they are still in cache."""
        rows = mask_full[first:end].reshape(-1)
        words = slice(first * self.stride // 8, end * self.stride // 8)
        np.not_equal(rows.view(np.uint64), 0, out=marks[words])

    def nonzero(self, mask_full: np.ndarray, out: np.ndarray,
                marks: np.ndarray | None = None) -> int:
        """Flat indices of the nonzero bytes of a padded uint8 mask into ``out``.

        Returns how many there are; when that exceeds ``len(out)`` nothing is
        written. The scan reads eight pixels per step (marking the nonzero
        words in a bool buffer first, where numpy's nonzero skips runs of
        zeros quickly); its temporaries are proportional to the number of
        nonzero pixels, not to the frame. ``marks``: those words' marks, made
        already (:meth:`mark_words`, every row that may hold a nonzero byte).
        """
        flat = mask_full.ravel()
        if marks is None:
            marks = self.word_hits
            np.not_equal(flat.view(np.uint64), 0, out=marks)
        words = np.flatnonzero(marks)
        if len(words) == 0:
            return 0
        octets = flat.reshape(-1, 8)[words]
        hits = np.flatnonzero(octets)
        n = len(hits)
        if n <= len(out):
            np.multiply(words[hits >> 3], 8, out=out[:n])
            np.add(out[:n], hits & 7, out=out[:n])
        return n
