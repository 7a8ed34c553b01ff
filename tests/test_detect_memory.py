"""Fixed memory: the default detector's per-frame loop does not grow or make frame-sized arrays.

tracemalloc sees every numpy buffer. After warm-up the traced memory must
stay flat over 1,000 frames (growth below 64 KiB: not a leak of even one
256 x 256 float32 buffer, 256 KiB, nor of 64 bytes a frame), and
the per-frame peak above that baseline must stay below 512 KiB: numpy's
ufunc iteration buffers (8192 elements each) and sparse lists of a few
hundred pixels fit; one full-size float32 frame (1600 x 1300: 8.3 MB) does
not.
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from tracker.config import DetectConfig, SimConfig
from tracker.detect import make_detector
from tracker.sim import render_points

CFG = DetectConfig(method="default")
# What does stay behind is Python's and numpy's small-object reuse (blocks kept
# for the next allocation of their size, still traced), and how much depends on
# the order the calling thread and the worker free them, which the machine's
# load decides: 7-22 KiB over 1,000 small frames at loads 0-10.
GROWTH_LIMIT = 64 * 1024
PEAK_LIMIT = 512 * 1024


def _frames(shape, count, stars, rng):
    rows, cols = shape
    out = []
    for _ in range(count):
        xs = rng.uniform(2, cols - 3, stars)
        ys = rng.uniform(2, rows - 3, stars)
        electrons = 10 ** rng.uniform(2.0, 4.3, stars)
        out.append(render_points(shape, xs, ys, electrons, SimConfig(), rng,
                                 noise_model="realistic").image)
    return out


def _run(det, frames, n):
    """Traced growth and peak (bytes above the start) over n frames, after warm-up."""
    for image in frames:
        det.detect(image)
    tracemalloc.start()
    try:
        for image in frames:
            det.detect(image)
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        counts = 0
        for i in range(n):
            counts += det.detect(frames[i % len(frames)]).count
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return current - base, peak - base, counts


def test_thousand_small_frames_allocate_nothing_lasting():
    rng = np.random.default_rng(21)
    shape = (256, 256)
    frames = _frames(shape, 8, 30, rng)
    # a frame full of impulses takes the whole-frame path; bad frames take the early exits
    noisy = frames[0].copy()
    noisy.ravel()[rng.choice(noisy.size, noisy.size // 10, replace=False)] = 1023
    frames += [noisy, np.zeros(shape, np.uint16), np.full(shape, np.nan)]
    growth, peak, counts = _run(make_detector(CFG, shape, 10), frames, 1000)
    assert counts > 1000 * 8 // 11  # stars really were found along the way
    assert growth < GROWTH_LIMIT
    assert peak < PEAK_LIMIT


def test_full_size_frames_allocate_nothing_frame_sized():
    rng = np.random.default_rng(22)
    shape = (1300, 1600)
    frames = _frames(shape, 2, 150, rng)
    growth, peak, counts = _run(make_detector(CFG, shape, 10), frames, 6)
    assert counts > 6 * 50
    assert growth < GROWTH_LIMIT
    assert peak < PEAK_LIMIT


def test_multiplicative_centroid_leaves_nothing_behind():
    """detect.centroid_noise: multiplicative on speckle frames, 300 frames.

    Its likelihood fit works on temporaries of (stars x window pixels x 4)
    float64 per frame: they scale with the star count, never with the frame,
    and are gone when the frame is done.

    One thread: with a worker beside the calling thread, numpy's cache of small
    freed blocks (up to 7 of each size under 1 KiB, still traced as allocated)
    fills in the order the two threads free them, which the machine's load
    decides: at loads of 10-15 the growth was 11,803-18,588 bytes (over the
    16 KiB limit this file then had once in 9 runs; most of it numpy's cached
    cumulative sums and index lists from the pair sweeps), with one thread
    8,117-9,682 bytes.
    """
    rng = np.random.default_rng(23)
    shape = (256, 256)
    frames = []
    for _ in range(6):
        xs, ys = rng.uniform(4, 251, 30), rng.uniform(4, 251, 30)
        frames.append(render_points(shape, xs, ys, 10 ** rng.uniform(3.0, 4.5, 30), SimConfig(),
                                    rng, noise_model="speckle", bit_depth=8).image)
    det = make_detector(DetectConfig(method="default", centroid_noise="multiplicative",
                                     threads=1), shape, 8)
    growth, peak, counts = _run(det, frames, 150)
    candidates = max(det.detect(f).counters["candidates"] for f in frames)
    assert counts > 150 * 10
    assert growth < GROWTH_LIMIT
    # Its temporaries are about 20 KiB per candidate (81-pixel windows, a few
    # float64 arrays of 4 parameters), 0.6-0.8 MiB for these 30-35; a lasting
    # frame-sized buffer would show in the growth.
    assert peak < PEAK_LIMIT + candidates * 24 * 1024, (peak, candidates)
