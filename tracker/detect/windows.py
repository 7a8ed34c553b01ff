"""Detection in square windows of a frame: every window at once, through a full-frame detector.

Tracking knows where its stars will be and looks only there
(tracker.identify.windows plans the windows). :class:`WindowDetector` copies
the ``cells`` windows of one frame, ``cell`` px square, side by side into a
mosaic (``columns`` windows a row, ordered by their place in the frame so
that mosaic neighbours are frame neighbours) and runs one detector on the
mosaic: the full-frame detector's stages, unchanged, give every window the
same guarantees as the whole frame (local background and noise from its own
tiles, impulse rejection, the matched filter's threshold, deblending,
centroids, flags). The detector is whatever ``make(shape)`` returns for the
mosaic's shape (tracker.detect.make_detector): that function is the whole
interface, so another detector takes over by being made there.

Stars are returned in frame pixels (tracker.detect.result's convention),
with the PSF the mosaic's detector used.
The filter and the background see the neighbouring window across a
window's inner borders, so a star centred within ``margin`` px of an
inner border is dropped (the planner sizes windows so that a predicted
star lies farther in); at a border that is the frame's own it is kept and
flagged EDGE as the full frame would flag it. Windows may overlap: a star
seen in two of them is reported once (the first, brighter, detection).

Fixed memory: the mosaic and the star table are made at construction.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tracker.detect.result import Detections, StarFlag
from tracker.detect.stars import StarTable
from tracker.detect.windowed import later_within

__all__ = ["WindowDetector"]

_SAME_STAR_PX = 1.0   # detections of one star in two overlapping windows lie closer


class WindowDetector:
    """Finds stars in ``cells`` windows of ``cell`` px of frames of ``frame_shape``.

    ``make(shape)`` returns the detector (``detect(image) -> Detections``)
    for the mosaic; ``dtype`` is the frames' (uint8 or uint16); ``margin``
    the PSF's reach, px; ``max_stars`` the rows of the star table.
    """

    def __init__(self, make: Callable[[tuple[int, int]], object], frame_shape: tuple[int, int],
                 cell: int, cells: int, margin: int, max_stars: int, dtype: type,
                 columns: int = 8) -> None:
        self.cell = int(cell)
        self.cells = int(cells)
        self.columns = min(int(columns), self.cells)
        shape = self.mosaic_shape(cell, cells, columns)
        self.frame_shape = (int(frame_shape[0]), int(frame_shape[1]))
        if self.cell > min(self.frame_shape):
            raise ValueError(f"window of {cell} px larger than the frame {frame_shape}")
        rows = shape[0] // self.cell
        self.mosaic = np.zeros(shape, dtype)
        self.detector = make(self.mosaic.shape)
        self.margin = int(margin)
        self.table = StarTable(max_stars)
        # flat frame index of every mosaic pixel = its window's corner + these offsets
        dy, dx = np.mgrid[0:self.cell, 0:self.cell]
        self.offsets = (dy[None, :, None, :] * self.frame_shape[1]
                        + dx[None, :, None, :]).astype(np.intp)   # (1, cell, 1, cell)
        self.corner = np.zeros((rows, 1, self.columns, 1), np.intp)
        self.index = np.zeros((rows, self.cell, self.columns, self.cell), np.intp)
        # frame (x0, y0) of each slot; slots beyond ``cells`` repeat the first windows
        # (a blank slot would lower its neighbours' background noise)
        self.placed = np.zeros((rows * self.columns, 2), np.intp)

    @staticmethod
    def mosaic_shape(cell: int, cells: int, columns: int = 8) -> tuple[int, int]:
        """(rows, cols) px of the mosaic of ``cells`` windows of ``cell`` px."""
        across = min(int(columns), int(cells))
        return -(-int(cells) // across) * int(cell), across * int(cell)

    def detect(self, image: np.ndarray, origins: np.ndarray) -> Detections:
        """Stars in the windows whose top-left pixels (x0, y0) are ``origins`` (cells, 2).

        Every window lies inside ``image`` (the planner clips them).
        """
        c, cols = self.cell, self.columns
        order = np.lexsort((origins[:, 0], origins[:, 1]))
        self.placed[:self.cells] = origins[order]
        self.placed[self.cells:] = self.placed[:len(self.placed) - self.cells]
        np.multiply(self.placed[:, 1], self.frame_shape[1], out=self.corner.reshape(-1))
        self.corner.reshape(-1)[:] += self.placed[:, 0]
        np.add(self.corner, self.offsets, out=self.index)
        np.take(np.ascontiguousarray(image).reshape(-1), self.index.reshape(self.mosaic.shape),
                out=self.mosaic)
        found = self.detector.detect(self.mosaic)
        stars = found.stars
        mx, my = stars["x"], stars["y"]
        mcol = np.clip(np.floor((mx + 0.5) / c).astype(np.intp), 0, cols - 1)
        mrow = np.clip(np.floor((my + 0.5) / c).astype(np.intp), 0, len(self.mosaic) // c - 1)
        slot = mrow * cols + mcol
        x0, y0 = self.placed[slot, 0], self.placed[slot, 1]
        fx, fy = mx - mcol * c + x0, my - mrow * c + y0
        keep = self._inside(fx - x0, x0, 1) & self._inside(fy - y0, y0, 0)
        rows = np.flatnonzero(keep)
        rows = rows[~later_within(fx[rows], fy[rows], _SAME_STAR_PX)][: self.table.capacity]
        n = len(rows)
        out = self.table.stars
        out[:n] = stars[rows]
        out["x"][:n], out["y"][:n] = fx[rows], fy[rows]
        h, w = self.frame_shape
        m = self.margin
        edge = ((fx[rows] < m) | (fy[rows] < m) | (fx[rows] > w - 1 - m)
                | (fy[rows] > h - 1 - m))
        flags = out["flags"][:n] & ~np.uint16(StarFlag.EDGE)
        flags[edge] |= StarFlag.EDGE
        out["flags"][:n] = flags
        return Detections(out[:n], found.reason, found.counters, found.stages_ms,
                          found.psf_sigma_px, found.psf_ellipticity, found.psf_angle_deg,
                          found.psf_stars)

    def _inside(self, offset: np.ndarray, origin: np.ndarray, axis: int) -> np.ndarray:
        """Offsets within a window at least ``margin`` from its inner borders.

        ``axis`` 1: x (the frame's width bounds it), 0: y. A border on the
        frame's own edge does not count.
        """
        limit = self.frame_shape[axis]
        m, c = self.margin, self.cell
        low_ok = (offset >= m - 0.5) | (origin == 0)
        high_ok = (offset <= c - 0.5 - m) | (origin + c >= limit)
        return low_ok & high_ok
