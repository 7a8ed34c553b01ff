"""Attitude representation: quaternions, rotation matrices, RA/Dec/roll.

Convention (docs/conventions.md): the attitude is the rotation R with
``v_cam = R @ v_icrs``; its quaternion q = [w, x, y, z] is scalar first with
w >= 0. Reported with it are the boresight RA/Dec (ICRS) and the roll: the
angle of celestial north at the image centre relative to image up (toward
y = 0), positive counter-clockwise as displayed, in [0, 360) degrees
(tetra3's convention).

Angles are radians unless a name says ``_deg``.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "quat_from_matrix", "matrix_from_quat", "radec_to_vector", "vector_to_radec",
    "radec_roll_from_matrix", "matrix_from_radec_roll", "angle_between_rotations",
    "solve_wahba", "attitude_covariance", "rotation_vector", "matrix_from_rotation_vector",
    "attitude_error",
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
    # Python floats: a dozen scalar operations on numpy scalars cost ten times the work
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R, dtype=np.float64).tolist()
    tr = r00 + r11 + r22
    cands = (tr, r00, r11, r22)
    k = cands.index(max(cands))        # the first largest, as argmax
    # math.sqrt: the chosen radicand is at least 1 for any matrix (its term is the largest
    # of the four; a NaN on the diagonal makes the trace NaN, chosen first, and stays NaN)
    if k == 0:
        w = 0.5 * math.sqrt(1.0 + tr)
        q = [w, (r21 - r12) / (4 * w), (r02 - r20) / (4 * w), (r10 - r01) / (4 * w)]
    elif k == 1:
        x = 0.5 * math.sqrt(1.0 + r00 - r11 - r22)
        q = [(r21 - r12) / (4 * x), x, (r01 + r10) / (4 * x), (r02 + r20) / (4 * x)]
    elif k == 2:
        y = 0.5 * math.sqrt(1.0 - r00 + r11 - r22)
        q = [(r02 - r20) / (4 * y), (r01 + r10) / (4 * y), y, (r12 + r21) / (4 * y)]
    else:
        z = 0.5 * math.sqrt(1.0 - r00 - r11 + r22)
        q = [(r10 - r01) / (4 * z), (r02 + r20) / (4 * z), (r12 + r21) / (4 * z), z]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0:
        norm = -norm
    return np.array(q) / norm


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
    # Python floats (vector_to_radec's arithmetic on one vector): numpy's calls on scalars
    # cost more than their work
    (_, _, n0), (_, _, n1), (x, y, z) = np.asarray(R, dtype=np.float64).tolist()
    ra = math.atan2(y, x) % (2.0 * math.pi)      # the boresight, camera +Z, in ICRS
    dec = math.atan2(z, math.hypot(x, y))
    roll = math.atan2(-n0, -n1) % (2.0 * math.pi)   # ICRS +Z (the pole) in the camera frame
    return ra, dec, roll


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


# --------------------------------------------------------------------------
# Wahba's problem and its uncertainty
# --------------------------------------------------------------------------


def solve_wahba(obs: np.ndarray, ref: np.ndarray, weights: np.ndarray | None = None
                ) -> np.ndarray:
    """The rotation R minimising sum w_i |obs_i - R @ ref_i|^2 (Wahba 1965), by SVD.

    ``obs`` (n, 3) unit vectors in the camera frame, ``ref`` (n, 3) the same
    stars' ICRS unit vectors, ``weights`` (n,) non-negative (None = equal).
    Markley's SVD method (J. Astronaut. Sci. 36(3), 1988): with the attitude
    profile matrix B = sum w_i obs_i ref_i^T = U S V^T, the optimum is
    R = U diag(1, 1, det U det V) V^T. It was chosen over QUEST and ESOQ2 for
    its robustness: it needs no characteristic-polynomial root finding, stays
    exact for two stars or nearly collinear stars, and one 3x3 SVD costs a few
    microseconds, far below the rest of the per-frame work. At least two
    non-parallel vectors are needed for a unique answer.
    """
    obs = np.asarray(obs, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    B = (obs.T * weights) @ ref if weights is not None else obs.T @ ref
    U, _, Vt = np.linalg.svd(B)
    # det U det V^T (each +-1) from the triple products: np.linalg.det is a LAPACK LU,
    # whose threads can cost a millisecond from the frame loop on a busy machine
    U[:, 2] *= _det3(U) * _det3(Vt)
    return U @ Vt


def _det3(M: np.ndarray) -> float:
    """The determinant of a 3 x 3 matrix, its rows' triple product."""
    (a, b, c), (d, e, f), (g, h, i) = M.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def attitude_covariance(obs: np.ndarray, sigma: float | np.ndarray) -> np.ndarray:
    """Covariance (3x3, rad^2, camera frame) of the small-angle attitude error.

    The QUEST measurement model (Shuster and Oh 1981): each unit vector
    ``obs_i`` carries an isotropic error of ``sigma_i`` radians per axis
    perpendicular to it, giving P = [sum sigma_i^-2 (I - obs_i obs_i^T)]^-1.
    The error angle theta is defined by R_true = exp([theta]x) R_est, so
    theta[0], theta[1] tilt the boresight and theta[2] is roll about it.
    """
    obs = np.asarray(obs, dtype=np.float64)
    inv_var = 1.0 / np.square(sigma)
    total = inv_var * len(obs) if np.ndim(inv_var) == 0 else np.sum(inv_var)
    # F = I total - G, G = sum obs_i obs_i^T / sigma_i^2, is symmetric: its inverse by
    # cofactors over the determinant (a LAPACK call from the frame loop can cost a
    # millisecond on a busy machine), its entries in Python floats (the same numbers as
    # I total - G in numpy for a finite total: 0 - G_ij is -G_ij)
    (g_xx, g_xy, g_xz), (_, g_yy, g_yz), (_, _, g_zz) = ((obs.T * inv_var) @ obs).tolist()
    total = float(total)
    xx, xy, xz, yy, yz, zz = total - g_xx, -g_xy, -g_xz, total - g_yy, -g_yz, total - g_zz
    c_xx, c_xy, c_xz = yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy
    c_yy, c_yz, c_zz = xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy
    det = xx * c_xx + xy * c_xy + xz * c_xz
    return np.array([[c_xx, c_xy, c_xz], [c_xy, c_yy, c_yz], [c_xz, c_yz, c_zz]]) / det


