"""The focus metric a person at the Pi needs: the PSF's FWHM across the field, as a picture.

A lens focused well gives the smallest star images in the middle of the
field; tilt shows as one side wider than the other, field curvature as the
corners wider than the middle. :func:`spread_over` picks the stars to
measure, a few per cell; :func:`focus_map` takes their PSFs
(tracker.detect.default.DefaultDetector.psf_of: isolated, unsaturated
stars, measured one by one) and bins them into a grid of cells; each
cell holds the median FWHM (2 sqrt(2 ln 2) sigma, the optics' own, pixel
width removed) and ellipticity of its stars.

The sigma is that of the Gaussian with the star's adaptively weighted
second moments: exact for a Gaussian PSF (within 1 % for sigma 0.8-3 px),
13-16 % above the true FWHM for a Moffat PSF with beta 3 (its wings), 6 %
below it for an Airy disc. Focusing needs only that it is smallest where
the star images are smallest, which holds for each shape.

:func:`terminal_lines` gives the grid as a few lines of text (FWHM in px,
``--`` for a cell with no star), :func:`draw_map` a picture: the frame
(square-root stretched) under the grid, each cell coloured from green (at
the frame's best FWHM) to red (twice it), its FWHM written in it, and a
title with the frame's median FWHM, ellipticity and star count.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from tracker.detect.psf import FWHM_PER_SIGMA

__all__ = ["FocusMap", "focus_map", "spread_over", "terminal_lines", "draw_map", "write_png"]


@dataclass
class FocusMap:
    """Median FWHM (px) and ellipticity per cell (NaN: no star), star counts, frame figures."""

    fwhm_px: np.ndarray          # (rows, cols)
    ellipticity: np.ndarray      # (rows, cols)
    stars: np.ndarray            # (rows, cols) int
    frame_fwhm_px: float         # median over all the stars, NaN if none
    frame_ellipticity: float
    total: int


def focus_map(stars: np.ndarray, shape: tuple[int, int], grid: tuple[int, int]) -> FocusMap:
    """Bin ``stars`` (fields x, y, sigma_px, ellipticity) of a frame of ``shape`` (rows,
    cols) into ``grid`` (rows, cols) cells."""
    rows, cols = int(grid[0]), int(grid[1])
    fwhm = np.full((rows, cols), np.nan)
    ell = np.full((rows, cols), np.nan)
    count = np.zeros((rows, cols), int)
    if len(stars):
        r = np.clip((stars["y"] * rows / shape[0]).astype(int), 0, rows - 1)
        c = np.clip((stars["x"] * cols / shape[1]).astype(int), 0, cols - 1)
        for i in range(rows):
            for j in range(cols):
                inside = (r == i) & (c == j)
                count[i, j] = int(np.count_nonzero(inside))
                if count[i, j]:
                    fwhm[i, j] = FWHM_PER_SIGMA * float(np.median(stars["sigma_px"][inside]))
                    ell[i, j] = float(np.median(stars["ellipticity"][inside]))
    total = len(stars)
    return FocusMap(fwhm, ell, count,
                    FWHM_PER_SIGMA * float(np.median(stars["sigma_px"])) if total else np.nan,
                    float(np.median(stars["ellipticity"])) if total else np.nan, total)


def spread_over(stars: np.ndarray, shape: tuple[int, int], grid: tuple[int, int],
                per_cell: int = 6) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per cell of ``grid`` (rows, cols) over a frame of ``shape``, the positions (x, y) of
    its ``per_cell`` most significant ``stars``: the stars a focus map measures, cell by
    cell, so that a corner is not left out because the middle is sharper, and each cell's
    stars are measured in windows fit for their own width."""
    rows, cols = int(grid[0]), int(grid[1])
    cell = (np.clip((stars["y"] * rows / shape[0]).astype(int), 0, rows - 1) * cols
            + np.clip((stars["x"] * cols / shape[1]).astype(int), 0, cols - 1))
    out = []
    for k in range(rows * cols):
        mine = np.flatnonzero(cell == k)
        mine = mine[np.argsort(-stars["snr"][mine], kind="stable")][:per_cell]
        out.append((stars["x"][mine], stars["y"][mine]))
    return out


def terminal_lines(fm: FocusMap) -> list[str]:
    """The map as text: a header line, then one line of FWHM (px) per row of cells."""
    head = (f"FWHM {fm.frame_fwhm_px:.2f} px, ellipticity {fm.frame_ellipticity:.2f}, "
            f"{fm.total} stars" if fm.total else "no stars bright and isolated enough")
    lines = [head]
    for row in fm.fwhm_px:
        lines.append(" ".join("  -- " if np.isnan(v) else f"{v:5.2f}" for v in row))
    return lines


def draw_map(image: np.ndarray, bit_depth: int, fm: FocusMap, width: int = 800) -> np.ndarray:
    """A BGR picture of the frame with the focus map over it, ``width`` px wide."""
    full = float(2 ** int(bit_depth) - 1)
    grey = np.sqrt(np.clip(image.astype(np.float32) / full, 0.0, 1.0))
    height = max(1, int(round(image.shape[0] * width / image.shape[1])))
    grey = cv2.resize(grey, (width, height), interpolation=cv2.INTER_AREA)
    canvas = cv2.cvtColor((grey * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    rows, cols = fm.fwhm_px.shape
    best = np.nanmin(fm.fwhm_px) if fm.total else np.nan
    for i in range(rows):
        for j in range(cols):
            x0, x1 = j * width // cols, (j + 1) * width // cols
            y0, y1 = i * height // rows, (i + 1) * height // rows
            v = fm.fwhm_px[i, j]
            if np.isnan(v):
                cv2.rectangle(canvas, (x0, y0), (x1 - 1, y1 - 1), (90, 90, 90), 1)
                continue
            t = float(np.clip(v / best - 1.0, 0.0, 1.0))     # 0 at the best, 1 at twice it
            colour = (0, int(255 * (1 - t)), int(255 * t))
            patch = canvas[y0:y1, x0:x1]
            patch[:] = (0.7 * patch + 0.3 * np.array(colour, np.float32)).astype(np.uint8)
            cv2.rectangle(canvas, (x0, y0), (x1 - 1, y1 - 1), colour, 2)
            cv2.putText(canvas, f"{v:.2f}", (x0 + 6, (y0 + y1) // 2 + 6),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 2, cv2.LINE_AA)
    title = terminal_lines(fm)[0]
    cv2.putText(canvas, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2,
                cv2.LINE_AA)
    return canvas


def write_png(path: Path, picture: np.ndarray) -> None:
    """Write ``picture`` to ``path`` atomically: a viewer refreshing it never sees half."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.png")
    if not cv2.imwrite(str(tmp), picture):
        raise OSError(f"{path}: could not write the PNG")
    os.replace(tmp, path)
