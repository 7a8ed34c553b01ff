"""Focal length and radial distortion from identified stars: per frame, and a slow filter.

**Per frame** (:func:`fit_frame`): the attitude (a small rotation theta
about the starting R, as ``R = exp([theta]x) R0``), the focal length f (px)
and the r^2 distortion k1 (tracker.camera's model; k2 and the principal
point stay as configured) minimise the pixel residuals of the matched
stars plus Gaussian priors on f and k1 (Gauss-Newton with the analytic
Jacobian; it converges in 2-4 steps from a pattern's estimate). Residuals
are weighted by the centroid variance sigma^2, re-estimated at every step
from the fit's own residuals blended with a prior (``centroid_sigma_px`` with 3 degrees of
freedom, as for the attitude sigmas). The result carries the frame's data
information on (f, k1) with theta eliminated (the Schur complement of the
normal matrix), which is what the filter accumulates.

**Over frames** (:class:`LensFilter`): information form. The prior
(configured f with its tolerance, configured k1 with the distortion prior)
stays; the frames' information and information vector are summed with
exponential forgetting, weight exp(-dt / time_constant), so the estimate
follows a focal length that drifts with temperature over minutes but is not
moved by one frame's noise. Its covariance is the inverse of the summed
information.

Units: f and the sigmas in pixels, k1 dimensionless (normalised
coordinates), time in seconds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from tracker.attitude import matrix_from_rotation_vector
from tracker.camera import CameraModel

__all__ = ["LensPrior", "FrameFit", "fit_frame", "LensFilter", "LensState"]

_PRIOR_DOF = 3.0
_ITERATIONS = 8


@dataclass(frozen=True)
class LensPrior:
    """Gaussian prior on (f_px, k1): means and standard deviations."""

    f_px: float
    sigma_f_px: float
    k1: float
    sigma_k1: float

    @property
    def information(self) -> np.ndarray:
        return np.diag([self.sigma_f_px ** -2, self.sigma_k1 ** -2])

    @property
    def mean(self) -> np.ndarray:
        return np.array([self.f_px, self.k1])


@dataclass
class FrameFit:
    """One frame's fit. ``info`` (2x2) and ``info_vector`` (2,) are its data's alone."""

    R: np.ndarray
    camera: CameraModel
    cov: np.ndarray          # (2, 2) posterior covariance of (f_px, k1), prior included
    info: np.ndarray
    info_vector: np.ndarray
    sigma_px: float          # centroid noise per axis, from the residuals and the prior
    residuals: np.ndarray    # (n,) distance from each star to its prediction, px


def _solve_spd(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """X with A X = B for a small symmetric positive definite A (k, k), B (k,) or (k, m).

    Cholesky in Python floats: LAPACK's solve and inverse, called from the
    frame loop between the detector's calls, cost from a few microseconds to
    a millisecond on a busy machine (a lens frame makes up to ten); this
    costs 10-15 us each, steadily. Raises np.linalg.LinAlgError when A is
    not positive definite.
    """
    a = A.tolist()
    k = len(a)
    L = [[0.0] * k for _ in range(k)]
    for i in range(k):
        for j in range(i + 1):
            acc = a[i][j] - sum(L[i][t] * L[j][t] for t in range(j))
            if i == j:
                if not acc > 0.0:
                    raise np.linalg.LinAlgError("matrix is not positive definite")
                L[i][i] = math.sqrt(acc)
            else:
                L[i][j] = acc / L[j][j]
    columns = B.reshape(k, -1).T.tolist()
    for col in columns:
        for i in range(k):          # L y = b
            col[i] = (col[i] - sum(L[i][t] * col[t] for t in range(i))) / L[i][i]
        for i in reversed(range(k)):  # L^T x = y
            col[i] = (col[i] - sum(L[t][i] * col[t] for t in range(i + 1, k))) / L[i][i]
    return np.array(columns).T.reshape(B.shape)


def _project_with_jacobian(camera: CameraModel, c: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) of camera-frame vectors and d(pixel)/d(theta, f, k1) (n, 2, 5)."""
    cx_, cy_, cz = c[:, 0], c[:, 1], c[:, 2]
    u, v = cx_ / cz, cy_ / cz
    r2 = u * u + v * v
    s = 1.0 + r2 * (camera.k1 + camera.k2 * r2)
    ds = 2.0 * (camera.k1 + 2.0 * camera.k2 * r2)     # d s / d(u or v), divided by u or v
    f = camera.f_px
    pix = np.stack((camera.cx + f * u * s, camera.cy + f * v * s), axis=1)
    # d(pixel)/d(u, v)
    dxu = f * (s + ds * u * u)
    dxv = f * ds * u * v
    dyv = f * (s + ds * v * v)
    # d(u, v)/dc, and dc/dtheta = -[c]x (c' = c + theta x c)
    du = np.stack((1.0 / cz, np.zeros_like(cz), -cx_ / cz ** 2), axis=1)
    dv = np.stack((np.zeros_like(cz), 1.0 / cz, -cy_ / cz ** 2), axis=1)
    skew = np.zeros((len(c), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = cz, -cy_
    skew[:, 1, 0], skew[:, 1, 2] = -cz, cx_
    skew[:, 2, 0], skew[:, 2, 1] = cy_, -cx_
    du_t = np.einsum("ni,nij->nj", du, skew)
    dv_t = np.einsum("ni,nij->nj", dv, skew)
    J = np.empty((len(c), 2, 5))
    J[:, 0, :3] = dxu[:, None] * du_t + dxv[:, None] * dv_t
    J[:, 1, :3] = dxv[:, None] * du_t + dyv[:, None] * dv_t
    J[:, 0, 3], J[:, 1, 3] = u * s, v * s
    J[:, 0, 4], J[:, 1, 4] = f * u * r2, f * v * r2
    return pix, J


def fit_frame(xy: np.ndarray, ref: np.ndarray, R0: np.ndarray, camera: CameraModel,
              prior: LensPrior, centroid_sigma_px: float) -> FrameFit:
    """Attitude, focal length and k1 from matched stars (module docstring).

    ``xy`` (n, 2) measured pixels, ``ref`` (n, 3) the stars' ICRS vectors,
    ``R0`` the starting attitude, ``camera`` the starting lens (its f and k1
    are replaced). Needs n >= 3.
    """
    R, cam = R0, dataclasses.replace(camera, f_px=float(camera.f_px), k1=float(camera.k1))
    P = prior.information
    m = prior.mean
    n = len(xy)

    def weighted(cam, R):
        """Residuals (n, 2), the data's normal matrix and vector, weighted by 1/sigma^2."""
        pix, J = _project_with_jacobian(cam, ref @ R.T)
        d = xy - pix
        sigma2 = ((float(np.square(d).sum()) + _PRIOR_DOF * centroid_sigma_px ** 2)
                  / max(1.0, 2 * n - 5 + _PRIOR_DOF))
        Jf = J.reshape(-1, 5)
        return d, Jf.T @ Jf / sigma2, Jf.T @ d.reshape(-1) / sigma2, sigma2

    for _ in range(_ITERATIONS):
        _, H, b, _ = weighted(cam, R)
        x = np.array([cam.f_px, cam.k1])
        Hp = H.copy()
        Hp[3:, 3:] += P
        bp = b.copy()
        bp[3:] += P @ (m - x)
        try:
            step = _solve_spd(Hp, bp)
        except np.linalg.LinAlgError:
            break
        R = matrix_from_rotation_vector(step[:3]) @ R
        cam = dataclasses.replace(cam, f_px=float(cam.f_px + step[3]),
                                  k1=float(cam.k1 + step[4]))
        if np.max(np.abs(step[:3])) < 1e-10 and abs(step[3]) < 1e-7 * cam.f_px:
            break
    d, H, b, sigma2 = weighted(cam, R)
    # eliminate theta: the frame's information on (f, k1) alone
    Htt, Htl = H[:3, :3], H[:3, 3:]
    try:
        solve_t = _solve_spd(Htt, np.column_stack((Htl, b[:3])))
    except np.linalg.LinAlgError:
        solve_t = np.zeros((3, 3))
    info = H[3:, 3:] - Htl.T @ solve_t[:, :2]
    grad = b[3:] - Htl.T @ solve_t[:, 2]
    x = np.array([cam.f_px, cam.k1])
    cov = _solve_spd(info + P, np.eye(2))
    return FrameFit(R=R, camera=cam, cov=cov, info=info, info_vector=info @ x + grad,
                    sigma_px=math.sqrt(sigma2), residuals=np.hypot(d[:, 0], d[:, 1]))


@dataclass(frozen=True)
class LensState:
    """The filter's estimate: f and k1 with their sigmas, and how many frames made it."""

    f_px: float
    sigma_f_px: float
    k1: float
    sigma_k1: float
    frames: int


class LensFilter:
    """Slow information filter of (f, k1) over solved frames (module docstring)."""

    def __init__(self, prior: LensPrior, time_constant_s: float) -> None:
        self.prior = prior
        self.time_constant_s = float(time_constant_s)
        self.reset()

    def reset(self) -> None:
        self._info = np.zeros((2, 2))
        self._vector = np.zeros(2)
        self._frames = 0
        self._last_t: int | None = None
        self._state: LensState | None = None   # state() until the next update

    def update(self, fit: FrameFit, t_ns: int) -> None:
        """Add one frame's information, older frames fading with the time constant."""
        if self._last_t is not None and t_ns > self._last_t and self.time_constant_s > 0:
            fade = math.exp(-(t_ns - self._last_t) / 1e9 / self.time_constant_s)
            self._info *= fade
            self._vector *= fade
        if self._last_t is None or t_ns > self._last_t:
            self._last_t = t_ns
        self._info = self._info + fit.info
        self._vector = self._vector + fit.info_vector
        self._frames += 1
        self._state = None

    def state(self) -> LensState:
        """The estimate after the last update (computed once per update)."""
        if self._state is None:
            self._state = self._estimate()
        return self._state

    def _estimate(self) -> LensState:
        P = self.prior.information
        cov = _solve_spd(P + self._info, np.eye(2))
        x = cov @ (P @ self.prior.mean + self._vector)
        return LensState(f_px=float(x[0]), sigma_f_px=math.sqrt(cov[0, 0]), k1=float(x[1]),
                         sigma_k1=math.sqrt(cov[1, 1]), frames=self._frames)
