"""tracker.detect.peaks: the local-maximum test against its definition, pixel by pixel; the
threshold's rows finished slab by slab (the detector's border strips) as over the frame."""

from __future__ import annotations

import cv2
import numpy as np

from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.layout import PaddedLayout
from tracker.detect.peaks import PeakFinder
from tracker.detect.slabs import SlabRunner


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


def test_each_compare_slab_finishes_its_own_threshold_rows_first():
    """find's ``finish(first, end)`` runs on every slab's rows before they are compared:
    rows a finish raises out of reach give no candidates, whatever slab holds them."""
    layout = PaddedLayout((120, 90), 8)
    slabs = SlabRunner(layout.rows, layout.cols, 0, 2, np.float32)
    finder = PeakFinder(layout, 3, 3.0, 4096, 512, slabs=slabs)
    filt_pad, filt = layout.buffer(np.float32)
    bg_pad, _ = layout.buffer(np.float32)
    filt[20, 30] = filt[70, 40] = filt[100, 60] = 10.0          # three peaks
    threshold = np.full(filt.shape, 1.0, np.float32)
    seen = []

    def finish(first, end):
        seen.append((first, end))
        threshold[max(first, 60):end] = np.inf                  # rows 60 on: out of reach

    n = finder.find(filt_pad, filt, threshold, bg_pad, lambda factor: None,
                    lambda flat, out: out.fill(1.0), finish=finish)
    assert sorted(seen) == slabs.slabs and len(seen) == 2
    assert n == 1 and finder.cand[0] == layout.flat_index(np.array([20]), np.array([30]))[0]


def test_the_thresholds_border_strips_raised_slab_by_slab_are_raised_once():
    """The detector's border gains applied on row ranges (as each compare slab does) give
    bit for bit the strips raised over the whole frame in one order: top, bottom, left,
    right (a pixel in a corner meets two of them)."""
    shape = (100, 140)
    det = make_detector(DetectConfig(method="default"), shape, 10)
    rng = np.random.default_rng(3)
    det.bg[:] = rng.uniform(10.0, 20.0, shape).astype(np.float32)
    start = (det.bg + rng.uniform(1.0, 5.0, shape)).astype(np.float32)
    r, c = det.edge_rows, det.edge_cols
    expected = start.copy()
    for sl, gain in (((slice(0, r), slice(None)), det.row_gains[0, :r]),
                     ((slice(-r, None), slice(None)), det.row_gains[1, :r]),
                     ((slice(None), slice(0, c)), det.col_gains[0, :, :c]),
                     ((slice(None), slice(-c, None)), det.col_gains[1, :, :c])):
        expected[sl] = (expected[sl] - det.bg[sl]) * gain + det.bg[sl]
    for cuts in ((0, 100), (0, 1, 50, 99, 100)):   # cuts inside the top and bottom strips
        det.threshold[:] = start
        for first, end in zip(cuts[:-1], cuts[1:], strict=True):
            det._raise_edges(first, end)
        np.testing.assert_array_equal(det.threshold, expected)
    assert r >= 2 and np.any(expected != start)
