"""Constants that depend only on the PSF's sigma step, computed once per step.

The default detector uses PSF sigmas in steps of 3 % (tracker.detect.default)
and derives a handful of constants from each: the false-alarm threshold of
its matched filter, the impulse contrasts, a star's roughness and its spread, its
lowest width over the pixel phase, the filter's noise gain at the frame's borders.
Each takes a fraction of a millisecond of small numpy arithmetic; a PSF that changes from frame to
frame (a folder of frames from different lenses, a focus run) would pay it
on every frame, and even a steady one on each frame that reaches a step
for the first time. :class:`SigmaSteps` keeps them in a table with one row
per step of the range the detector handles, made and filled at
construction (:meth:`SigmaSteps.fill`, 70 steps: about 80 ms once), so a
frame never computes them and memory stays fixed whatever the PSF does.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["SigmaSteps"]


class SigmaSteps:
    """Rows of ``scalars`` floats and two float32 gain vectors of up to ``gains`` values,
    for the steps ``first``..``last``; steps outside are computed every time."""

    def __init__(self, first: int, last: int, scalars: int, gains: int) -> None:
        self.first = int(first)
        count = int(last) - self.first + 1
        self.known = np.zeros(count, np.bool_)
        self.scalars = np.zeros((count, int(scalars)), np.float64)
        self.gains = np.zeros((count, 2, int(gains)), np.float32)
        self.lengths = np.zeros(count, np.intp)

    def fill(self, compute: Callable[[int], tuple[tuple, tuple[np.ndarray, np.ndarray]]]
             ) -> None:
        """Compute every step of the table: ``compute(step)`` as :meth:`get`'s."""
        for i in range(len(self.known)):
            step = self.first + i
            self.get(step, lambda step=step: compute(step))

    def get(self, step: int,
            compute: Callable[[], tuple[tuple, tuple[np.ndarray, np.ndarray]]]
            ) -> tuple[tuple, tuple[np.ndarray, np.ndarray]]:
        """(scalars, (first gains, second gains)) of ``step``; ``compute()`` gives them
        (a tuple of floats and two float32 vectors of one length) when not yet known.
        The vectors returned are views of the table."""
        i = int(step) - self.first
        if not 0 <= i < len(self.known):
            return compute()
        if not self.known[i]:
            scalars, (a, b) = compute()
            self.scalars[i] = scalars
            n = len(a)
            self.gains[i, 0, :n] = a
            self.gains[i, 1, :n] = b
            self.lengths[i] = n
            self.known[i] = True
        n = int(self.lengths[i])
        return tuple(float(v) for v in self.scalars[i]), (self.gains[i, 0, :n],
                                                           self.gains[i, 1, :n])
