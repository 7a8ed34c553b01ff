"""The star solver: lost in space, tracking, verification, the attitude and the lens.

``solve(stars, t_ns)`` takes the detector's stars (pixel centroids and
fluxes) and returns a :class:`Solution`. It keeps state between calls: the
last attitude and rate (for tracking) and the lens estimate.

1. **Tracking** (when the last solution is recent): the attitude is
   predicted from the last one and the angular rate of the last two; every
   catalogue star is projected through the current lens estimate, image
   stars are paired with the nearest prediction within ``track_gate_px``,
   the attitude is solved and the pairing repeated within
   ``match_radius_px``. Lock is kept while the match verifies (below);
   otherwise:
2. **Lost in space**: four-star patterns of the ``pattern_stars`` brightest
   stars (in brightness order; when that finds nothing, once more with
   those the detector flagged saturated, elongated or at the edge last:
   tracker.identify.lost.clean_first) are looked up by their scale-free
   code (tracker.identify.lost),
   with the focal length anywhere in the configured prior
   (``identify.focal_tolerance`` around ``camera.focal_length_mm``). Each
   hypothesis (attitude and focal length) is verified by projecting the
   database stars and counting matches among the ``verify_stars``
   brightest image stars (in the pattern stars' order): once
   within three pixels, then, with attitude
   and focal length refitted on those, within ``match_radius_px`` (or 3.5
   times the residuals' sigma, when the centroids are noisier). It is
   accepted when at least ``min_matched`` stars match and the probability
   that a wrong attitude would match as many (tracker.identify.verify) is
   below ``max_prob_false``. The work is capped by counts
   (``max_patterns``, ``max_hypotheses``), never by time.
3. **Refinement**: with the accepted attitude, all image stars are matched
   to the catalogue, within three pixels and again, after the attitude,
   the focal length and k1 are fitted to them (tracker.identify.lens,
   priors: the configured lens), within the final radius as in
   verification (tracking: once, within the radius of the frame before);
   the fit to those gives this frame's focal length and sigma;
   the slow lens filter takes the frame's information, and the attitude is
   solved once more through the filtered lens (Wahba), with sigmas from the
   residuals blended with the ``centroid_sigma_px`` prior. Wahba (here and
   in tracking's gated pass) weights each star by its centroid's expected
   precision, 1 / variance (tracker.identify.predict.centroid_variance: a
   0.05 px floor and 1.75 px / SNR, a trail's length added along it from
   the rate and the exposure, when the caller gives the exposure), when
   the detector gave every star an SNR. Measured against the truth on
   tracked 3 deg/s slews, a bright star is centred to 0.05-0.1 px and one
   at SNR 6 to 0.4-0.5 px: a weight's floor of 0.25 px (the prior above,
   on main to ea288bd) made the faint stars, most of a frame's matches,
   count nearly as much as the bright ones: with these weights the
   cross-boresight and roll RMS errors fall by 8-46 % on the full frame
   and 10-42 % in windows (tracker.bench.track, 16 mm and 8 mm at 3 deg/s,
   seeds 101-104). The reported sigmas stay those of equal weights
   (conservative).

Aberration: with the frame's observer context (an absolute time, perhaps a
velocity: tracker.astrometry.observer) the catalogue directions of tracking
and refinement (predictions, the lens fit, Wahba) are the apparent ones for
that observer, so the attitude solved is the ICRS attitude and the lens fit
does not take aberration's scale (up to 1.3e-4) for a focal length. Lost in
space uses the database's astrometric directions: aberration moves a field
nearly as a rotation, which the hypothesis' attitude absorbs (up to 25
arcsec, well within the refinement's first three-pixel pass), and the
remainder (|beta| times the angle from the boresight: 0.13 px in the
corners of an 8 mm lens's field) is well inside the match radius.

When lost in space fails but a search over a wider focal-length range
(``identify.focal_search``) verifies, the frame is still failed (the
configuration disagrees with the sky) and ``reason`` says which focal
length the stars fit and how to set it.

Bad input never raises: the solution's ``reason`` says why there is no
attitude (``too_few_stars``, ``no_match``, ``not_verified``, ``budget``,
``bad_input``, ``wrong_fov``, or ``focal_length: ...``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from tracker.astrometry.aberration import aberrate
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
from tracker.identify.lens import LensFilter, LensPrior, LensState, fit_frame
from tracker.identify.lost import Hypothesis, PatternSearch, WorkBudget, clean_first
from tracker.identify.predict import (
    TrackPrediction,
    centroid_variance,
    informative,
    pinhole_travel,
    spread_and_smear,
)
from tracker.identify.verify import Projector, false_match_probability, match_nearest
from tracker.timing import StageTimer

__all__ = ["Solution", "Solver", "LensReport"]

_ARCSEC = math.degrees(1.0) * 3600.0
_PRIOR_DOF = 3.0
_FIRST_PASS_PX = 3.0
# tracking's catalogue cone: this much wider, reused while the axis stays inside (at 3 deg/s
# and 10 fps searched every 6.7 frames, not every 1.7 as at 0.5 deg; the cone's stars up to
# the windows' magnitude are all that is projected: prediction's thread CPU 234 -> 198 us a
# frame at 16 mm, 194 -> 172 at 8 mm, the same predictions)
_CONE_REUSE_RAD = math.radians(2.0)
# the faintest magnitude tracking expects to see falls by at most this a frame: a star
# at the detection limit, seen in one frame in two, keeps the windows' count steady
_FAINTEST_DECAY_MAG = 0.02

@dataclass(frozen=True)
class LensReport:
    """The lens as the solver now believes it (the slow filter; tracker.identify.lens).

    ``drift_ppm`` is the focal length's difference from the configured one,
    parts per million; ``frames`` how many solved frames informed it.
    """

    focal_length_mm: float
    sigma_focal_length_mm: float
    k1: float
    sigma_k1: float
    drift_ppm: float
    frames: int

    def to_json(self) -> dict:
        return {"focal_length_mm": self.focal_length_mm,
                "sigma_focal_length_mm": self.sigma_focal_length_mm, "k1": self.k1,
                "sigma_k1": self.sigma_k1, "drift_ppm": self.drift_ppm, "frames": self.frames}


@dataclass
class Solution:
    """One frame's answer. ``R`` is v_cam = R @ v_icrs; angles in the names' units.

    ``ra_deg``, ``dec_deg``, ``roll_deg`` describe the image centre (docs/conventions.md),
    which is the boresight unless a calibrated principal point moved it.
    ``sigma_cross_arcsec`` is the RMS of the boresight's angular error,
    ``sigma_roll_arcsec`` that of the rotation about it (tracker.attitude.
    attitude_covariance); ``residual_arcsec`` the RMS fit residual per star.
    ``hip`` has one entry per input star (0 = unidentified). ``rate_rad_s`` is
    the body angular velocity in the camera frame from the last two solutions
    (None if unknown, if they are further apart than ``track_max_gap_s``: a
    rate averaged over a long gap is not a rate, or if its 1-sigma exceeds
    ``rate_valid_sigma_deg_s`` on an axis); ``sigma_rate_rad_s`` that 1-sigma
    per axis, from the two attitudes' covariances (docs/protocol.md 2.2). ``prob_false`` is the
    model probability that the accepted match is wrong (tracker.identify.verify).
    ``focal_length_mm`` and ``sigma_focal_length_mm`` are this frame's own
    estimate (NaN without a solution, when the pixel size is unknown, or on
    the windowed frames that took the filtered lens: ``track_lens_every``);
    ``lens`` is the slow filter's estimate after this frame. ``patterns`` and
    ``hypotheses`` count the lost-in-space work done.
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
    sigma_rate_rad_s: np.ndarray | None = None
    prob_false: float = 1.0
    focal_length_mm: float = math.nan
    sigma_focal_length_mm: float = math.nan
    lens: LensReport | None = None
    patterns: int = 0
    hypotheses: int = 0
    stages_ms: dict = field(default_factory=dict)

    def to_json(self) -> dict | None:
        """The attitude record of the replay output (docs/conventions.md), or None without one."""
        if not self.ok:
            return None
        return {"q": [float(v) for v in self.q], "ra_deg": self.ra_deg,
                "dec_deg": self.dec_deg, "roll_deg": self.roll_deg, "matched": self.matched,
                "sigma_arcsec": self.sigma_cross_arcsec,
                "sigma_roll_arcsec": self.sigma_roll_arcsec, "mode": self.mode,
                "prob_false": self.prob_false, "focal_length_mm": self.focal_length_mm,
                "sigma_focal_length_mm": self.sigma_focal_length_mm,
                "lens": self.lens.to_json() if self.lens is not None else None}


