"""The star solver: lost in space, tracking, verification and the attitude.

``solve(stars, t_ns)`` takes the detector's stars (pixel centroids and
fluxes) and returns a :class:`Solution`. It keeps state between calls:

1. **Tracking** (when the last solution is recent): the attitude is
   predicted from the last one and the angular rate of the last two; every
   catalogue star is projected, image stars are paired with the nearest
   prediction within ``track_gate_px``, the attitude is solved and the
   pairing repeated within ``match_radius_px``. Lock is kept while the
   match verifies (below); otherwise:
2. **Lost in space**: triangles of the ``pattern_stars`` brightest stars are
   looked up in the pattern database (tracker.identify.lost); each
   candidate's attitude is verified by projecting the database stars and
   counting matches among the ``verify_stars`` brightest image stars.
   A hypothesis is accepted when at least ``min_matched`` stars match and
   the probability that a wrong attitude would match as many
   (tracker.identify.verify) is below ``max_prob_false``.
3. **Refinement**: with the accepted attitude, all image stars are matched
   to the whole catalogue within ``match_radius_px`` and Wahba's problem is
   solved again (tracker.attitude.solve_wahba); the residuals give the
   per-axis angular noise, blended with the ``centroid_sigma_px`` prior
   (3 degrees of freedom), and from it the cross-boresight and roll sigmas.

Bad input never raises: the solution's ``reason`` says why there is no
attitude (``too_few_stars``, ``no_match``, ``not_verified``, ``bad_input``,
``wrong_fov``, ``timeout``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from tracker.attitude import (
    attitude_covariance,
    matrix_from_rotation_vector,
    quat_from_matrix,
    radec_roll_from_matrix,
    rotation_vector,
    solve_wahba,
)
from tracker.camera import CameraModel
from tracker.config import IdentifyConfig
from tracker.detect.result import StarFlag
from tracker.identify.database import BoundDatabase
from tracker.identify.lost import TriangleSearch, triad_order
from tracker.identify.verify import Projector, false_match_probability, match_nearest
from tracker.timing import StageTimer

__all__ = ["Solution", "Solver"]

_ARCSEC = math.degrees(1.0) * 3600.0
_PRIOR_DOF = 3.0


@dataclass
class Solution:
    """One frame's answer. ``R`` is v_cam = R @ v_icrs; angles in the names' units.

    ``ra_deg``, ``dec_deg``, ``roll_deg`` describe the image centre (DESIGN.md),
    which is the boresight unless a calibrated principal point moved it.
    ``sigma_cross_arcsec`` is the RMS of the boresight's angular error,
    ``sigma_roll_arcsec`` that of the rotation about it (tracker.attitude.
    attitude_covariance); ``residual_arcsec`` the RMS fit residual per star.
    ``hip`` has one entry per input star (0 = unidentified). ``rate_rad_s`` is
    the body angular velocity in the camera frame from the last two solutions
    (None if unknown, or if they are further apart than ``track_max_gap_s``:
    a rate averaged over a long gap is not a rate). ``prob_false`` is the
    model probability that the accepted match is wrong (tracker.identify.verify).
    """

    ok: bool
    reason: str | None
    hip: np.ndarray
    mode: str = "lost_in_space"
    R: np.ndarray | None = None
    q: np.ndarray | None = None
    ra_deg: float = math.nan
    dec_deg: float = math.nan
    roll_deg: float = math.nan
    matched: int = 0
    sigma_cross_arcsec: float = math.nan
    sigma_roll_arcsec: float = math.nan
    residual_arcsec: float = math.nan
    rate_rad_s: np.ndarray | None = None
    prob_false: float = 1.0
    hypotheses: int = 0
    stages_ms: dict = field(default_factory=dict)

    def to_json(self) -> dict | None:
        """The attitude record of the replay output (DESIGN.md), or None without one."""
        if not self.ok:
            return None
        return {"q": [float(v) for v in self.q], "ra_deg": self.ra_deg,
                "dec_deg": self.dec_deg, "roll_deg": self.roll_deg, "matched": self.matched,
                "sigma_arcsec": self.sigma_cross_arcsec,
                "sigma_roll_arcsec": self.sigma_roll_arcsec, "mode": self.mode,
                "prob_false": self.prob_false}


def _not_duplicate(xy: np.ndarray, radius: float) -> np.ndarray:
    """Mask dropping every star within ``radius`` px of a brighter (earlier) one."""
    order = np.argsort(xy[:, 0], kind="stable")
    xs, ys = xy[order, 0], xy[order, 1]
    drop = np.zeros(len(xy), dtype=bool)
    for k in range(1, len(xy)):
        near_x = xs[k:] - xs[:-k] <= radius
        if not np.any(near_x):
            break
        close = near_x & (np.hypot(xs[k:] - xs[:-k], ys[k:] - ys[:-k]) <= radius)
        first, second = order[:-k][close], order[k:][close]
        drop[np.maximum(first, second)] = True
    return ~drop


def _centre_rotation(camera: CameraModel) -> np.ndarray:
    """Rotation (camera frame) taking the image-centre ray to +Z, the smallest one.

    RA/Dec/roll are reported for the image centre (DESIGN.md); with the
    principal point elsewhere (a calibrated lens) the boresight is not there.
    """
    centre = camera.pixel_to_vector(np.array([(camera.width - 1) / 2.0,
                                              (camera.height - 1) / 2.0]))
    axis = np.cross(centre, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    if s < 1e-15:
        return np.eye(3)
    return matrix_from_rotation_vector(axis / s * math.atan2(s, centre[2]))


class Solver:
    """Identifies stars and solves the attitude; build it with ``make_solver``.

    ``bound`` is the pattern database tied to the catalogue; ``catalogue``
    vectors (and HIP numbers) are used for tracking and refinement.
    ``fov_error`` (a message) makes every solve fail with ``wrong_fov``.
    """

    def __init__(self, cfg: IdentifyConfig, camera: CameraModel, bound: BoundDatabase,
                 catalogue, fov_error: str | None = None) -> None:
        self.cfg = cfg
        self.camera = camera
        self.bound = bound
        self.fov_error = fov_error
        self._cat_hip = np.asarray(catalogue.hip, dtype=np.int32)
        self._cat_vectors = np.ascontiguousarray(catalogue.vectors, dtype=np.float64)
        self._cat_mag = np.asarray(catalogue.mag, dtype=np.float64)
        self._search = TriangleSearch(bound, cfg.pair_tolerance_px / camera.f_px)
        self._db_proj = Projector(camera, bound.vectors)
        self._cat_proj = Projector(camera, self._cat_vectors)
        self._area = float(camera.width * camera.height)
        self._max_pair = bound.db.max_pair_angle
        self._min_sep = cfg.min_separation_px / camera.f_px
        self._sigma0 = cfg.centroid_sigma_px / camera.f_px
        self._timer = StageTimer()
        self._to_centre = _centre_rotation(camera)
        self.reset()

    def reset(self) -> None:
        """Forget the tracking state (the next frame is solved lost in space)."""
        self._last_R: np.ndarray | None = None
        self._last_t: int | None = None
        self._rate: np.ndarray | None = None   # rotation vector rate of R, rad/s

    # -- input ---------------------------------------------------------------

    def _prepare(self, stars) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | str:
        """(input indices sorted bright first, their xy, flux or None) or a reason code.

        Non-finite rows and sources flagged EXTENDED by the detector are left out.
        """
        names = getattr(getattr(stars, "dtype", None), "names", None) or ()
        if "x" not in names or "y" not in names:
            return "bad_input"
        x = np.asarray(stars["x"], dtype=np.float64)
        y = np.asarray(stars["y"], dtype=np.float64)
        has_flux = "flux" in names
        flux = (np.asarray(stars["flux"], dtype=np.float64) if has_flux
                else -np.arange(len(x), dtype=np.float64))
        good = np.isfinite(x) & np.isfinite(y) & np.isfinite(flux)
        if "flags" in names:   # nebulae, comets, lit terrain: not catalogue stars
            good &= (np.asarray(stars["flags"]) & StarFlag.EXTENDED) == 0
        idx = np.flatnonzero(good)
        idx = idx[np.argsort(-flux[idx], kind="stable")]
        xy = np.stack((x[idx], y[idx]), axis=1)
        if len(idx) > 1 and self.cfg.duplicate_px > 0:
            keep = _not_duplicate(xy, self.cfg.duplicate_px)
            idx, xy = idx[keep], xy[keep]
        if len(idx) < max(3, self.cfg.min_matched):
            return "too_few_stars"   # no match of fewer could be accepted
        return idx, xy, (flux[idx] if has_flux else None)

    # -- public --------------------------------------------------------------

    def solve(self, stars, t_ns: int, observer=None) -> Solution:
        """Identify ``stars`` (STAR_DTYPE rows: x, y, flux) seen at ``t_ns``; see the module.

        ``observer``: the frame's tracker.astrometry.observer.Observer (None: unknown).
        """
        timer = self._timer
        timer.reset()
        timer.start("prepare")
        n_in = len(stars) if hasattr(stars, "__len__") else 0
        hip = np.zeros(n_in, dtype=np.int32)
        if self.fov_error is not None:
            return self._fail("wrong_fov", hip)
        prepared = self._prepare(stars)
        if isinstance(prepared, str):
            return self._fail(prepared, hip)
        idx, xy, flux = prepared
        vec = self.camera.pixel_to_vector(xy)
        found = None
        mode = "tracking"
        if self._can_track(t_ns):
            timer.start("track")
            found = self._track(xy, vec, t_ns)
            if found is not None:
                timer.start("refine")
                sol = self._finish(*found, xy, vec, flux, idx, hip, t_ns, mode)
                if sol is not None:
                    return sol
        mode = "lost_in_space"
        timer.start("lost_in_space")
        found = self._lost_in_space(xy, vec)
        if not isinstance(found, str):
            timer.start("refine")
            sol = self._finish(*found, xy, vec, flux, idx, hip, t_ns, mode)
            if sol is not None:
                return sol
            found = "not_verified"
        self.reset()
        return self._fail(found, hip)

    # -- stages --------------------------------------------------------------

    def _can_track(self, t_ns: int) -> bool:
        if self._last_R is None or self._last_t is None:
            return False
        gap = (t_ns - self._last_t) / 1e9
        return 0.0 <= gap <= self.cfg.track_max_gap_s

    def _predicted(self, t_ns: int) -> np.ndarray:
        if self._rate is None:
            return self._last_R
        dt = (t_ns - self._last_t) / 1e9
        return matrix_from_rotation_vector(self._rate * dt) @ self._last_R

    def _track(self, xy, vec, t_ns):
        """(R, None, 1) from the predicted attitude after one gated pass, or None."""
        R = self._predicted(t_ns)
        cat_idx, pred = self._cat_proj.predict(R)
        which, _ = match_nearest(xy, pred, self.cfg.track_gate_px)
        ok = which >= 0
        if np.count_nonzero(ok) < self.cfg.min_matched:
            return None
        return solve_wahba(vec[ok], self._cat_vectors[cat_idx[which[ok]]]), None, 1

    def _lost_in_space(self, xy, vec):
        """(R, prob_false, hypotheses) or a reason code."""
        cfg = self.cfg
        n_pat = min(cfg.pattern_stars, len(xy))
        n_ver = min(cfg.verify_stars, len(xy))
        gram = vec[:n_pat] @ vec[:n_pat].T
        seps = np.arccos(np.clip(gram, -1.0, 1.0))
        usable = (seps <= self._max_pair) & (seps >= self._min_sep)
        deadline = time.perf_counter() + cfg.max_lis_ms / 1000.0
        hypotheses = 0
        best_reason = "no_match"
        for t, (i, j, k) in enumerate(triad_order(n_pat)):
            if t >= cfg.max_triads:
                break
            if not (usable[i, j] and usable[j, k] and usable[i, k]):
                continue
            handed = np.sign(np.dot(vec[i], np.cross(vec[j], vec[k])))
            tris = self._search.candidates(seps[i, j], seps[j, k], seps[i, k], handed)
            for tri in tris:
                hypotheses += 1
                R = solve_wahba(vec[[i, j, k]], self.bound.vectors[tri])
                result = self._verify(R, xy[:n_ver], vec[:n_ver], hypotheses)
                if result is not None:
                    return result
                best_reason = "not_verified"
            if time.perf_counter() > deadline:
                return "timeout"
        return best_reason

    def _verify(self, R, xy, vec, hypotheses):
        """Check a 3-star hypothesis against the database stars; (R, prob, h) or None."""
        cfg = self.cfg
        db_idx, pred = self._db_proj.predict(R)
        which, _ = match_nearest(xy, pred, cfg.match_radius_px)
        ok = which >= 0
        matched = int(np.count_nonzero(ok))
        if matched < cfg.min_matched:
            return None
        R = solve_wahba(vec[ok], self.bound.vectors[db_idx[which[ok]]])
        db_idx, pred = self._db_proj.predict(R)
        which, _ = match_nearest(xy, pred, cfg.match_radius_px)
        ok = which >= 0
        matched = int(np.count_nonzero(ok))
        # three stars made the hypothesis; the others are the evidence
        prob = false_match_probability(matched - 3, len(xy) - 3, len(pred),
                                       cfg.match_radius_px, self._area, hypotheses)
        if matched < cfg.min_matched or prob >= cfg.max_prob_false:
            return None
        return R, prob, hypotheses

    def _photometric_check(self, ok, which, cat_idx, flux) -> None:
        """Unmatch stars whose catalogue magnitude disagrees with their flux.

        The zero point is the median of (mag + 2.5 log10 flux) over the matches;
        a match more than ``mag_tolerance`` from it is dropped (in place).
        """
        if flux is None or np.count_nonzero(ok) < 4:
            return
        rows = np.flatnonzero(ok)
        inst = -2.5 * np.log10(np.maximum(flux[rows], 1e-30))
        diff = self._cat_mag[cat_idx[which[rows]]] - inst
        off = np.abs(diff - np.median(diff)) > self.cfg.mag_tolerance
        ok[rows[off]] = False

    def _finish(self, R, prob, hypotheses, xy, vec, flux, idx, hip, t_ns, mode
                ) -> Solution | None:
        """Refine against the whole catalogue, compute sigmas, update the tracking state.

        ``prob`` None (tracking) means: verify here, with the refined matches;
        returns None if they do not verify.
        """
        cat_idx, pred = self._cat_proj.predict(R)
        which, _ = match_nearest(xy, pred, self.cfg.match_radius_px)
        ok = which >= 0
        self._photometric_check(ok, which, cat_idx, flux)
        n = int(np.count_nonzero(ok))
        if prob is None:
            prob = false_match_probability(n, len(xy), len(pred), self.cfg.match_radius_px,
                                           self._area, 1)
            if n < self.cfg.min_matched or prob >= self.cfg.max_prob_false:
                return None
        if n < 3:
            return None
        obs = vec[ok]
        ref = self._cat_vectors[cat_idx[which[ok]]]
        R = solve_wahba(obs, ref)
        resid2 = float(np.square(obs - ref @ R.T).sum())
        sigma = math.sqrt((resid2 + _PRIOR_DOF * self._sigma0 ** 2)
                          / max(1.0, 2 * n - 3 + _PRIOR_DOF))
        P = attitude_covariance(obs, sigma)
        hip[idx[ok]] = self._cat_hip[cat_idx[which[ok]]]
        ra, dec, roll = radec_roll_from_matrix(self._to_centre @ R)
        rate = None
        if self._last_R is not None and self._last_t is not None and \
                0 < t_ns - self._last_t <= self.cfg.track_max_gap_s * 1e9:
            new_rate = rotation_vector(R @ self._last_R.T) / ((t_ns - self._last_t) / 1e9)
            # average with the previous estimate: halves the noise of a steady rate
            self._rate = new_rate if self._rate is None else 0.5 * (self._rate + new_rate)
            rate = -self._rate
        else:
            self._rate = None
        self._last_R, self._last_t = R, t_ns
        self._timer.stop()
        return Solution(
            ok=True, reason=None, hip=hip, mode=mode, R=R, q=quat_from_matrix(R),
            ra_deg=math.degrees(ra), dec_deg=math.degrees(dec), roll_deg=math.degrees(roll),
            matched=n, sigma_cross_arcsec=math.sqrt(P[0, 0] + P[1, 1]) * _ARCSEC,
            sigma_roll_arcsec=math.sqrt(P[2, 2]) * _ARCSEC,
            residual_arcsec=math.sqrt(resid2 / n) * _ARCSEC, rate_rad_s=rate,
            prob_false=prob, hypotheses=hypotheses, stages_ms=dict(self._timer.ms))

    def _fail(self, reason: str, hip: np.ndarray) -> Solution:
        self._timer.stop()
        return Solution(ok=False, reason=reason, hip=hip, stages_ms=dict(self._timer.ms))
