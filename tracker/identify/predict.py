"""Where tracked stars will be in the next frame, how sure that is, and how far they smear.

Conventions: v_cam = R @ v_icrs; a small rotation theta (radians, camera
frame) of the attitude moves a direction to v + theta x v (R_true =
exp([theta]x) R_est, as tracker.attitude.attitude_covariance defines the
error); the body rate omega (rad/s, camera frame) moves directions as
dv_cam/dt = -omega x v_cam.

The predicted attitude at time t is exp([r dt]x) R_last, r the solver's
rate of R (= -omega), dt = t - t_last. Its error theta has covariance

    P(t) = P_last + P_r dt^2 + (a dt^2 / 2)^2 I

(P_last the last attitude's, P_r the rate's, a the angular acceleration
allowed, 1 sigma per axis). A star at normalised image coordinates
(u, w) = (X/Z, Y/Z) moves by J theta pixels with

    J = f [[-u w, 1 + u^2, -w], [-(1 + w^2), u w, u]]

(pinhole; distortion changes J by k1 rho^2, well below the slack in the
windows), so its position's covariance is J P J^T and its radial
1-sigma ``sqrt(trace)``. Over an exposure of T seconds it travels
``J (-omega) T`` pixels (the smear), centred on the mid-exposure position
the frame's time stamps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.camera import CameraModel

__all__ = ["TrackPrediction", "pixel_jacobian", "pinhole_travel", "spread_and_smear", "informative",
           "centroid_variance", "CENTROID_FLOOR_PX", "CENTROID_SPREAD_PX"]

# A star's centroid 1-sigma per axis, sigma^2 = FLOOR^2 + (SPREAD / snr)^2: the
# background-limited term of a Gaussian PSF's centroid is sqrt(2) s / SNR (s the
# pixel-integrated PSF sigma, about 1.25 px for the default 1.2 px optics), and a floor
# (pixel response, residual pixel-phase bias) holds for the brightest stars. Measured on
# tracked 3 deg/s slews (bench track --seed 101, 16 mm and 8 mm, 7,900 matched stars against
# the truth, both axes, centroid_variance's trail term): floor 0.062 px and SPREAD 1.94 s
# (s 1.15-1.25 px there), the floor 1/37 of SPREAD as here 1/35 (only the ratio weighs).
CENTROID_FLOOR_PX = 0.05
CENTROID_SPREAD_PX = 1.75

# J's entries (row-major) as pixel_jacobian's terms [u, w, u w, 1 + u^2, 1 + w^2] and signs
_J_TERMS = np.array([2, 3, 1, 4, 2, 0])
_J_SIGNS = np.array([-1.0, 1.0, -1.0, -1.0, 1.0, 1.0])


@dataclass(frozen=True)
class TrackPrediction:
    """Predicted image positions of the stars tracking follows, brightest first.

    ``xy`` (m, 2) px at mid-exposure; ``sigma_px`` (m,) radial 1-sigma of
    each; ``smear_px`` (m, 2) its travel over the exposure; ``catalogue``
    (m,) its catalogue index, -1 for an unidentified star followed.
    ``R`` the predicted attitude; ``dt_s`` the time since the last solution.
    """

    R: np.ndarray
    xy: np.ndarray
    sigma_px: np.ndarray
    smear_px: np.ndarray
    catalogue: np.ndarray
    dt_s: float


def pixel_jacobian(camera: CameraModel, cam_vectors: np.ndarray) -> np.ndarray:
    """(m, 2, 3): d(pixel) / d(theta) at camera-frame directions ``cam_vectors`` (m, 3).

    Its five distinct terms (u, w, u w, 1 + u^2, 1 + w^2) are computed once and
    placed into J's six entries, with f and their signs, by one gather and one
    product (a frame loop's cost is numpy's calls, not their arithmetic).
    """
    v = np.asarray(cam_vectors, dtype=np.float64)
    terms = np.empty((len(v), 5))
    np.divide(v[:, :2], v[:, 2:3], out=terms[:, :2])
    np.multiply(terms[:, 0], terms[:, 1], out=terms[:, 2])
    np.multiply(terms[:, :2], terms[:, :2], out=terms[:, 3:])
    terms[:, 3:] += 1.0
    return (terms.take(_J_TERMS, axis=1) * (camera.f_px * _J_SIGNS)).reshape(-1, 2, 3)


def pinhole_travel(camera: CameraModel, xy: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """(n, 2) px: how far image positions ``xy`` (n, 2) px move under the small rotation
    ``turn`` (rad, camera frame, as theta of the module docstring), through the pinhole.

    J theta written out on (u, w) = ((x - cx) / f, (y - cy) / f): with
    q = u t1 - w t0 it is f (t1 - w t2 + u q, -t0 + u t2 + w q), a few whole-array
    operations (a frame's cost here is numpy's calls: a third of building J).
    """
    t0, t1, t2 = np.asarray(turn, dtype=np.float64).tolist()
    uw = np.subtract(xy, camera.principal_point)
    uw /= camera.f_px
    q = uw @ np.array((t1, -t0))
    out = uw[:, ::-1] * np.array((-t2, t2))
    out += uw * q[:, None]
    out += (t1, -t0)
    out *= camera.f_px
    return out


def spread_and_smear(camera: CameraModel, cam_vectors: np.ndarray, P_theta: np.ndarray,
                     omega: np.ndarray, exposure_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(radial sigma (m,), smear (m, 2)) in px of stars at camera-frame directions
    ``cam_vectors`` (m, 3), the attitude's error covariance ``P_theta`` (3, 3, rad^2,
    module docstring), the body rate ``omega`` (rad/s, camera frame) and
    ``exposure_s`` the exposure time.

    sigma^2 = trace(J P J^T) = sum over J's rows of j P j^T, all stars in one
    product (np.einsum of three operands costs twice as much on a frame's stars).
    """
    J = pixel_jacobian(camera, cam_vectors)
    sigma = np.sqrt(np.maximum(np.add.reduce((np.matmul(J, P_theta) * J).reshape(-1, 6), axis=1),
                               0.0))
    smear = J @ (-np.asarray(omega, dtype=np.float64) * exposure_s)
    return sigma, smear


