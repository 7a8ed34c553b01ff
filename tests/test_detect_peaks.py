"""tracker.detect.peaks: the local-maximum test against its definition, pixel by pixel."""

from __future__ import annotations

import cv2
import numpy as np

from tracker.detect.layout import PaddedLayout
from tracker.detect.peaks import PeakFinder


def _raster_maxima(image: np.ndarray, above: np.ndarray) -> np.ndarray:
    """The definition, pixel by pixel: above the four neighbours met before it in raster
    order, not below the four after (reflected at the border like a padded buffer's)."""
    rows, cols = image.shape
    out = np.zeros_like(above)
    for r, c in zip(*np.nonzero(above), strict=True):
        nb = [image[min(max(r + dy, 0), rows - 1), min(max(c + dx, 0), cols - 1)]
              for dy, dx in ((-1, -1), (-1, 0), (-1, 1), (0, -1),
                             (0, 1), (1, -1), (1, 0), (1, 1))]
        out[r, c] = image[r, c] > max(nb[:4]) and image[r, c] >= max(nb[4:])
    return out


def test_local_maxima_are_those_of_the_raster_order_definition_plateaus_included():
    rng = np.random.default_rng(5)
    layout = PaddedLayout((60, 80), 4)
    finder = PeakFinder(layout, 3, 3.0, 4096, 512)
    filt_pad, filt = layout.buffer(np.float32)
    noise = rng.normal(0.0, 1.0, (60, 80)).astype(np.float32)
    np.copyto(filt, cv2.GaussianBlur(noise, (5, 5), 1.0))
    filt[20:23, 30:34] = 5.0                      # a flat top: one maximum, its first pixel
    np.rint(filt * 4, out=filt)                   # ties between neighbours
    cv2.copyMakeBorder(filt, 4, 4, 4, 4, cv2.BORDER_REPLICATE, dst=filt_pad)
    threshold = np.full(filt.shape, 0.5, np.float32)
    n = finder._above(filt, threshold, lambda factor: None)
    m = finder._local_maxima(n, filt_pad)
    found = np.zeros(filt.shape, np.bool_)
    rows, cols = layout.frame_position(finder.pixels[:n][finder.is_max[:n]])
    found[rows, cols] = True
    expected = _raster_maxima(filt, filt > threshold)
    assert m == int(expected.sum()) > 10
    assert np.array_equal(found, expected)
    assert found[20, 30] and found[20:23, 30:34].sum() == 1


def test_pairs_are_every_pair_of_candidates_within_the_radius():
    rng = np.random.default_rng(8)
    layout = PaddedLayout((200, 300), 30)
    finder = PeakFinder(layout, 12, 3.0, 4096, 512)
    n = 400   # half spread over the frame, half crowded into five rows (a glare's edge)
    rows = np.concatenate((rng.integers(0, 200, n // 2), rng.integers(100, 105, n // 2)))
    cols = rng.integers(0, 300, n)
    flat = np.unique(layout.flat_index(rows, cols))
    rng.shuffle(flat)                                  # ranked by brightness, not place
    n = len(flat)
    finder.cand[:n] = flat
    i, j = finder._pairs(n)
    r, c = layout.frame_position(flat)
    d2 = (r[:, None] - r[None, :]) ** 2 + (c[:, None] - c[None, :]) ** 2
    expected = set(zip(*np.nonzero((d2 <= 144) & ~np.eye(n, dtype=bool)), strict=True))
    assert len(expected) > 100
    assert set(zip(i.tolist(), j.tolist(), strict=True)) == expected
    assert len(i) == len(expected)