def rotation_vector(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis times angle, radians) of the rotation matrix R."""
    w, x, y, z = quat_from_matrix(R).tolist()
    s = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    return np.array((x * scale, y * scale, z * scale))


def matrix_from_rotation_vector(theta: np.ndarray) -> np.ndarray:
    """Rotation matrix exp([theta]x) of a rotation vector (radians), Rodrigues' formula."""
    # in Python floats: a 3-vector's nine numpy calls cost more than its arithmetic
    # (tracking calls it every frame); K K = theta theta^T - angle^2 I
    x, y, z = np.asarray(theta, dtype=np.float64).tolist()
    angle2 = x * x + y * y + z * z
    angle = math.sqrt(angle2)
    if angle < 1e-12:
        a, b = 1.0, 0.0
    else:
        a, b = math.sin(angle) / angle, (1.0 - math.cos(angle)) / angle2
    c = 1.0 - b * angle2
    return np.array([[c + b * x * x, b * x * y - a * z, b * x * z + a * y],
                     [b * x * y + a * z, c + b * y * y, b * y * z - a * x],
                     [b * x * z - a * y, b * y * z + a * x, c + b * z * z]])


def attitude_error(R_est: np.ndarray, R_true: np.ndarray) -> tuple[float, float]:
    """Cross-boresight and roll error (radians) of R_est against R_true.

    Cross-boresight is the angle between the two boresights (camera +Z in
    ICRS); roll is the signed rotation about the boresight, the z component
    of the rotation vector of R_true @ R_est^T (camera frame).
    """
    a, b = np.asarray(R_est)[2], np.asarray(R_true)[2]
    cross = float(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b)))
    return cross, float(rotation_vector(np.asarray(R_true) @ np.asarray(R_est).T)[2])
