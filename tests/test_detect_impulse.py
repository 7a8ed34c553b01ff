"""The lone-impulse rule judged again once a frame's PSF is known
(tracker.detect.impulse.ImpulseFilter.retest_lone)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tracker.detect.impulse import ImpulseFilter, psf_contrast, psf_ring
from tracker.detect.layout import PaddedLayout

BACKGROUND = 100
LIMIT = 20                  # k_sigma times the pixel noise, ADU


def _star(frame, row, col, sigma, peak):
    """Add a pixel-integrated Gaussian star centred on pixel (row, col), ``peak`` ADU high."""
    edges = np.arange(-6.5, 7.0)
    w = np.diff([math.erf(e / (sigma * math.sqrt(2.0))) for e in edges])
    stamp = np.outer(w, w)
    stamp *= peak / stamp.max()
    frame[row - 6:row + 7, col - 6:col + 7] += np.rint(stamp).astype(frame.dtype)


def test_a_hot_pixel_spared_for_a_sharp_psf_is_replaced_for_the_frames_and_its_star_kept():
    """A hot pixel 60 ADU high whose 3x3 median five lifted neighbours raise by 10 stands
    above it by 0.83 of its height: spared by the first pass (judged against a 0.55 px
    PSF) and by the refinement against the sharpest PSF handled. Against the frame's
    2.2 px PSF it is an impulse and is replaced by its median, while the peak of a star
    of that PSF, 300 ADU high (above its median by more than the limit), is not."""
    layout = PaddedLayout((80, 80), 8)
    pad, frame = layout.buffer(np.uint16)
    frame[:] = BACKGROUND
    frame[19:22, 19:22] = [[110, 110, 110], [110, 160, 100], [110, 100, 100]]
    _star(frame, 50, 50, 2.2, 300.0)
    bg_pad, bg = layout.buffer(np.float32)
    bg[:] = BACKGROUND
    limit_pad, limit = layout.buffer(np.uint16)
    limit[:] = LIMIT
    impulses = ImpulseFilter(layout, 0.5 * (1.0 + psf_contrast(0.55, worst_phase=True)), 64,
                             np.uint16)
    impulses.run(pad, frame, bg_pad, limit_pad, limit)
    impulses.refine(pad, bg_pad, limit_pad, impulses.contrast, 0.5 * psf_ring(0.45))
    assert frame[20, 20] == 160 and frame[50, 50] == BACKGROUND + 300
    mirror = pad.astype(np.float32)
    hit, excess = impulses.retest_lone(pad, 0.5 * (1.0 + psf_contrast(0.9 * 2.2, True)),
                                       0.5 * psf_ring(0.9 * 2.2), mirror_pad=mirror)
    assert list(hit) == list(layout.flat_index(np.array([20]), np.array([20])))
    assert list(excess) == [50.0]
    assert frame[20, 20] == 110 and mirror[8 + 20, 8 + 20] == 110.0
    assert frame[50, 50] == BACKGROUND + 300


@pytest.mark.parametrize("threads", [1, 2])
def test_the_first_cut_lists_every_pixel_beyond_the_limit_from_its_median(threads):
    """The first cut (made a few rows at a time, in slabs, with the mask's words marked
    as it goes) lists exactly the pixels differing from their 3x3 median by more than
    the limit, in raster order: a frame of 150 rows (no whole number of the cut's row
    blocks, two slabs) with noise, hot and dead pixels and a limit varying across it."""
    rng = np.random.default_rng(12)
    shape = (150, 90)
    layout = PaddedLayout(shape, 8)
    pad, frame = layout.buffer(np.uint16)
    frame[:] = rng.poisson(BACKGROUND, shape)
    hits = rng.choice(frame.size, 300, replace=False)
    frame.ravel()[hits[:200]] += 80
    frame.ravel()[hits[200:]] = 0
    limit_pad, limit = layout.buffer(np.uint16)
    limit[:] = np.linspace(15, 60, shape[1]).astype(np.uint16)[None, :]
    expected = np.abs(frame.astype(np.int32) - cv2.medianBlur(frame, 3)) > limit
    rows, cols = np.nonzero(expected)
    impulses = ImpulseFilter(layout, 0.5, 4096, np.uint16, threads)
    assert impulses.slabs.threads == threads
    for _ in range(2):                     # the second frame's cut starts from the first's
        impulses.cut(frame, limit)
        n = impulses._listed
        assert n == len(rows) > 150
        np.testing.assert_array_equal(impulses.index[:n], layout.flat_index(rows, cols))


def test_a_first_pass_that_does_not_split_its_counts_leaves_the_second_pass_the_same():
    """test(..., split=False) counts only the impulse pixels; refine, which counts hot
    pixels and tracks itself, then replaces the same pixels and reports the same counts as
    after a first pass that split them (hot pixels, a track, dead pixels, a star)."""
    rng = np.random.default_rng(13)
    shape = (120, 100)
    layout = PaddedLayout(shape, 8)
    base = rng.poisson(BACKGROUND, shape).astype(np.uint16)
    base.ravel()[rng.choice(base.size, 40, replace=False)] += 90     # hot pixels
    base[30, 20:32] += 120                                           # a track
    base[31, 24:29] += 60
    base.ravel()[rng.choice(base.size, 10, replace=False)] = 0       # dead pixels
    _star(base, 80, 60, 1.5, 400.0)
    out = []
    for split in (True, False):
        pad, frame = layout.buffer(np.uint16)
        frame[:] = base
        bg_pad, bg = layout.buffer(np.float32)
        bg[:] = BACKGROUND
        limit_pad, limit = layout.buffer(np.uint16)
        limit[:] = LIMIT
        impulses = ImpulseFilter(layout, 0.5 * (1.0 + psf_contrast(0.55, worst_phase=True)),
                                 4096, np.uint16)
        impulses.cut(frame, limit)
        first = dict(impulses.test(pad, bg_pad, limit_pad, split=split))
        counts = dict(impulses.refine(pad, bg_pad, limit_pad, 0.5 * (1.0 + psf_contrast(
            0.9 * 1.5, True)), 0.5 * psf_ring(0.9 * 1.5)))
        out.append((first, counts, pad.copy()))
    (split_first, split_counts, split_pad), (first, counts, frame_pad) = out
    assert first == {"impulse_pixels": split_first["impulse_pixels"], "hot_pixels": 0,
                     "cosmic_rays": 0}
    assert split_first["hot_pixels"] > 30 and split_counts["cosmic_rays"] >= 1
    assert counts == split_counts
    np.testing.assert_array_equal(frame_pad, split_pad)
