"""Wahba solver, its covariance and the rotation helpers (tracker.attitude)."""

import math

import numpy as np
import pytest

from tracker.attitude import (
    attitude_covariance,
    attitude_error,
    matrix_from_quat,
    matrix_from_radec_roll,
    matrix_from_rotation_vector,
    rotation_vector,
    solve_wahba,
)

ARCSEC = math.radians(1 / 3600)


def _rotation(rng):
    q = rng.normal(size=4)
    return matrix_from_quat(q / np.linalg.norm(q))


def _field(rng, n, half_width=0.15):
    """n unit vectors within a cone around +Z (a star tracker's field)."""
    xy = rng.uniform(-half_width, half_width, size=(n, 2))
    v = np.column_stack([xy, np.ones(n)])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_noise_free_vectors_give_the_exact_rotation():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = _rotation(rng)
        obs = _field(rng, 5)
        ref = obs @ R          # ref = R^T obs, so obs = R ref
        assert np.allclose(solve_wahba(obs, ref), R, atol=1e-12)


def test_two_stars_suffice_and_weights_are_used():
    rng = np.random.default_rng(2)
    R = _rotation(rng)
    obs = _field(rng, 3)
    ref = obs @ R
    assert np.allclose(solve_wahba(obs[:2], ref[:2]), R, atol=1e-12)
    # a wild third star with zero weight changes nothing
    bad = ref.copy()
    bad[2] = _field(rng, 1)[0]
    assert np.allclose(solve_wahba(obs, bad, np.array([1.0, 1.0, 0.0])), R, atol=1e-12)


def test_result_is_a_proper_rotation_even_for_a_mirrored_field():
    rng = np.random.default_rng(3)
    obs = _field(rng, 6)
    ref = obs * np.array([-1.0, 1.0, 1.0])   # a reflection: no rotation fits exactly
    R = solve_wahba(obs, ref)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_covariance_matches_monte_carlo_scatter():
    """Observed errors agree with the QUEST covariance within Monte-Carlo noise (10 %)."""
    rng = np.random.default_rng(4)
    sigma = 5 * ARCSEC
    obs0 = _field(rng, 12)
    R = _rotation(rng)
    ref = obs0 @ R
    errs = []
    for _ in range(2000):
        noise = rng.normal(scale=sigma, size=obs0.shape)
        obs = obs0 + noise - np.sum(noise * obs0, axis=1, keepdims=True) * obs0
        obs /= np.linalg.norm(obs, axis=1, keepdims=True)
        errs.append(rotation_vector(R @ solve_wahba(obs, ref).T))
    errs = np.array(errs)
    P = attitude_covariance(obs0, sigma)
    # 2000 samples: relative standard error of a variance is sqrt(2/2000) = 3 %
    assert np.var(errs[:, 2]) == pytest.approx(P[2, 2], rel=0.1)
    assert np.var(errs[:, 0]) + np.var(errs[:, 1]) == pytest.approx(P[0, 0] + P[1, 1], rel=0.1)
    # roll is far less certain than tilt for a narrow field
    assert P[2, 2] > 10 * P[0, 0]


def test_rotation_vector_round_trip_and_small_angles():
    rng = np.random.default_rng(5)
    for angle in (1e-9, 1e-3, 1.0, 3.0):
        axis = rng.normal(size=3)
        theta = axis / np.linalg.norm(axis) * angle
        R = matrix_from_rotation_vector(theta)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.allclose(rotation_vector(R), theta, atol=1e-12)


def test_attitude_error_separates_tilt_and_roll():
    R = matrix_from_radec_roll(1.0, 0.5, 0.3)
    roll_only = matrix_from_rotation_vector([0.0, 0.0, 20 * ARCSEC]) @ R
    cross, roll = attitude_error(roll_only, R)
    assert cross == pytest.approx(0.0, abs=1e-12)
    assert roll == pytest.approx(-20 * ARCSEC, rel=1e-9)
    tilt = matrix_from_rotation_vector([3 * ARCSEC, 4 * ARCSEC, 0.0]) @ R
    cross, roll = attitude_error(tilt, R)
    assert cross == pytest.approx(5 * ARCSEC, rel=1e-6)
    assert roll == pytest.approx(0.0, abs=1e-12)