def centroid_variance(snr: np.ndarray, trail_px2: np.ndarray | None = None) -> np.ndarray:
    """A centroid's variance per axis, averaged over the two axes, px^2 (the
    solve's scalar weight is its inverse).

    ``snr`` (m,) the stars' SNR; ``trail_px2`` (m,) the squares of their
    travels over the exposure, px^2 (None: not trailed). Background-limited,
    a centroid's variance along an axis is 2 / SNR^2 times the light's second
    moment along it: s^2 across a trail, s^2 + L^2 / 12 along one of length L
    (a box of L convolved with the PSF), so the two axes' mean is
    FLOOR^2 + (SPREAD^2 + L^2 / 12) / SNR^2 with SPREAD = sqrt(2) s. On the
    slews above the errors along trails of 5.5 px (16 mm) were 1.5-1.8 times
    those across, against the 1.6 this gives.
    """
    snr2 = np.square(np.maximum(np.asarray(snr, float), 1e-6))
    if trail_px2 is None:
        return CENTROID_FLOOR_PX ** 2 + CENTROID_SPREAD_PX ** 2 / snr2
    return CENTROID_FLOOR_PX ** 2 + (CENTROID_SPREAD_PX ** 2
                                     + np.asarray(trail_px2, float) / 12.0) / snr2


def informative(xy: np.ndarray, snr: np.ndarray, centre: tuple[float, float],
                share: float) -> np.ndarray:
    """Indices (ascending) of the fewest stars that carry ``share`` of the attitude's information.

    ``xy`` (m, 2) px predicted positions, ``snr`` (m,) their predicted SNR;
    ``centre`` the boresight's pixel. Each star weighs w = 1 / sigma^2 of
    its centroid (:func:`centroid_variance`, untrailed); the
    cross-boresight information is sum w, roll's sum w rho^2 (rho its
    distance from ``centre``): roll is held by stars far out. The stars with
    the largest shares of each that add up to ``share`` of its total are
    taken, the union of both sets; the input's order is kept (brightest
    first when it was).
    """
    m = len(xy)
    if m == 0:
        return np.zeros(0, np.intp)
    w = 1.0 / centroid_variance(snr)
    rho2 = np.square(xy[:, 0] - centre[0]) + np.square(xy[:, 1] - centre[1])
    keep = np.zeros(m, bool)
    for info in (w, w * rho2):
        order = (-info).argsort(kind="stable")    # (the arrays' methods: numpy's wrappers
        total = info[order].cumsum()              # cost more than these calls' work)
        k = min(m, int(total.searchsorted(share * total[-1])) + 1)
        keep[order[:k]] = True
    return keep.nonzero()[0]
