"""Attitude representation: quaternions, rotation matrices, RA/Dec/roll.

Convention (DESIGN.md): the attitude is the rotation R with
``v_cam = R @ v_icrs``; its quaternion q = [w, x, y, z] is scalar first with
w >= 0. Reported with it are the boresight RA/Dec (ICRS) and the roll: the
angle of celestial north at the image centre relative to image up (toward
y = 0), positive counter-clockwise as displayed, in [0, 360) degrees
(tetra3's convention).

Angles are radians unless a name says ``_deg``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "quat_from_matrix", "matrix_from_quat", "radec_to_vector", "vector_to_radec",
    "radec_roll_from_matrix", "matrix_from_radec_roll", "angle_between_rotations",
]


def radec_to_vector(ra: np.ndarray, dec: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3) in ICRS for right ascension and declination (radians)."""
    ra = np.asarray(ra, dtype=np.float64)
    dec = np.asarray(dec, dtype=np.float64)
    cd = np.cos(dec)
    return np.stack([cd * np.cos(ra), cd * np.sin(ra), np.sin(dec)], axis=-1)


def vector_to_radec(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RA in [0, 2 pi) and Dec in [-pi/2, pi/2] (radians) of vectors (..., 3)."""
    v = np.asarray(v, dtype=np.float64)
    ra = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2 * np.pi)
    dec = np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))
    return ra, dec


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion [w, x, y, z] with w >= 0 of the rotation matrix R.

    Uses the numerically stable branch on the largest diagonal term
    (Shepperd's method).
    """
    R = np.asarray(R, dtype=np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    cands = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax(cands))
    if k == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
             (R[1, 0] - R[0, 1]) / (4 * w)]
    elif k == 1:
        x = 0.5 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / (4 * x), x, (R[0, 1] + R[1, 0]) / (4 * x),
             (R[0, 2] + R[2, 0]) / (4 * x)]
    elif k == 2:
        y = 0.5 * np.sqrt(1.0 - R[0, 0] + R[1, 1] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / (4 * y), (R[0, 1] + R[1, 0]) / (4 * y), y,
             (R[1, 2] + R[2, 1]) / (4 * y)]
    else:
        z = 0.5 * np.sqrt(1.0 - R[0, 0] - R[1, 1] + R[2, 2])
        q = [(R[1, 0] - R[0, 1]) / (4 * z), (R[0, 2] + R[2, 0]) / (4 * z),
             (R[1, 2] + R[2, 1]) / (4 * z), z]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of the unit quaternion q = [w, x, y, z]."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def radec_roll_from_matrix(R: np.ndarray) -> tuple[float, float, float]:
    """Boresight RA, Dec and roll (radians; roll in [0, 2 pi)) of v_cam = R @ v_icrs.

    Roll is measured at the boresight (+Z). For a camera with its principal
    point at the image centre that is the image centre of the convention.
    """
    R = np.asarray(R, dtype=np.float64)
    boresight = R[2]  # the camera +Z axis expressed in ICRS
    ra, dec = vector_to_radec(boresight)
    north_cam = R[:, 2]  # ICRS +Z (celestial pole) in the camera frame
    roll = np.mod(np.arctan2(-north_cam[0], -north_cam[1]), 2 * np.pi)
    return float(ra), float(dec), float(roll)


def matrix_from_radec_roll(ra: float, dec: float, roll: float) -> np.ndarray:
    """The rotation v_cam = R @ v_icrs whose boresight and roll are given (radians)."""
    z = radec_to_vector(ra, dec)
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.cross(z, east)
    # Image up (-Y) is north rotated clockwise by roll about the boresight, as seen
    # on the sky; image left (-X) completes the frame.
    up = np.cos(roll) * north - np.sin(roll) * east
    y_axis = -up
    x_axis = np.cross(y_axis, z)
    return np.vstack([x_axis, y_axis, z])


def angle_between_rotations(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle (radians) of the rotation taking Ra to Rb."""
    D = np.asarray(Ra) @ np.asarray(Rb).T
    # atan2 of the antisymmetric and symmetric parts: accurate for tiny angles,
    # where arccos of the trace alone loses half the digits.
    sin = 0.5 * np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
    cos = (np.trace(D) - 1.0) / 2.0
    return float(np.arctan2(sin, cos))
