"""The minimum-error split of a tile's samples into sky and body (tracker.detect.sky_split)."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.detect.sky_split import sky_class_size, sky_part


@pytest.mark.parametrize("ground_share", [0.05, 0.3, 0.6, 0.75])
def test_the_split_counts_the_sky_beside_ground_of_any_share(ground_share):
    """64 samples: Gaussian sky (noise 3 ADU) and textured ground 60-300 noises brighter,
    uniform; 500 tiles per share. The darker class is the sky's samples, exactly in 97 % or more
    of the tiles and to within one sample in all (an outlying sky sample, or ground
    as dark as the sky's top, may go either way). With only 6 sky samples (ground 90 %)
    the split is weaker: 487 of 500 exact, one cut inside the ground."""
    rng = np.random.default_rng(7)
    m, ground = 64, int(round(ground_share * 64))
    samples = rng.normal(20.0, 3.0, (500, m))
    samples[:, :ground] = rng.uniform(200.0, 900.0, (500, ground))
    samples.sort(axis=1)
    size = sky_class_size(samples)
    assert np.mean(size == m - ground) >= 0.97
    assert np.all(np.abs(size - (m - ground)) <= 1)


def test_saturated_ground_with_no_spread_leaves_the_sky_its_own_class():
    """Ground clipped at full scale (every sample 1023) over 70 % of a tile: the sky's
    class is its 19 samples (in 97 % or more of 400 tiles), and their level and noise
    are the sky's (20, 3 ADU) to within the scatter of so few samples."""
    rng = np.random.default_rng(8)
    samples = np.sort(np.concatenate([rng.normal(20.0, 3.0, (400, 19)),
                                      np.full((400, 45), 1023.0)], axis=1), axis=1)
    size = sky_class_size(samples)
    assert np.mean(size == 19) >= 0.97
    level, noise = sky_part(samples, samples, size)
    # the darker part's mean sits 0.7 noise below the sky's mean (its 6th-37th percentiles)
    assert abs(np.median(level) - (20.0 - 0.7 * 3.0)) < 0.5
    assert abs(np.median(noise) - 3.0) < 0.5


def test_fewer_than_four_samples_are_all_sky():
    assert np.all(sky_class_size(np.sort(np.arange(6.0).reshape(2, 3))) == 3)
