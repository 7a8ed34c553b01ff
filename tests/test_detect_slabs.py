"""Slab-parallel filters equal one whole-frame call, pixel for pixel; uint16 input is exact."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from tracker.config import DetectConfig, SimConfig
from tracker.detect import make_detector
from tracker.detect.frame_input import FrameInput
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
