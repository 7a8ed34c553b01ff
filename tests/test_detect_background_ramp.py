"""The background grid on a ramp (tracker.detect.background): its 3x3 median reads the
border's tiles extended by linear extrapolation, so a corner tile keeps the ramp's level,
and star-free noise under glare rising toward a corner gives the false-alarm budget's
count of detections there, not one nearly every frame (issue 12)."""

from __future__ import annotations

import dataclasses

import numpy as np

from tracker.config import Config
from tracker.detect import make_detector
from tracker.detect.background import BackgroundGrid
from tracker.detect.layout import PaddedLayout


def test_a_ramps_corner_tiles_keep_its_level():
    """A noiseless ramp rising 0.25 ADU/px along both axes on 32 px tiles: every tile's
    smoothed level is its raw level (a linear grid is its own 3x3 median once the
    border is extrapolated); the corners' medians of repeated tiles were 8 ADU (a
    tile's step) off, toward the frame's inside."""
    layout = PaddedLayout((256, 256), 8)
    grid = BackgroundGrid(layout, 32, 4, 64)
    padded, work = layout.buffer(np.uint16)
    yy, xx = np.mgrid[0:256, 0:256]
    work[:] = np.rint(40.0 + 0.25 * (xx + yy))
    level = np.zeros(grid.grid_shape, np.float32)
    noise = np.zeros(grid.grid_shape, np.float32)
    grid.stats(padded, level, noise, 0.29)
    np.testing.assert_allclose(level, grid.level_raw, rtol=0, atol=1e-3)


def test_noise_under_glare_rising_to_a_corner_is_no_star():
    """Star-free Gaussian noise (3 ADU) on a ramp of 60 ADU across the diagonal of a
    256 x 256 10-bit frame: on 200 frames the budget (0.1 a frame) allows about 20
    detections anywhere, an 8 px corner square's share of them 0.02; 3 came, none
    there (seed 31). With the bright corner tile's level a tile's step low, 56 came,
    51 of them there."""
    cfg = Config()
    det = make_detector(dataclasses.replace(cfg.detect, method="default"), (256, 256), 10)
    rng = np.random.default_rng(31)
    yy, xx = np.mgrid[0:256, 0:256]
    ramp = 40.0 + 60.0 * (xx + yy) / 256.0
    corner = total = 0
    for _ in range(200):
        frame = np.clip(np.rint(ramp + rng.normal(0.0, 3.0, ramp.shape)), 0, 1023)
        stars = det.detect(frame.astype(np.uint16)).stars
        total += len(stars)
        corner += int(np.count_nonzero((stars["x"] > 247.5) & (stars["y"] > 247.5)))
    assert total <= 20
    assert corner <= 1


def test_an_image_over_a_base_is_capped_at_a_marked_tiles_own_value():
    """BackgroundGrid.cap_over_in_tiles: in the marked tiles an image stands at most the
    tile's grid value over the base (a ramp here), in place; elsewhere it is untouched."""
    layout = PaddedLayout((128, 160), 8)
    grid = BackgroundGrid(layout, 32, 4, 64)
    yy, xx = np.mgrid[0:128, 0:160].astype(np.float32)
    base = 10.0 + 0.5 * xx
    _, dst = layout.buffer(np.float32)
    dst[:] = base + 0.1 * yy                      # 0 to 12.7 over the base
    before = dst.copy()
    values = np.full(grid.grid_shape, 5.0, np.float32)
    marked = np.zeros(grid.grid_shape, bool)
    marked[1, 2] = marked[3, 0] = True
    grid.cap_over_in_tiles(values, dst, base, marked)
    tile = marked[np.minimum(yy // 32, 3).astype(int), np.minimum(xx // 32, 4).astype(int)]
    np.testing.assert_array_equal(dst[~tile], before[~tile])
    np.testing.assert_allclose(dst[tile], np.minimum(before[tile], base[tile] + 5.0), atol=1e-5)
    assert np.any(dst[tile] < before[tile])


def test_a_tiles_noise_on_glare_rising_across_it_is_the_noise_not_the_rise():
    """Gaussian noise of 20 ADU on glare rising 5 ADU/px along x and 2.5 along y (10 x 10
    tiles of 32 px): the tiles' median noise is within 10 % of 20 ADU and every tile's,
    the border's too (the ramp extended), within 30 % (64 samples a tile, the largest of
    three estimates, then the 3x3 median: the same without the rise). Measured about
    each tile's constant level it was the rise across the tile, 58-81 ADU (issue 12:
    impulses and noise peaks on glare then passed tests of that noise)."""
    layout = PaddedLayout((320, 320), 8)
    grid = BackgroundGrid(layout, 32, 4, 64)
    padded, work = layout.buffer(np.uint16)
    yy, xx = np.mgrid[0:320, 0:320]
    rng = np.random.default_rng(1)
    noise_only = rng.normal(0.0, 20.0, (320, 320))
    level = np.zeros(grid.grid_shape, np.float32)
    noise = np.zeros(grid.grid_shape, np.float32)
    for rise in (0.0, 5.0):
        work[:] = np.rint(100.0 + rise * (xx + 0.5 * yy) + noise_only)
        grid.stats(padded, level, noise, 0.29, upper=True)
        assert abs(np.median(noise) / 20.0 - 1.0) < 0.1, rise
        assert np.all(np.abs(noise / 20.0 - 1.0) < 0.3), rise
