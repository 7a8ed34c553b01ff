"""The background grid's tile sums (tracker.detect.background): its level, noise and count
above the level agree with numpy's plain reductions of the same sorted samples; a
second pass for the dark side reusing the sorted samples gives what a full one does."""

from __future__ import annotations

import numpy as np

from tracker.detect.background import BackgroundGrid
from tracker.detect.layout import PaddedLayout


def test_tile_sums_agree_with_plain_reductions():
    rng = np.random.default_rng(21)
    layout = PaddedLayout((300, 400), 8)
    grid = BackgroundGrid(layout, 32, 4, 64)
    padded, work = layout.buffer(np.uint16)
    work[:] = np.clip(rng.normal(40.0, 3.0, work.shape) + np.linspace(0.0, 30.0, 400), 0, 1023)
    level = np.zeros(grid.grid_shape, np.float32)
    noise = np.zeros(grid.grid_shape, np.float32)
    grid.stats(padded, level, noise, 0.29, upper=True)
    m = grid.samples.shape[-1]
    rounded = np.sort(grid.rounded.astype(np.float64), axis=-1)
    expected_level = rounded[..., m // 4: m - m // 4].mean(axis=-1)
    np.testing.assert_allclose(grid.level_raw, expected_level, rtol=1e-6)
    np.testing.assert_array_equal(grid.above, np.sum(rounded > grid.level_raw[..., None], -1))
    # a float frame less an image read at the samples (the filtered frame's statistics)
    floats_pad, floats = layout.buffer(np.float32)
    floats[:] = work * np.float32(1.37)
    minus_pad, minus = layout.buffer(np.float32)
    minus[:] = np.float32(0.5) * work
    grid.sample_minus(minus_pad)
    grid.stats(floats_pad, level, noise, 0.29, upper=True, minus=True)
    samples = np.sort(grid.samples.astype(np.float64), axis=-1)
    np.testing.assert_allclose(grid.level_raw, samples[..., m // 4: m - m // 4].mean(axis=-1),
                               rtol=1e-6)


def test_a_second_pass_for_the_dark_side_reusing_the_sorted_samples_is_a_full_pass():
    """stats(..., resample=False), for the tiles across a body's edge, gives bit for bit
    what a pass reading and sorting the same frame's samples again gives."""
    rng = np.random.default_rng(22)
    layout = PaddedLayout((300, 400), 8)
    padded, work = layout.buffer(np.uint16)
    work[:] = np.clip(rng.normal(40.0, 3.0, work.shape), 0, 1023)
    work[216:] += 600                                   # lit ground below row 216
    dark_side = np.zeros((9, 12), bool)
    dark_side[6, :] = True                              # the tiles across its edge
    sky_split = np.zeros_like(dark_side)
    sky_split[6, :4] = True
    results = []
    for resample in (True, False):
        grid = BackgroundGrid(layout, 32, 4, 64)
        level = np.zeros(grid.grid_shape, np.float32)
        noise = np.zeros(grid.grid_shape, np.float32)
        grid.stats(padded, level, noise, 0.29, upper=True)
        grid.stats(padded, level, noise, 0.29, upper=True, dark_side=dark_side,
                   sky_split=sky_split, resample=resample)
        results.append((level, noise, grid.level_raw.copy(), grid.above.copy(),
                        grid.skewness()))
    for full, reused in zip(*results, strict=True):
        np.testing.assert_array_equal(full, reused)
