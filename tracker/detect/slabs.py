"""Running a neighbourhood filter on horizontal slabs of a frame in parallel threads.

OpenCV's float Gaussian and its median run on one core. :class:`SlabRunner`
cuts the frame into ``threads`` horizontal slabs and filters each in its own
thread (OpenCV releases the GIL), the first in the calling thread. A filter
with a kernel reaching ``halo`` rows treats each slab's edge as the frame's
border, so the ``halo`` rows on either side of each cut come out wrong; they
are then recomputed from a strip of ``4 * halo`` rows around the cut and
copied in. The result is the same, pixel for pixel, as one call on the whole
frame.

:meth:`SlabRunner.rows` does the same for work that only reads and writes
its own rows (no cuts to repair), and :meth:`SlabRunner.start` runs a filter
on the whole frame in a worker thread while the caller does other work.
Frames too short to cut (fewer than
``8 * max(halo, 1)`` rows per slab) are processed in one call. Buffers
(one strip per cut) and the worker threads are made at construction.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

__all__ = ["SlabRunner", "set_opencv_threads"]


def set_opencv_threads(threads: int) -> None:
    """OpenCV's threads per call for the process: ``threads`` (1 = in the calling thread
    alone), or 0 for OpenCV's default (every core)."""
    cv2.setNumThreads(-1 if threads == 0 else int(threads))


class SlabRunner:
    """Applies ``op(src, dst)`` to (rows, cols) images of ``dtype`` in ``threads`` slabs.

    ``halo`` is the largest reach of the filters it will run.
    """

    def __init__(self, rows: int, cols: int, halo: int, threads: int, dtype: type) -> None:
        self.halo = int(halo)
        threads = max(1, int(threads))
        if rows < 8 * max(self.halo, 1) * threads:
            threads = 1
        bounds = np.linspace(0, rows, threads + 1).round().astype(int)
        self.slabs = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        self.strips = ([np.zeros((4 * self.halo, cols), dtype) for _ in self.slabs[1:]]
                       if self.halo > 0 else [])
        self.pool = ThreadPoolExecutor(threads - 1) if threads > 1 else None

    @property
    def threads(self) -> int:
        return len(self.slabs)

    def rows(self, work: Callable[[int, int], object]) -> None:
        """Call ``work(first, end)`` for every slab's rows [first, end), in parallel."""
        if self.pool is None:
            work(*self.slabs[0])
            return
        jobs = [self.pool.submit(work, a, b) for a, b in self.slabs[1:]]
        work(*self.slabs[0])
        for job in jobs:
            job.result()

    def start(self, op: Callable[[np.ndarray, np.ndarray], object], src: np.ndarray,
              dst: np.ndarray) -> Callable[[], object]:
        """Begin dst = op(src) over the whole frame in one call on a worker thread, while
        the caller goes on with other work; returns the function that waits for it.
        With one thread it runs now (the wait returns at once)."""
        if self.pool is None:
            op(src, dst)
            return lambda: None
        return self.pool.submit(op, src, dst).result

    def run(self, op: Callable[[np.ndarray, np.ndarray], object], src: np.ndarray,
            dst: np.ndarray, halo: int | None = None) -> None:
        """dst = op(src) over the whole frame; ``src`` and ``dst`` do not overlap.

        ``halo``: the reach of this ``op``, at most the constructor's (default).
        """
        self.rows(lambda a, b: op(src[a:b], dst[a:b]))
        h = self.halo if halo is None else min(int(halo), self.halo)
        if h == 0:
            return
        for (cut, _), strip in zip(self.slabs[1:], self.strips, strict=True):
            part = strip[:4 * h]
            op(src[cut - 2 * h:cut + 2 * h], part)
            np.copyto(dst[cut - h:cut + h], part[h:3 * h])
