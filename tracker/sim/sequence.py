"""Attitudes for simulation: uniform random draws and constant-rate slews.

Rates are body rates: omega (rad/s) about the camera's own x, y, z axes.
An inertial direction then moves in the camera frame as
dv_cam/dt = -omega x v_cam, so the attitude (v_cam = R @ v_icrs) after a
time t is ``rotation(-omega * t) @ R``.
"""

from __future__ import annotations

import numpy as np

from tracker.attitude import matrix_from_quat

__all__ = ["random_attitude", "rotation_vector_matrix", "attitude_at"]


def random_attitude(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix drawn uniformly on SO(3) (normalised 4-D Gaussian quaternion)."""
    q = rng.normal(size=4)
    while np.linalg.norm(q) < 1e-9:
        q = rng.normal(size=4)
    return matrix_from_quat(q)


def rotation_vector_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, radians), Rodrigues' formula."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = float(np.linalg.norm(rotvec))
    if angle == 0.0:
        return np.eye(3)
    k = rotvec / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * (cross @ cross)


def attitude_at(R: np.ndarray, rate_rad_s: np.ndarray | None, dt_s: float) -> np.ndarray:
    """Attitude ``dt_s`` seconds after ``R`` under the constant body rate ``rate_rad_s``."""
    if rate_rad_s is None:
        return np.asarray(R, dtype=np.float64)
    return rotation_vector_matrix(-np.asarray(rate_rad_s, dtype=np.float64) * dt_s) @ R
