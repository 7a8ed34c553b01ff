"""Pixel-integrated Gaussian point-spread function.

A star at (x, y) (pixel convention: origin at the centre of the top-left
pixel, pixel (c, r) spans c-0.5..c+0.5, r-0.5..r+0.5) with PSF sigma ``s``
puts into pixel (c, r) the fraction

    wx(c) * wy(r),   wx(c) = (erf((c + 0.5 - x) / (s sqrt 2)) - erf((c - 0.5 - x) / (s sqrt 2))) / 2

of its light: the Gaussian integrated exactly over the pixel, so the
fractions sum to 1 over the plane and the intensity centroid of the
stamp is (x, y). A moving star is the mean of such stamps at sub-steps of
its path. Stars just outside the frame still spill their wings in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.normal import pixel_fractions

__all__ = ["Stamps", "psf_stamps", "add_stamps", "stamp_half_width", "stamp_pixels",
           "stamp_box"]

# Gaussian tails beyond this many sigma hold < 6e-7 of the light per axis.
_TAIL_SIGMAS = 5.0


def stamp_half_width(sigma: float) -> int:
    """Pixels either side of a star's pixel that receive its light."""
    return int(np.ceil(_TAIL_SIGMAS * sigma)) + 1


@dataclass(frozen=True)
class Stamps:
    """Per-star light fractions on a small pixel box.

    ``values[i]`` (shape (ky, kx)) is star i's fraction of light in pixels
    rows ``y0[i] .. y0[i]+ky-1``, columns ``x0[i] .. x0[i]+kx-1``; it sums
    to 1 up to the clipped tails (< 1e-6).
    """

    x0: np.ndarray
    y0: np.ndarray
    values: np.ndarray


def _axis_weights(centres: np.ndarray, first: np.ndarray, size: int,
                  sigma: float) -> np.ndarray:
    """Fractions (N, M, size) along one axis for centres (N, M), boxes starting at first (N,)."""
    edges = first[:, None, None] + np.arange(size + 1) - 0.5  # (N, 1, size+1)
    return pixel_fractions(edges - centres[:, :, None], sigma)[0]


def stamp_box(xs, ys, half: int):
    """Star paths as (N, M) arrays and the box each star's stamp covers.

    ``xs``, ``ys``: positions (N,) or paths (N, M), px; ``half``: pixels
    either side of the path's pixels. Returns (xs, ys, x0, y0, kx, ky): the
    paths, each box's first column and row, and the boxes' common width and
    height. Raises ValueError for mismatched shapes or non-finite positions.
    """
    xs = np.atleast_1d(np.asarray(xs, dtype=np.float64))
    ys = np.atleast_1d(np.asarray(ys, dtype=np.float64))
    if xs.ndim == 1:
        xs, ys = xs[:, None], ys[:, None]
    if xs.shape != ys.shape or xs.ndim != 2:
        raise ValueError(f"star paths must have matching shapes (N,) or (N, M); got "
                         f"{xs.shape} and {ys.shape}")
    if not (np.all(np.isfinite(xs)) and np.all(np.isfinite(ys))):
        raise ValueError("star positions must be finite")
    lo_x, lo_y = np.floor(xs.min(axis=1) + 0.5), np.floor(ys.min(axis=1) + 0.5)
    span_x = int((np.floor(xs.max(axis=1) + 0.5) - lo_x).max(initial=0))
    span_y = int((np.floor(ys.max(axis=1) + 0.5) - lo_y).max(initial=0))
    x0 = (lo_x - half).astype(np.int64)
    y0 = (lo_y - half).astype(np.int64)
    return xs, ys, x0, y0, span_x + 2 * half + 1, span_y + 2 * half + 1


def psf_stamps(xs: np.ndarray, ys: np.ndarray, sigma: float) -> Stamps:
    """Stamps of N stars along paths xs, ys of shape (N,) or (N, M) (M sub-steps, px).

    With M sub-steps the stamp is the mean over the path: a star that
    moves during the exposure. ``sigma`` is the PSF sigma in pixels.
    """
    if not sigma > 0:
        raise ValueError(f"PSF sigma must be > 0 px; got {sigma}")
    xs, ys, x0, y0, kx, ky = stamp_box(xs, ys, stamp_half_width(sigma))
    wx = _axis_weights(xs, x0, kx, sigma)
    wy = _axis_weights(ys, y0, ky, sigma)
    values = np.einsum("nmy,nmx->nyx", wy, wx) / xs.shape[1]
    return Stamps(x0=x0, y0=y0, values=values)


def stamp_pixels(shape: tuple[int, int],
                 stamps: Stamps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row and column of every stamp pixel, and whether it lies in an image of ``shape``.

    The three arrays broadcast to ``stamps.values.shape``.
    """
    height, width = shape
    _, ky, kx = stamps.values.shape
    rows = stamps.y0[:, None, None] + np.arange(ky)[None, :, None]
    cols = stamps.x0[:, None, None] + np.arange(kx)[None, None, :]
    inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    return rows, cols, inside


def add_stamps(shape: tuple[int, int], stamps: Stamps, amounts: np.ndarray) -> np.ndarray:
    """Float64 image of the given shape holding ``amounts[i] * stamps.values[i]`` summed.

    Parts of stamps outside the image are dropped.
    """
    height, width = shape
    rows, cols, inside = stamp_pixels(shape, stamps)
    flat = (rows * width + cols)[inside]
    weights = (stamps.values * np.asarray(amounts, dtype=np.float64)[:, None, None])[inside]
    image = np.bincount(flat, weights=weights, minlength=height * width)
    return image.reshape(height, width)
