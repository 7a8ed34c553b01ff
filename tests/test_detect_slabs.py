"""Slab-parallel filters equal one whole-frame call, pixel for pixel; uint16 input is exact."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from tracker.config import DetectConfig, SimConfig
from tracker.detect import make_detector
from tracker.detect.background import BackgroundGrid
from tracker.detect.binned import BinnedPeaks
from tracker.detect.frame_input import FrameInput
from tracker.detect.layout import PaddedLayout
from tracker.detect.slabs import SlabRunner
from tracker.sim import render_points


def _gauss(src, dst):
    cv2.GaussianBlur(src, (5, 5), 1.23, dst=dst, borderType=cv2.BORDER_REFLECT)


def _median(src, dst):
    cv2.medianBlur(src, 3, dst=dst)


@pytest.mark.parametrize("threads", [1, 2, 3, 4])
@pytest.mark.parametrize("rows", [5, 40, 101])
@pytest.mark.parametrize("op,halo,dtype", [(_gauss, 2, np.float32), (_median, 1, np.uint16)])
def test_slab_filter_equals_one_call(threads, rows, op, halo, dtype):
    rng = np.random.default_rng(rows * 10 + threads)
    image = rng.integers(0, 1024, (rows, 37)).astype(dtype)
    image[rows // 2, 5] = 1023  # a sharp feature on a cut, where slabs are repaired
    expected = np.zeros_like(image)
    op(image, expected)
    runner = SlabRunner(rows, 37, halo, threads, dtype)
    got = np.full_like(image, 7)
    runner.run(op, image, got)
    np.testing.assert_array_equal(got, expected)
    # too-short frames are not cut: every slab keeps 8 halos of rows
    assert runner.threads == (threads if rows >= 8 * halo * threads else 1)


def test_slab_rows_visits_every_row_once():
    runner = SlabRunner(50, 3, 0, 3, np.uint8)
    seen = np.zeros(50, int)

    def work(a, b):
        seen[a:b] += 1

    runner.rows(work)
    assert runner.threads == 3
    assert np.all(seen == 1)


def test_slab_errors_reach_the_caller():
    runner = SlabRunner(64, 8, 1, 2, np.float32)

    def broken(src, dst):
        raise ValueError("slab failed")

    with pytest.raises(ValueError, match="slab failed"):
        runner.run(broken, np.zeros((64, 8), np.float32), np.zeros((64, 8), np.float32))


def _wide_psf_frame(seed):
    """Faint stars of a 2.2 px PSF (peak SNR under 5): the PSF measured on 4 x 4 bins."""
    rng = np.random.default_rng(seed)
    shape = (500, 500)
    xs, ys = rng.uniform(30, 470, 40), rng.uniform(30, 470, 40)
    clean = dataclasses.replace(SimConfig(), hot_pixel_fraction=0.0, cosmic_ray_rate_cm2_s=0.0)
    return render_points(shape, xs, ys, np.full(40, 450.0), clean, rng,
                         noise_model="realistic", psf_sigma_px=2.2).image


@pytest.mark.parametrize("threads", [2, 3])
def test_the_frame_binned_in_slabs_gives_the_candidates_of_one_call(threads):
    """The 4 x 4 bins made in row slabs (each slab the blocks beginning in its rows, any
    cut) are those of one call, and so are the candidates; a detector of two threads
    measures a wide PSF on them as one of one thread does, star for star."""
    image = _wide_psf_frame(9)
    shape = image.shape
    layout = PaddedLayout(shape, 4)
    padded, inner = layout.buffer(np.uint16)
    inner[:] = image
    sky = float(np.median(image))
    spread = float(np.median(np.abs(image - sky))) / 0.6745
    level, noise = np.full((13, 13), sky, np.float32), np.full((13, 13), spread, np.float32)
    finders = [BinnedPeaks(layout, 512),
               BinnedPeaks(layout, 512, slabs=SlabRunner(shape[0], shape[1], 0, threads,
                                                         np.uint16))]
    counts = [f.find(padded, inner, level, noise, 4.0) for f in finders]
    assert counts[0] == counts[1] >= 20
    np.testing.assert_array_equal(finders[0].binned, finders[1].binned)
    for name in ("start", "brightest"):
        np.testing.assert_array_equal(getattr(finders[0], name), getattr(finders[1], name))
    results = []
    for n in (1, threads):
        cfg = dataclasses.replace(DetectConfig(method="default"), threads=n)
        result = make_detector(cfg, shape, 10).detect(image)
        results.append((result.stars.copy(), result.psf_sigma_px, result.psf_stars))
    assert results[0][1] == pytest.approx(2.2, rel=0.1) and results[0][2] >= 5
    np.testing.assert_array_equal(results[0][0], results[1][0])
    assert results[0][1:] == results[1][1:]


@pytest.mark.parametrize("threads", [2, 3])
def test_background_tiles_sampled_in_slabs_equal_one_call(threads):
    """The tiles' samples read and sorted in row slabs: the same level, noise and sorted
    samples as in one call, for an integer frame (its lattice and dither) and for a float
    frame less the sampled background."""
    rng = np.random.default_rng(threads)
    shape = (300, 230)
    layout = PaddedLayout(shape, 6)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    sky = 80.0 + 0.1 * xx + 0.05 * yy + rng.normal(0.0, 3.0, shape)
    sky[rng.integers(0, 300, 40), rng.integers(0, 230, 40)] += 500.0   # stars and hits
    frames = []
    for dtype in (np.uint16, np.float32):
        padded, inner = layout.buffer(dtype)
        inner[:] = np.rint(sky) if dtype == np.uint16 else sky
        frames.append(padded)
    minus_pad, minus = layout.buffer(np.float32)
    minus[:] = 80.0 + 0.1 * xx
    runner = SlabRunner(shape[0], shape[1], 0, threads, np.float32)
    assert runner.threads == threads
    grid = BackgroundGrid(layout, 32, 4, 64)
    for padded, minus_too in ((frames[0], False), (frames[1], True)):
        out = []
        for slabs in (None, runner):
            level, noise = np.zeros(grid.grid_shape, np.float32), np.zeros(grid.grid_shape,
                                                                           np.float32)
            grid.sample_minus(minus_pad)
            grid.stats(padded, level, noise, 0.3, upper=True, minus=minus_too, slabs=slabs)
            out.append((level, noise, grid.samples.copy(), grid.rounded.copy()))
        for one, slabbed in zip(*out, strict=True):
            np.testing.assert_array_equal(one, slabbed)


def test_uint16_input_clips_to_full_scale_and_rounds_floats():
    inp = FrameInput((2, 3), 10, min_size=1, dtype=np.uint16)
    assert inp.load(np.array([[-5.0, 0.4, 0.6], [511.5, 1023.0, 4000.0]])) is None
    np.testing.assert_array_equal(inp.work, [[0, 0, 1], [512, 1023, 1023]])
    assert inp.load(np.array([[0, 70000, 3], [4, 5, 6]], np.int64)) is None
    np.testing.assert_array_equal(inp.work, [[0, 1023, 3], [4, 5, 6]])
    assert inp.load(np.array([[0, 2000, 3], [4, 5, 6]], np.uint16)) is None
    np.testing.assert_array_equal(inp.work, [[0, 1023, 3], [4, 5, 6]])
    assert inp.load(np.array([[0, 200, 3], [4, 5, 6]], np.uint8)) is None
    np.testing.assert_array_equal(inp.work, [[0, 200, 3], [4, 5, 6]])


def test_threads_do_not_change_the_stars():
    """Slabs are exact, so one thread and four give identical star tables."""
    rng = np.random.default_rng(8)
    shape = (240, 320)
    xs, ys = rng.uniform(5, 315, 40), rng.uniform(5, 235, 40)
    image = render_points(shape, xs, ys, 10 ** rng.uniform(2.5, 4.5, 40), SimConfig(), rng,
                          noise_model="realistic").image
    image[rng.integers(0, 240, 30), rng.integers(0, 320, 30)] = 1023  # hot pixels
    results = []
    for threads in (1, 4):
        cfg = dataclasses.replace(DetectConfig(method="default"), threads=threads)
        results.append(make_detector(cfg, shape, 10).detect(image).stars.copy())
    assert len(results[0]) >= 30
    np.testing.assert_array_equal(results[0], results[1])


def test_making_a_detector_sets_opencvs_thread_count():
    """OpenCV's pool is off by default (the slabs are the parallelism), on when asked."""
    make_detector(dataclasses.replace(DetectConfig(), opencv_threads=0), (64, 64), 10)
    everything = cv2.getNumThreads()
    make_detector(DetectConfig(), (64, 64), 10)
    assert cv2.getNumThreads() == 1
    make_detector(dataclasses.replace(DetectConfig(), opencv_threads=3), (64, 64), 10)
    assert cv2.getNumThreads() == 3
    make_detector(DetectConfig(), (64, 64), 10)
    assert everything >= 1
