"""Bad input gives no attitude and a reason code, never an exception."""

import json

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.config import ConfigError, IdentifyConfig
from tracker.detect import STAR_DTYPE, StarFlag
from tracker.identify import DatabaseError, make_solver
from tracker.identify.database import PatternDatabase


@pytest.fixture(scope="module")
def solver():
    return make_solver(IdentifyConfig(), camera(16.0), catalogue())


def _stars(xy, flux=None):
    s = np.zeros(len(xy), dtype=STAR_DTYPE)
    if len(xy):
        s["x"], s["y"] = np.asarray(xy, dtype=float).T
        s["flux"] = 1000.0 if flux is None else flux
    return s


def _check_failed(sol, reason):
    assert not sol.ok
    assert sol.reason == reason
    assert sol.R is None and sol.to_json() is None
    assert np.all(sol.hip == 0)


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_stars(solver, n):
    _check_failed(solver.solve(_stars([[100.0 + 50 * i, 200.0] for i in range(n)]), 0),
                  "too_few_stars")


def test_nan_and_infinite_centroids_are_ignored(solver):
    rng = np.random.default_rng(21)
    R = random_rotation(rng)
    stars, truth = synthetic_stars(camera(16.0), R, rng)
    stars["x"][::7] = np.nan
    stars["flux"][1] = np.inf
    solver.reset()
    sol = solver.solve(stars, 0)
    assert sol.ok
    assert sol.hip[0] == truth[0] or sol.hip[0] == 0
    assert np.all(sol.hip[::7] == 0)
    assert sol.hip[1] == 0
    _check_failed(solver.solve(_stars([[np.nan, 1.0]] * 5), 0), "too_few_stars")


def test_duplicated_centroids_count_once(solver):
    """The same three stars given five times each are still three stars."""
    _check_failed(solver.solve(_stars([[100.0, 100.0], [400.0, 300.0], [800.0, 900.0]] * 5),
                               0), "too_few_stars")
    rng = np.random.default_rng(22)
    stars, _ = synthetic_stars(camera(16.0), random_rotation(rng), rng)
    doubled = np.concatenate([stars, stars])
    solver.reset()
    sol = solver.solve(doubled, 0)
    assert sol.ok
    assert sol.matched == np.count_nonzero(sol.hip[:len(stars)])
    assert np.all(sol.hip[len(stars):] == 0)


def test_only_false_stars_give_no_attitude(solver):
    """Random points: no false solve in 30 frames of 8-40 points (the model allows 1e-6)."""
    rng = np.random.default_rng(23)
    for i in range(30):
        n = 8 + i
        sol = solver.solve(_stars(rng.uniform([0, 0], [1599, 1299], size=(n, 2)),
                                  rng.uniform(100, 5000, n)), 0)
        assert not sol.ok
        assert sol.reason in ("no_match", "not_verified", "budget")


def test_input_without_coordinates_is_bad_input(solver):
    _check_failed(solver.solve(np.zeros(5, dtype=[("a", float)]), 0), "bad_input")
    _check_failed(solver.solve([1, 2, 3], 0), "bad_input")


def test_database_for_another_field_of_view_gives_wrong_fov():
    """A database named in the configuration that does not serve the camera."""
    db8 = make_solver(IdentifyConfig(), camera(8.0), catalogue()).bound.path
    solver = make_solver(IdentifyConfig(database=db8), camera(16.0), catalogue())
    rng = np.random.default_rng(24)
    stars, _ = synthetic_stars(camera(16.0), random_rotation(rng), rng)
    _check_failed(solver.solve(stars, 0), "wrong_fov")
    assert "built for fields" in solver.fov_error


def test_a_field_outside_the_supported_range_is_a_config_error():
    with pytest.raises(DatabaseError, match=r"a 1\.4 deg field is outside the 3-80 deg"):
        make_solver(IdentifyConfig(), camera(200.0), catalogue())
    assert issubclass(DatabaseError, ConfigError)


def test_corrupted_database_is_refused(tmp_path):
    src = make_solver(IdentifyConfig(), camera(8.0), catalogue()).bound.path
    with np.load(src) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["patterns"] = arrays["patterns"].copy()
    arrays["patterns"][0, 0] ^= 1
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    with pytest.raises(DatabaseError, match="SHA-256 of the arrays does not match"):
        PatternDatabase.load(bad)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(DatabaseError, match="not a readable pattern database"):
        PatternDatabase.load(tmp_path / "junk.npz")
    with pytest.raises(DatabaseError, match="pattern database not found"):
        PatternDatabase.load(tmp_path / "missing.npz")
    meta = json.loads(str(arrays["meta"]))
    meta["format_version"] = 1
    np.savez(bad, **{**arrays, "meta": np.array(json.dumps(meta))})
    with pytest.raises(DatabaseError, match="format version 1, expected 2; rebuild it"):
        PatternDatabase.load(bad)


def test_extended_sources_are_not_identified(solver):
    """Detector-flagged EXTENDED sources (nebulae, comets) take no HIP number."""
    rng = np.random.default_rng(23)
    R = random_rotation(rng)
    stars, _ = synthetic_stars(camera(16.0), R, rng)
    stars["flags"][:3] = StarFlag.EXTENDED        # the three brightest, say
    solver.reset()
    sol = solver.solve(stars, 0)
    assert sol.ok and np.all(sol.hip[:3] == 0) and np.count_nonzero(sol.hip[3:]) >= 5
    stars["flags"][:] = StarFlag.EXTENDED
    solver.reset()
    _check_failed(solver.solve(stars, 0), "too_few_stars")
