"""Which windows of the next frame tracking looks at: around predicted stars, plus a sweep.

A predicted star needs a window of half-width

    h = k sigma + |smear| / 2 + reach

(``identify.track_window_sigma`` k times its radial 1-sigma, half its travel
over the exposure, and the PSF's reach, within which tracker.detect.windows
drops stars at a window's inner border). All windows of a frame share one
side, the largest h of its stars rounded up to a multiple of ``STEP_PX``
(at least ``MIN_CELL_PX``), so that one detector serves the frame; a frame
needing more than ``identify.track_window_max_px`` is searched whole. Sides
are three background tiles of at least 8 px: the window detector takes
each window's background from its own 3 x 3 tiles (tracker.pipeline).

Every frame gets the same number of windows, ``capacity`` = stars followed
+ ``identify.track_sweep_windows``: the predicted stars' (brightest first),
and the rest sweep the frame, row after row of windows across frames (a
star seen in two windows is reported once). The sweep finds stars that
the catalogue does not predict (planets, satellites, a wrong lens) and
keeps the cost of a frame fixed: the windows of stars too faint to be
found (tracker.identify.solver.Solver.prediction leaves them out) sweep
too. Windows are clipped into the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker.identify.predict import TrackPrediction

__all__ = ["WindowPlan", "WindowPlanner", "STEP_PX", "MIN_CELL_PX"]

STEP_PX = 24      # window sides are multiples of this (3 tiles): few sizes, few detectors
MIN_CELL_PX = 24  # 3 x 3 background tiles of 8 px at least


@dataclass(frozen=True)
class WindowPlan:
    """One frame's windows: ``origins`` (n, 2) top-left (x0, y0) px, ``cell`` px square.

    The first ``stars`` are around predicted stars; ``area_px`` is the
    frame area the windows cover (overlaps counted once per window).
    ``origins`` is the planner's buffer, valid until its next plan.
    """

    cell: int
    origins: np.ndarray
    stars: int
    area_px: float


class WindowPlanner:
    """Plans windows for frames of ``width`` x ``height`` px; keeps the sweep's place.

    ``capacity`` windows a frame, ``sweep`` of them at least for the sweep;
    ``sigmas`` the k above, ``reach_px`` the PSF's reach, ``max_cell_px``
    the largest window.
    """

    def __init__(self, width: int, height: int, capacity: int, sweep: int, sigmas: float,
                 reach_px: float, max_cell_px: int) -> None:
        self.width, self.height = int(width), int(height)
        self.capacity = int(capacity)
        self.sweep = int(sweep)
        self.sigmas = float(sigmas)
        self.reach = float(reach_px)
        self.max_cell = min(int(max_cell_px), self.width, self.height)
        self._next = (0, 0)     # the sweep's next window, top-left (x0, y0)
        self.origins = np.zeros((self.capacity, 2), np.intp)

    def cell_for(self, prediction: TrackPrediction) -> int | None:
        """The window side this prediction needs (module docstring), or None if too large."""
        if len(prediction.xy) == 0:
            return None
        half = (self.sigmas * prediction.sigma_px
                + 0.5 * np.hypot(prediction.smear_px[:, 0], prediction.smear_px[:, 1])
                + self.reach)
        side = 2.0 * float(half.max()) + 1.0
        cell = max(MIN_CELL_PX, STEP_PX * math.ceil(side / STEP_PX))
        return cell if cell <= self.max_cell else None

    def plan(self, prediction: TrackPrediction) -> WindowPlan | None:
        """This frame's windows, or None when they would be too large (search the frame)."""
        cell = self.cell_for(prediction)
        if cell is None:
            return None
        n_star = min(len(prediction.xy), self.capacity - self.sweep)
        o = self.origins
        o[:n_star] = np.minimum(np.maximum(np.rint(prediction.xy[:n_star] - 0.5 * (cell - 1)),
                                           0), (self.width - cell, self.height - cell))
        self._sweep(cell, n_star)
        return WindowPlan(cell=cell, origins=o, stars=n_star,
                          area_px=float(self.capacity * cell * cell))

    def _sweep(self, cell: int, first: int) -> None:
        """Fill windows ``first``.. with the sweep's next places (module docstring).

        The sweep walks a grid of ``cell`` px from the top-left, row after row,
        and starts again at the top after the last row.
        """
        across = -(-self.width // cell)
        down = -(-self.height // cell)
        x, y = self._next
        start = (min(y // cell, down - 1)) * across + min(x // cell, across - 1)
        steps = np.arange(start, start + self.capacity - first + 1) % (across * down)
        row, col = np.divmod(steps, across)
        self.origins[first:, 0] = np.minimum(col[:-1] * cell, self.width - cell)
        self.origins[first:, 1] = np.minimum(row[:-1] * cell, self.height - cell)
        self._next = (int(col[-1]) * cell, int(row[-1]) * cell)
