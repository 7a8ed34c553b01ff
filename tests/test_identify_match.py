"""match_nearest: the sorted-window search gives what an all-pairs search gives, and its
all-pairs path for small inputs (a windowed frame's) the very same pairs."""

import numpy as np
import pytest

from tracker.identify import verify
from tracker.identify.verify import match_nearest


def brute_force(xy, pred, radius):
    """All pairs: each star's nearest prediction, conflicts to the nearest claim."""
    d = np.hypot(xy[:, None, 0] - pred[None, :, 0], xy[:, None, 1] - pred[None, :, 1])
    best = np.argmin(d, axis=1)
    bd = d[np.arange(len(xy)), best]
    idx = np.where(bd <= radius, best, -1)
    for p in set(idx[idx >= 0]):
        claims = np.flatnonzero(idx == p)
        if len(claims) > 1:
            keep = claims[np.argmin(bd[claims])]
            idx[claims[claims != keep]] = -1
    return idx, np.where(idx >= 0, bd, np.inf)


@pytest.mark.parametrize("seed", range(20))
@pytest.mark.parametrize("radius", [1.5, 12.0, 80.0])
def test_same_pairs_as_all_pairs(seed, radius):
    rng = np.random.default_rng(seed)
    pred = rng.uniform(0, 400, size=(rng.integers(1, 300), 2))
    # half the stars near a prediction, half anywhere; some exact duplicates
    near = pred[rng.integers(0, len(pred), 60)] + rng.normal(0, radius / 2, (60, 2))
    xy = np.vstack([near, rng.uniform(0, 400, size=(60, 2)), pred[:3]])
    idx, dist = match_nearest(xy, pred, radius)
    want_idx, want_dist = brute_force(xy, pred, radius)
    # ties at equal distance may pick either prediction; distances must agree
    np.testing.assert_allclose(dist, want_dist, rtol=0, atol=1e-12)
    assert np.array_equal(idx >= 0, want_idx >= 0)
    ok = idx >= 0
    assert len(set(idx[ok])) == ok.sum()   # no prediction used twice


def test_empty_inputs():
    idx, dist = match_nearest(np.zeros((0, 2)), np.zeros((5, 2)), 2.0)
    assert idx.shape == (0,)
    idx, dist = match_nearest(np.zeros((3, 2)), np.zeros((0, 2)), 2.0)
    assert (idx == -1).all() and np.isinf(dist).all()


@pytest.mark.parametrize("seed", range(10))
def test_small_inputs_pair_as_the_sorted_search_does(seed, monkeypatch):
    """Below _DENSE_PAIRS all pairs are compared: the same indices and distances as the
    sorted-window search, ties at equal distance (whole-pixel positions, a prediction
    given twice) and NaN included."""
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(200):
        n, m = rng.integers(1, 60, 2)
        span = rng.choice([30.0, 300.0])
        xy, pred = rng.uniform(0, span, (n, 2)), rng.uniform(0, span, (m, 2))
        xy[: n // 2], pred[: m // 2] = np.round(xy[: n // 2]), np.round(pred[: m // 2])
        if m > 1:
            pred[1] = pred[0]
            xy[0] = pred[0]
        xy[-1, 0] = np.nan
        cases.append((xy, pred, rng.uniform(0.5, 15.0)))
    dense = [match_nearest(*case) for case in cases]
    assert all(len(c[0]) * len(c[1]) <= verify._DENSE_PAIRS for c in cases)
    monkeypatch.setattr(verify, "_DENSE_PAIRS", 0)
    for (xy, pred, radius), (idx, dist) in zip(cases, dense, strict=True):
        want_idx, want_dist = match_nearest(xy, pred, radius)
        assert np.array_equal(idx, want_idx)
        assert np.array_equal(dist, want_dist)