def _median(values: np.ndarray) -> float:
    """np.median of a non-empty 1-D array (the mean of the two middle values when even),
    by one partition: np.median's own wrapper costs ten times the work on a frame's
    few dozen values."""
    n = len(values)
    k = n // 2
    middle = values.copy()
    if n % 2:
        middle.partition(k)
        return float(middle[k])
    middle.partition((k - 1, k))
    return float((middle[k - 1] + middle[k]) / 2.0)


def _not_duplicate(xy: np.ndarray, radius: float) -> np.ndarray:
    """Mask dropping every star within ``radius`` px of a brighter (earlier) one."""
    order = np.argsort(xy[:, 0], kind="stable")
    xs, ys = xy[order, 0], xy[order, 1]
    drop = np.zeros(len(xy), dtype=bool)
    for k in range(1, len(xy)):
        near_x = xs[k:] - xs[:-k] <= radius
        if not near_x.any():
            break
        close = near_x & (np.hypot(xs[k:] - xs[:-k], ys[k:] - ys[:-k]) <= radius)
        first, second = order[:-k][close], order[k:][close]
        drop[np.maximum(first, second)] = True
    return ~drop


def _centre_rotation(camera: CameraModel) -> np.ndarray | None:
    """Rotation (camera frame) taking the image-centre ray to +Z, the smallest one, or None
    when that ray is +Z (no rotation: the caller skips the product).

    RA/Dec/roll are reported for the image centre (docs/conventions.md); with the
    principal point elsewhere (a calibrated lens) the boresight is not there.
    """
    middle = ((camera.width - 1) / 2.0, (camera.height - 1) / 2.0)
    if (camera.cx, camera.cy) == middle:
        return None     # the principal point's ray is +Z for any lens
    centre = camera.pixel_to_vector(np.array(middle))
    axis = np.cross(centre, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    if s < 1e-15:
        return None
    return matrix_from_rotation_vector(axis / s * math.atan2(s, centre[2]))


def lens_prior(cfg: IdentifyConfig, camera: CameraModel) -> LensPrior:
    """The configured lens as a prior: f within the tolerance, k1 within the distortion prior.

    The focal tolerance is taken as two sigma; ``distortion_px`` is the
    one-sigma displacement k1 may cause at the image corner.
    """
    corner = max(math.hypot(x - camera.cx, y - camera.cy)
                 for x in (-0.5, camera.width - 0.5) for y in (-0.5, camera.height - 0.5))
    rho = corner / camera.f_px
    return LensPrior(f_px=camera.f_px, sigma_f_px=max(cfg.focal_tolerance, 1e-4)
                     * camera.f_px / 2.0, k1=camera.k1,
                     sigma_k1=max(cfg.distortion_px, 1e-3) / (camera.f_px * rho ** 3))


class Solver:
    """Identifies stars and solves the attitude; build it with ``make_solver``.

    ``bound`` is the pattern database tied to the catalogue; ``catalogue``
    vectors (and HIP numbers) are used for tracking and refinement.
    ``fov_error`` (a message) makes every solve fail with ``wrong_fov``. The
    camera's pixel size converts focal lengths to millimetres for the report.
    """

    def __init__(self, cfg: IdentifyConfig, camera: CameraModel, bound: BoundDatabase,
                 catalogue, fov_error: str | None = None) -> None:
        self.cfg = cfg
        self.camera = camera
        self.bound = bound
        self.fov_error = fov_error
        pixel = camera.pixel_size_um
        self._mm_per_px = pixel / 1000.0 if pixel else math.nan
        self._cat_hip = np.asarray(catalogue.hip, dtype=np.int32)
        self._cat_vectors = np.ascontiguousarray(catalogue.vectors, dtype=np.float64)
        self._cat_mag = np.asarray(catalogue.mag, dtype=np.float64)
        self._search = PatternSearch(bound, cfg.pattern_tolerance_px, cfg.min_separation_px)
        self._db_proj = Projector(bound.vectors)
        self._cat_proj = Projector(self._cat_vectors, reuse_cone_rad=_CONE_REUSE_RAD,
                                   key=self._cat_mag)
        self._area = float(camera.width * camera.height)
        self._timer = StageTimer()
        self._prior = lens_prior(cfg, camera)
        self.lens = LensFilter(self._prior, cfg.lens_time_constant_s)
        self._lens_cam: tuple[LensState, CameraModel] | None = None   # lens_camera's last
        self._report: tuple[LensState, LensReport] | None = None   # _lens_report's last
        self._obs: tuple | None = None   # (camera, xy, their unit vectors): _observed's last
        self.reset()

    def reset(self, lens: bool = False) -> None:
        """Forget the tracking state (the next frame is solved lost in space).

        The lens estimate is kept unless ``lens``: it belongs to the camera,
        not the pointing (forget it for another camera, or for calls that must
        not depend on the ones before, as tracker.solve's).
        """
        if lens:
            self.lens.reset()
        self._last_R: np.ndarray | None = None
        self._last_t: int | None = None
        self._rate: np.ndarray | None = None   # rotation vector rate of R, rad/s
        self._rate_P: np.ndarray | None = None   # its covariance, (rad/s)^2
        self._last_P: np.ndarray | None = None   # the last attitude's covariance, rad^2
        self._unknown = np.zeros((0, 3))   # directions of unidentified stars followed
        self._windowed = 0   # windowed tracking frames in a row (the lens fit's turn)
        self._radius = self.cfg.match_radius_px   # tracking's match radius, from residuals
        self._beta: np.ndarray | None = None   # this frame's observer velocity / c, ICRS
        self._snr: np.ndarray | None = None   # this frame's stars' SNR, as _prepare ordered them
        self._weight: np.ndarray | None = None  # their Wahba weights (_weights), in that order
        self._flags: np.ndarray | None = None  # their detector flags (lost in space orders by them)
        self._faintest = math.inf   # catalogue magnitude of the faintest stars matched lately
        self._snr_zero: float | None = None   # log10 SNR + 0.4 mag of the last matches

    def lens_camera(self) -> CameraModel:
        """The camera model with the filtered focal length and k1 (one object per estimate)."""
        state = self.lens.state()
        if self._lens_cam is None or self._lens_cam[0] is not state:
            self._lens_cam = (state, dataclasses.replace(self.camera, f_px=state.f_px,
                                                         k1=state.k1))
        return self._lens_cam[1]

    def _observed(self, camera: CameraModel, xy: np.ndarray) -> np.ndarray:
        """Unit vectors (n, 3) of the image stars ``xy`` through ``camera``.

        Kept for the last (camera, xy) pair: tracking and refinement of a
        frame look at the same stars through the same lens.
        """
        if self._obs is None or self._obs[0] is not camera or self._obs[1] is not xy:
            self._obs = (camera, xy, camera.pixel_to_vector(xy))
        return self._obs[2]

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
        idx = good.nonzero()[0]
        idx = idx[np.argsort(-flux[idx], kind="stable")]
        xy = np.empty((len(idx), 2))
        xy[:, 0], xy[:, 1] = x[idx], y[idx]
        if len(idx) > 1 and self.cfg.duplicate_px > 0:
            keep = _not_duplicate(xy, self.cfg.duplicate_px)
            idx, xy = idx[keep], xy[keep]
        if len(idx) < max(4, self.cfg.min_matched):
            return "too_few_stars"   # no match of fewer could be accepted
        self._snr = np.asarray(stars["snr"], dtype=np.float64)[idx] if "snr" in names else None
        self._flags = np.asarray(stars["flags"])[idx] if "flags" in names else None
        return idx, xy, (flux[idx] if has_flux else None)

    # -- public --------------------------------------------------------------

    def solve(self, stars, t_ns: int, observer=None, search_area_px: float | None = None,
              predicted: np.ndarray | None = None,
              predicted_xy: np.ndarray | None = None,
              exposure_s: float | None = None,
              smear_px: np.ndarray | None = None) -> Solution:
        """Identify ``stars`` (STAR_DTYPE rows: x, y, flux) seen at ``t_ns``; see the module.

        ``observer``: the frame's tracker.astrometry.observer.Observer (None: unknown).
        ``search_area_px``: the stars come from windows of this total area
        around the catalogue stars ``predicted`` (indices; this solver's
        :meth:`prediction`, tracker.identify.windows): only tracking is
        tried, against those stars, its false-match odds taken over that
        area, the lens fitted on one such frame in ``track_lens_every``; a
        frame that does not verify fails with ``not_verified`` and keeps the
        state (the caller searches the whole frame next). ``predicted_xy``
        (len(predicted), 2): where :meth:`prediction` put those stars, px
        (at the attitude, lens and observer this frame is tracked from): the
        gated pass pairs each with the nearest star found
        there (within ``track_gate_px``), with no projection of its own.
        ``exposure_s``: the frame's exposure time; with it and a rate, each
        star's weight counts its trail (module docstring, refinement).
        ``smear_px`` (len(stars), 2): those trails, px, if the caller has them
        (:meth:`smear_px` at or within a few px of the stars: the same to a
        thousandth of a pixel); None: reckoned here.
        """
        timer = self._timer
        timer.reset()
        timer.start("prepare")
        self._beta = None if observer is None else observer.beta()
        n_in = len(stars) if hasattr(stars, "__len__") else 0
        hip = np.zeros(n_in, dtype=np.int32)
        if self.fov_error is not None:
            return self._fail("wrong_fov", hip)
        prepared = self._prepare(stars)
        if isinstance(prepared, str):
            return self._fail(prepared, hip)
        idx, xy, flux = prepared
        if exposure_s is None:
            smear = None
        elif smear_px is None:
            smear = self.smear_px(xy, t_ns, exposure_s)
        else:
            smear = smear_px[idx]
        # every star's weight once (elementwise: the same numbers as the subsets' own)
        self._weight = None if self._snr is None else 1.0 / centroid_variance(
            self._snr, None if smear is None else np.square(smear).sum(axis=1))
        lens_cam = self.lens_camera()
        subset = None if search_area_px is None else np.asarray(predicted)
        if self._can_track(t_ns):
            timer.start("track")
            tracked = self._track(xy, lens_cam, t_ns, subset, predicted_xy)
            if tracked is not None:
                timer.start("refine")
                R, pairs, ref = tracked
                sol = self._finish(R, None, xy, flux, idx, hip, t_ns, "tracking", None, None,
                                   search_area_px or self._area, subset,
                                   None if predicted_xy is None else (pairs, ref))
                if sol is not None:
                    return sol
        if search_area_px is not None:
            return self._fail("not_verified", hip)
        timer.start("lost_in_space")
        budget = WorkBudget(self.cfg.max_patterns, self.cfg.max_hypotheses)
        f_low, f_high = self._focal_range(self.cfg.focal_tolerance)
        found = self._lost_in_space(xy, lens_cam, f_low, f_high, budget)
        if isinstance(found, tuple):
            timer.start("refine")
            R, prob, f_px = found
            sol = self._finish(R, prob, xy, flux, idx, hip, t_ns, "lost_in_space", budget,
                               f_px)
            if sol is not None:
                return sol
            found = "not_verified"
        self.reset()
        reason = found
        if self.cfg.focal_search > self.cfg.focal_tolerance:
            timer.start("focal_search")
            wide = WorkBudget(self.cfg.max_patterns, self.cfg.max_hypotheses)
            lo, hi = self._focal_range(self.cfg.focal_search)
            hint = self._lost_in_space(xy, lens_cam, lo, hi, wide, skip_f=(f_low, f_high))
            if isinstance(hint, tuple):
                reason = self._focal_advice(hint[2])
        return self._fail(reason, hip, budget)

    # -- stages --------------------------------------------------------------

    def _focal_range(self, tolerance: float) -> tuple[float, float]:
        f = self._prior.f_px
        return f * (1.0 - tolerance), f * (1.0 + tolerance)

    def _focal_advice(self, f_px: float) -> str:
        """The reason of a frame whose stars fit a focal length outside the prior."""
        cfg_f = self._prior.f_px
        pct = 100.0 * (f_px / cfg_f - 1.0)
        tol = f"+- {100 * self.cfg.focal_tolerance:g} % (identify.focal_tolerance)"
        if not math.isfinite(self._mm_per_px):
            return (f"focal_length: the stars fit a focal length of {f_px:.1f} px ({pct:+.1f} "
                    f"%), outside the configured {cfg_f:.1f} px {tol}; run `tracker calibrate`")
        mm = f"{f_px * self._mm_per_px:.4g}"
        return (f"focal_length: the stars fit a focal length of {mm} mm ({pct:+.1f} %), "
                f"outside camera.focal_length_mm {cfg_f * self._mm_per_px:.4g} {tol}; set "
                f"camera.focal_length_mm: {mm}, or run `tracker calibrate`")

    def prediction(self, t_ns: int, exposure_s: float, observer=None) -> TrackPrediction | None:
        """The stars tracking follows into a frame at ``t_ns``, or None without a rate.

        The catalogue stars predicted in the image no fainter than
        ``track_window_mag_margin`` below the faintest star matched lately
        (the last solution's faintest, or the limit before less
        ``_FAINTEST_DECAY_MAG`` a frame, whichever is fainter: fainter stars
        would not be found, their windows would cost without a star; a star a
        little fainter found in its window raises the limit for the next
        frame); of those, once a frame's matches gave the SNR a magnitude
        predicts, the fewest that carry ``track_window_information`` of the
        attitude's information (tracker.identify.predict.informative), at
        most ``track_window_stars``, brightest first; then the
        ``track_window_unknown`` brightest unidentified stars of the last
        frame, each with its uncertainty and its smear over ``exposure_s``
        (tracker.identify.predict). Needs a recent solution and a rate (the
        first frame after a lock has none: its stars are searched in the
        whole frame).
        """
        if not self._can_track(t_ns) or self._rate is None or self._last_P is None:
            return None
        cfg = self.cfg
        dt = (t_ns - self._last_t) / 1e9
        R = self._predicted(t_ns)
        camera = self.lens_camera()
        beta = None if observer is None else observer.beta()
        # the catalogue stars in the image bright enough, brightest first (the cone is kept
        # by magnitude: only those are projected), then the unidentified stars followed
        # that are in the image (index -1)
        unknown = self._unknown[:cfg.track_window_unknown]
        found, cam, pix = self._cat_proj.project(
            R, camera, beta=beta, key_max=self._faintest + cfg.track_window_mag_margin,
            extra=unknown)
        named = len(found) - (np.count_nonzero(found < 0) if len(unknown) else 0)
        if self._snr_zero is None:
            rows = np.arange(min(named, cfg.track_window_stars))
        else:
            snr = 10.0 ** (self._snr_zero - 0.4 * self._cat_mag[found[:named]])
            rows = informative(pix[:named], snr, (camera.cx, camera.cy),
                               cfg.track_window_information)[:cfg.track_window_stars]
        if named < len(found):
            rows = np.concatenate((rows, np.arange(named, len(found))))
        catalogue, cam, xy = found[rows], cam[rows], pix[rows]
        # uncertainties and smears of the stars given windows only
        accel = math.radians(cfg.track_accel_deg_s2) * 0.5 * dt * dt
        P = self._rate_P * dt
        P *= dt
        P += self._last_P
        P.flat[::4] += accel * accel
        sigma, smear = spread_and_smear(camera, cam, P, -self._rate, exposure_s)
        return TrackPrediction(R=R, xy=xy, sigma_px=sigma, smear_px=smear,
                               catalogue=catalogue, dt_s=dt)

    def smear_px(self, xy: np.ndarray, t_ns: int, exposure_s: float) -> np.ndarray | None:
        """(n, 2) travel of image positions ``xy`` over an exposure at ``t_ns``, px.

        From the current rate (tracker.identify.predict), through the pinhole
        (distortion changes it by k1 rho^2, a few per cent of a few pixels at
        the corners); None without a rate.
        """
        if not self._can_track(t_ns) or self._rate is None:
            return None
        return pinhole_travel(self.lens_camera(), np.asarray(xy, dtype=np.float64),
                              self._rate * exposure_s)

    def max_smear_px(self, t_ns: int, exposure_s: float) -> float | None:
        """An upper bound of :meth:`smear_px` over the whole frame, px (None without a rate).

        |J omega T| <= |J|_F |omega| T, and every entry of the pinhole J grows
        with |u| and |w|: |J|_F at the frame's farthest |u| and |w| bounds it
        everywhere (a few per cent of distortion below the bound's slack).
        """
        if not self._can_track(t_ns) or self._rate is None:
            return None
        camera = self.lens_camera()
        u = max(camera.cx + 0.5, camera.width - 0.5 - camera.cx) / camera.f_px
        w = max(camera.cy + 0.5, camera.height - 0.5 - camera.cy) / camera.f_px
        norm = math.sqrt(2.0 * (u * w) ** 2 + (1.0 + u * u) ** 2 + (1.0 + w * w) ** 2
                         + u * u + w * w)
        return camera.f_px * norm * math.hypot(*self._rate.tolist()) * exposure_s

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

    def _project(self, R, camera: CameraModel, subset: np.ndarray | None):
        """(catalogue indices, pixels) of the catalogue stars in the image, or of ``subset``."""
        if subset is None:
            return self._cat_proj.predict(R, camera, beta=self._beta)
        pix = camera.vector_to_pixel(self._seen(subset) @ R.T)
        inside = camera.in_frame(pix)
        return subset[inside], pix[inside]

    def _track(self, xy, camera: CameraModel, t_ns: int, subset: np.ndarray | None = None,
               subset_xy: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The attitude from the predicted one after one gated pass, the pass's pairs (per
        image star its index into the predictions, ``subset`` when given, or -1) and the
        paired stars' catalogue directions as this frame's observer sees them (the paired
        image stars' order), or None.

        ``subset_xy``: the pixels of ``subset`` at the predicted attitude, if known.
        """
        if subset_xy is None:
            cat_idx, pred = self._project(self._predicted(t_ns), camera, subset)
        else:
            cat_idx, pred = subset, subset_xy
        which, _ = match_nearest(xy, pred, self.cfg.track_gate_px)
        ok = which >= 0
        if np.count_nonzero(ok) < self.cfg.min_matched:
            return None
        ref = self._seen(cat_idx[which[ok]])
        return solve_wahba(self._observed(camera, xy)[ok], ref, self._weights(ok)), which, ref

    def _weights(self, ok: np.ndarray) -> np.ndarray | None:
        """Wahba's weights (module docstring, refinement) of this frame's stars ``ok``
        (a mask over them as _prepare ordered them), or None (equal) when some star has no
        positive SNR."""
        if self._weight is None or not (self._snr[ok] > 0).all():    # (NaN fails it too)
            return None
        return self._weight[ok]

    def _seen(self, cat_idx: np.ndarray) -> np.ndarray:
        """Catalogue directions as this frame's observer sees them (module docstring)."""
        ref = self._cat_vectors[cat_idx]
        return ref if self._beta is None else aberrate(ref, self._beta)

    def _lost_in_space(self, xy, camera: CameraModel, f_low: float, f_high: float,
                       budget: WorkBudget, skip_f=None):
        """(R, prob_false, f_px) of the first verified hypothesis, or a reason code.

        Two passes. The first draws pattern stars (and tests hypotheses on stars)
        in brightness order: the database holds each region's brightest stars,
        and a frame's brightest stars are often real and saturated. When it
        finds nothing and the detector flagged some of the first stars doubtful
        (:func:`tracker.identify.lost.clean_first`), a second pass, with as much
        work again, draws them unflagged first: a few bright false stars (particle
        hits saturating on glare, glare fragments) then cost no pattern. The
        chance of a wrong pattern's lookup (``budget.chance``) adds up over both
        passes, so the false-match odds count every pattern looked up.
        """
        cfg = self.cfg
        found = self._pattern_pass(xy, camera, f_low, f_high, budget, skip_f, None)
        if isinstance(found, tuple) or self._flags is None:
            return found
        order = clean_first(len(xy), cfg.pattern_stars, self._flags)
        if np.array_equal(order, np.arange(len(order))):
            return found        # nothing doubtful among the pattern stars: the same pass
        budget.max_patterns += cfg.max_patterns
        budget.max_hypotheses += cfg.max_hypotheses
        second = self._pattern_pass(xy, camera, f_low, f_high, budget, skip_f, self._flags)
        return second if isinstance(second, tuple) or found == "no_match" else found

    def _pattern_pass(self, xy, camera: CameraModel, f_low: float, f_high: float,
                      budget: WorkBudget, skip_f, flags):
        """One lost-in-space pass with stars in ``clean_first`` order for ``flags``."""
        cfg = self.cfg
        # the pattern stars lead the stars tested, in the same order
        tested = xy[clean_first(len(xy), cfg.verify_stars, flags)]
        reason = "no_match"
        for hyp in self._search.hypotheses(xy, camera, f_low, f_high, cfg.pattern_stars,
                                           budget, skip_f, flags):
            if budget.hypotheses >= budget.max_hypotheses:
                return "budget"
            budget.hypotheses += 1
            result = self._verify(hyp, camera, tested, budget.chance)
            if result is not None:
                return result
            reason = "not_verified"
        return "budget" if budget.exhausted else reason

    def _first_radius(self) -> float:
        return max(_FIRST_PASS_PX, self.cfg.match_radius_px)

    def _final_radius(self, residuals: np.ndarray) -> float:
        """The final pass's match radius: ``match_radius_px``, or wider for noisier centroids.

        3.5 sigma of the first pass's residuals (sigma per axis = median
        distance / 1.1774 for Gaussian errors), at most the first pass's
        radius; a star lies beyond 3.5 sigma with probability 0.2 %.
        """
        if len(residuals) < 3:
            return self.cfg.match_radius_px
        sigma = _median(residuals) / 1.1774
        return min(max(self.cfg.match_radius_px, 3.5 * sigma), self._first_radius())

    def _verify(self, hyp: Hypothesis, camera: CameraModel, xy, trials: float):
        """Check a hypothesis against the database stars; (R, prob, f_px) or None."""
        cfg = self.cfg
        cam = dataclasses.replace(camera, f_px=hyp.f_px)
        db_idx, pred = self._db_proj.predict(hyp.R, cam)
        which, _ = match_nearest(xy, pred, self._first_radius())
        ok = which >= 0
        if np.count_nonzero(ok) < cfg.min_matched:
            return None
        fit = fit_frame(xy[ok], self.bound.vectors[db_idx[which[ok]]], hyp.R, cam,
                        self._lens_only_f(cam), cfg.centroid_sigma_px)
        radius = self._final_radius(fit.residuals)
        db_idx, pred = self._db_proj.predict(fit.R, fit.camera)
        which, _ = match_nearest(xy, pred, radius)
        matched = int(np.count_nonzero(which >= 0))
        # four stars made the hypothesis; the others are the evidence
        prob = false_match_probability(matched - 4, len(xy) - 4, len(pred), radius,
                                       self._area, trials)
        if matched < cfg.min_matched or prob >= cfg.max_prob_false:
            return None
        return fit.R, prob, fit.camera.f_px

    def _lens_only_f(self, camera: CameraModel) -> LensPrior:
        """A prior leaving f free (a tenth of itself) and holding k1 where it is."""
        return LensPrior(f_px=camera.f_px, sigma_f_px=0.1 * camera.f_px, k1=camera.k1,
                         sigma_k1=1e-9)

    def _photometric_check(self, ok, which, cat_idx, flux) -> None:
        """Unmatch stars whose catalogue magnitude disagrees with their flux.

        The zero point is the median of (mag + 2.5 log10 flux) over the matches;
        a match more than ``mag_tolerance`` from it is dropped (in place).
        """
        if flux is None or np.count_nonzero(ok) < 4:
            return
        rows = ok.nonzero()[0]
        inst = -2.5 * np.log10(np.maximum(flux[rows], 1e-30))
        diff = self._cat_mag[cat_idx[which[rows]]] - inst
        off = np.abs(diff - _median(diff)) > self.cfg.mag_tolerance
        ok[rows[off]] = False

    def _match_catalogue(self, R, camera, xy, flux, radius: float, subset=None):
        """(ok mask, which, cat_idx, predictions, distances) of the image stars against
        the catalogue (or its ``subset``)."""
        cat_idx, pred = self._project(R, camera, subset)
        which, dist = match_nearest(xy, pred, radius)
        ok = which >= 0
        self._photometric_check(ok, which, cat_idx, flux)
        return ok, which, cat_idx, pred, dist

    def _match_pairs(self, R, camera, xy, flux, radius: float, cat_idx: np.ndarray,
                     pairs: np.ndarray, ref: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(ok mask, which, distances) as :meth:`_match_catalogue` gives them, from the gated
        pass's ``pairs`` into ``cat_idx`` and their directions ``ref`` (:meth:`_track`):
        each paired star keeps its star if within ``radius`` of it at ``R``; then which of
        the pairs were kept (a mask over them) and ``ref`` rotated by ``R`` (the camera
        frame).

        Only the paired stars are projected and nothing is searched: the
        windows' predictions are the stars that carry the attitude, far apart
        against the attitude's correction (a fraction of a pixel to a few),
        so a star's nearest prediction does not change with it.
        """
        rows = (pairs >= 0).nonzero()[0]
        rotated = ref @ R.T
        off = camera.vector_to_pixel(rotated)
        off -= xy[rows]
        d = np.hypot(off[:, 0], off[:, 1])
        which = np.empty(len(xy), np.int64)
        which.fill(-1)
        dist = np.empty(len(xy))
        dist.fill(np.inf)
        near = d <= radius
        kept_rows = rows[near]
        which[kept_rows], dist[kept_rows] = pairs[kept_rows], d[near]
        ok = which >= 0
        self._photometric_check(ok, which, cat_idx, flux)
        return ok, which, dist, ok[rows], rotated

    def _finish(self, R, prob, xy, flux, idx, hip, t_ns, mode, budget, f_px,
                area_px: float | None = None, subset: np.ndarray | None = None,
                gated: tuple[np.ndarray, np.ndarray] | None = None) -> Solution | None:
        """Refine against the catalogue, fit the lens, update the state (module docstring).

        ``prob`` None (tracking) means: verify here, with the refined matches
        (the stars found in ``area_px``); returns None if they do not verify.
        ``f_px``: the focal length lost in space found with ``R`` (None: the
        filtered lens's). ``subset``: windowed tracking (see :meth:`solve`); ``gated``
        its gated pass's pairs and their directions (:meth:`_track`), which the
        refined matches are taken from (:meth:`_match_pairs`) with no catalogue
        lookup of their own; when it keeps every pair and the lens is the one
        the gated pass saw, the gated pass's attitude is the answer (Wahba on
        the same stars) and its rotated directions give the residuals.
        """
        cfg = self.cfg
        camera = self.lens_camera()
        if f_px is not None:
            camera = dataclasses.replace(camera, f_px=f_px)
        if mode == "tracking":
            # the filtered lens and the tracked attitude are good: one pass, at the
            # radius the last frame's residuals gave
            radius = self._radius
        else:
            ok, which, cat_idx, _, _ = self._match_catalogue(R, camera, xy, flux,
                                                             self._first_radius())
            if np.count_nonzero(ok) < 4:
                return None
            first = fit_frame(xy[ok], self._seen(cat_idx[which[ok]]), R, camera,
                              self._prior, cfg.centroid_sigma_px)
            R, camera, radius = first.R, first.camera, self._final_radius(first.residuals)
        if gated is None:
            ok, which, cat_idx, pred, dist = self._match_catalogue(R, camera, xy, flux, radius,
                                                                   subset)
            predicted = len(pred)
        else:
            ok, which, dist, kept, rotated = self._match_pairs(R, camera, xy, flux, radius,
                                                               subset, *gated)
            cat_idx, predicted = subset, len(subset)
        n = int(np.count_nonzero(ok))
        if prob is None:
            prob = false_match_probability(n, len(xy), predicted, radius, area_px, 1)
            if n < cfg.min_matched or prob >= cfg.max_prob_false:
                return None
        if n < 4:
            return None
        matched = cat_idx[which[ok]]
        if gated is None:
            ref = self._seen(matched)
        elif kept.all():
            ref = gated[1]
        else:
            ref, rotated = gated[1][kept], rotated[kept]
        mags = self._cat_mag[matched]
        if self._snr is not None:
            snr, seen_mags = self._snr[ok], mags
            seen = snr > 0
            if not seen.all():
                snr, seen_mags = snr[seen], mags[seen]
            if len(snr):
                self._snr_zero = _median(np.log10(snr) + 0.4 * seen_mags)
        faintest = float(mags.max())
        if math.isfinite(self._faintest):
            faintest = max(faintest, self._faintest - _FAINTEST_DECAY_MAG)
        self._faintest = faintest
        frame = None
        self._windowed = self._windowed + 1 if subset is not None else 0
        if self._windowed % cfg.track_lens_every == 0:
            frame = fit_frame(xy[ok], ref, R, camera, self._prior, cfg.centroid_sigma_px)
            self.lens.update(frame, t_ns)
        self._radius = self._final_radius(dist[ok] if frame is None else frame.residuals)
        state = self.lens.state()
        lens_cam = self.lens_camera()
        observed = self._observed(lens_cam, xy)
        obs = observed[ok]
        if not (gated is not None and lens_cam is camera and kept.all()):
            # (else the gated pass solved it from these stars through this lens: that R)
            R = solve_wahba(obs, ref, self._weights(ok))
            rotated = ref @ R.T
        resid2 = float(np.square(obs - rotated).sum())
        sigma0 = cfg.centroid_sigma_px / lens_cam.f_px
        sigma = math.sqrt((resid2 + _PRIOR_DOF * sigma0 ** 2)
                          / max(1.0, 2 * n - 3 + _PRIOR_DOF))
        P = attitude_covariance(obs, sigma)
        hip[idx[ok]] = self._cat_hip[matched]
        centre = _centre_rotation(lens_cam)
        ra, dec, roll = radec_roll_from_matrix(R if centre is None else centre @ R)
        rate = rate_sigma = None
        if self._last_R is not None and self._last_t is not None and \
                0 < t_ns - self._last_t <= self.cfg.track_max_gap_s * 1e9:
            dt = (t_ns - self._last_t) / 1e9
            new_rate = rotation_vector(R @ self._last_R.T)
            new_rate /= dt
            new_P = P + self._last_P
            new_P /= dt * dt
            # average with the previous estimate: halves the noise of a steady rate
            if self._rate is None:
                self._rate, self._rate_P = new_rate, new_P
            else:
                new_rate += self._rate
                new_rate *= 0.5
                new_P += self._rate_P
                new_P *= 0.25
                self._rate, self._rate_P = new_rate, new_P
            rate_sigma = np.sqrt(self._rate_P.diagonal())
            if max(rate_sigma.tolist()) <= math.radians(self.cfg.rate_valid_sigma_deg_s):
                rate = -self._rate
            else:
                rate_sigma = None
        else:
            self._rate = self._rate_P = None
        self._last_R, self._last_t, self._last_P = R, t_ns, P
        unmatched = (~ok).nonzero()[0][:self.cfg.track_window_unknown]
        self._unknown = observed[unmatched] @ R
        self._timer.stop()
        return Solution(
            ok=True, reason=None, hip=hip, mode=mode, R=R, q=quat_from_matrix(R),
            ra_deg=math.degrees(ra), dec_deg=math.degrees(dec), roll_deg=math.degrees(roll),
            matched=n, sigma_cross_arcsec=math.sqrt(P[0, 0] + P[1, 1]) * _ARCSEC,
            sigma_roll_arcsec=math.sqrt(P[2, 2]) * _ARCSEC,
            residual_arcsec=math.sqrt(resid2 / n) * _ARCSEC, rate_rad_s=rate,
            sigma_rate_rad_s=rate_sigma,
            prob_false=prob,
            focal_length_mm=math.nan if frame is None else frame.camera.f_px * self._mm_per_px,
            sigma_focal_length_mm=(math.nan if frame is None
                                   else math.sqrt(frame.cov[0, 0]) * self._mm_per_px),
            lens=self._lens_report(state),
            patterns=budget.patterns if budget else 0,
            hypotheses=budget.hypotheses if budget else 0, stages_ms=dict(self._timer.ms))

    def _lens_report(self, state: LensState) -> LensReport:
        """The report of the filter's ``state``, made once per estimate (frozen: the
        solutions of the frames between two lens fits share it)."""
        if self._report is None or self._report[0] is not state:
            mm = self._mm_per_px
            self._report = (state, LensReport(
                focal_length_mm=state.f_px * mm, sigma_focal_length_mm=state.sigma_f_px * mm,
                k1=state.k1, sigma_k1=state.sigma_k1,
                drift_ppm=1e6 * (state.f_px / self._prior.f_px - 1.0), frames=state.frames))
        return self._report[1]

    def _fail(self, reason: str, hip: np.ndarray, budget: WorkBudget | None = None) -> Solution:
        self._timer.stop()
        return Solution(ok=False, reason=reason, hip=hip,
                        patterns=budget.patterns if budget else 0,
                        hypotheses=budget.hypotheses if budget else 0,
                        stages_ms=dict(self._timer.ms))
