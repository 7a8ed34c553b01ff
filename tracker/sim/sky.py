"""Render catalogue stars seen from an attitude: the simulator's sky.

Stars are projected through :class:`tracker.camera.CameraModel`
(distortion included) with v_cam = R @ v_icrs, converted to
photo-electrons (tracker.sim.photometry) and handed to
:func:`tracker.sim.frame.render_points`. With a body rate the stars are
smeared over the exposure (``SimConfig.smear``): positions at sub-steps
no more than sigma/2 apart, the attitude R being the one at the exposure
mid-point.

With an absolute time (``t_tai_ns``) the stars are drawn where a moving
observer sees them: aberrated (tracker.astrometry.aberration) by the
Earth's barycentric velocity at that time plus the observer's velocity
relative to the Earth's centre (``observer_velocity_km_s``, ICRS axes). The
attitude R stays the ICRS attitude of the camera, the one the tracker
reports.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from tracker.astrometry.aberration import aberrate, observer_beta
from tracker.astrometry.timescale import check_tai_ns, utc_iso_from_tai_ns
from tracker.attitude import quat_from_matrix, radec_roll_from_matrix
from tracker.camera import CameraModel
from tracker.config import CameraConfig, SimConfig
from tracker.sim.frame import SimFrame, render_points, sim_psf
from tracker.sim.photometry import sky_electrons_per_pixel, star_electrons
from tracker.sim.psf_shapes import PsfShape
from tracker.sim.scene import Scene
from tracker.sim.sequence import attitude_at

__all__ = ["render_sky", "render_sequence"]

_MAX_SMEAR_STEPS = 256


def _camera_parts(camera, pixel_size_um, bit_depth) -> tuple[CameraModel, float, int]:
    """CameraModel, pixel pitch (um) and bit depth from a CameraConfig or a CameraModel."""
    if isinstance(camera, CameraConfig):
        return (CameraModel.from_config(camera),
                camera.pixel_size_um if pixel_size_um is None else pixel_size_um,
                camera.bit_depth if bit_depth is None else bit_depth)
    if isinstance(camera, CameraModel):
        default = CameraConfig()
        return (camera, default.pixel_size_um if pixel_size_um is None else pixel_size_um,
                default.bit_depth if bit_depth is None else bit_depth)
    raise TypeError(f"camera must be a CameraConfig or CameraModel; got "
                    f"{type(camera).__name__}")


def _rate_rad_s(rate_deg_s) -> np.ndarray | None:
    if rate_deg_s is None:
        return None
    rate = np.asarray(rate_deg_s, dtype=np.float64)
    if rate.shape != (3,) or not np.all(np.isfinite(rate)):
        raise ValueError(f"rate_deg_s must be three finite numbers (x, y, z); got {rate_deg_s}")
    return None if not np.any(rate) else np.radians(rate)


def render_sky(camera, catalogue, R: np.ndarray, sim_cfg: SimConfig,
               rng: np.random.Generator, *, t_s: float = 0.0, rate_deg_s=None,
               noise_model: str | None = None, snr_db: float | None = None,
               pixel_size_um: float | None = None, bit_depth: int | None = None,
               psf: PsfShape | None = None, scene: Scene | None = None,
               t_tai_ns: int | None = None, observer_velocity_km_s=None) -> SimFrame:
    """Render the catalogue as seen at attitude ``R`` (v_cam = R @ v_icrs, mid-exposure).

    ``camera``: a CameraConfig (preferred; gives the pixel pitch and bit
    depth) or a CameraModel (pitch and bit depth then default to the
    OV2311's 3 um and 10 bits unless given). ``catalogue``: anything with
    ``vectors`` (N, 3) ICRS unit vectors, ``mag`` (Hp), ``hip`` and
    ``epoch_year`` (tracker.catalogue.Catalogue). ``rate_deg_s``: body rate
    (x, y, z) in deg/s, or None for a still camera; ``t_s`` is recorded as
    the frame's time. Every star whose light reaches the frame is rendered.
    ``psf`` overrides the configured PSF (tracker.sim.psf_shapes). ``scene``
    (tracker.sim.scene, realistic sensor model) adds its light and particle
    charge, and hides the stars whose centre it occludes.
    ``t_tai_ns`` (TAI ns since 1970, tracker.astrometry.timescale) turns on
    aberration, with ``observer_velocity_km_s`` (geocentric, ICRS, km/s;
    None = at rest at the Earth's centre); both go into the truth.
    """
    model, pitch_um, depth = _camera_parts(camera, pixel_size_um, bit_depth)
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
        raise ValueError("R must be a 3x3 rotation matrix")
    rate = _rate_rad_s(rate_deg_s)
    focal_mm = model.f_px * pitch_um / 1000.0
    exposure_s = sim_cfg.exposure_ms / 1000.0
    psf = sim_psf(sim_cfg) if psf is None else psf
    half = psf.half_width

    vectors = np.asarray(catalogue.vectors, dtype=np.float64)
    if t_tai_ns is not None:
        vectors = aberrate(vectors, observer_beta(check_tai_ns(t_tai_ns),
                                                  observer_velocity_km_s))
    reach = model.fov_diagonal_rad / 2.0 + np.radians(2.0)
    if rate is not None:
        reach += float(np.linalg.norm(rate)) * exposure_s
    near = np.flatnonzero(vectors @ R[2] > np.cos(min(reach, np.radians(89.0))))
    ends = (-0.5, 0.5) if rate is not None and sim_cfg.smear else (0.0,)
    paths = [model.vector_to_pixel(vectors[near] @ attitude_at(R, rate, e * exposure_s).T)
             for e in ends]
    if len(ends) == 2:
        travel = np.nanmax(np.hypot(*(paths[1] - paths[0]).T), initial=0.0)
        steps = int(min(_MAX_SMEAR_STEPS, np.ceil(travel / (0.5 * psf.sigma_px)) + 1))
        offsets = np.linspace(-0.5, 0.5, max(steps, 2)) * exposure_s
        paths = [model.vector_to_pixel(vectors[near] @ attitude_at(R, rate, dt).T)
                 for dt in offsets]
    pix = np.stack(paths, axis=1)  # (N, M, 2)
    ok = np.all(np.isfinite(pix), axis=(1, 2))
    lo, hi = pix.min(axis=1), pix.max(axis=1)
    ok &= ((hi[:, 0] >= -0.5 - half) & (lo[:, 0] <= model.width - 0.5 + half)
           & (hi[:, 1] >= -0.5 - half) & (lo[:, 1] <= model.height - 0.5 + half))
    if scene is not None:   # a star is hidden when its direction is behind the scene
        mid = pix[:, pix.shape[1] // 2]
        col = np.clip(np.rint(mid[:, 0]), 0, model.width - 1).astype(np.intp)
        row = np.clip(np.rint(mid[:, 1]), 0, model.height - 1).astype(np.intp)
        inside = ((mid[:, 0] >= -0.5) & (mid[:, 0] <= model.width - 0.5)
                  & (mid[:, 1] >= -0.5) & (mid[:, 1] <= model.height - 0.5))
        ok &= ~(inside & scene.occluded[row, col])
    keep = near[ok]
    pix = pix[ok]
    mags = np.asarray(catalogue.mag, dtype=np.float64)[keep]
    frame = render_points(
        (model.height, model.width), pix[..., 0], pix[..., 1],
        star_electrons(mags, focal_mm, sim_cfg), sim_cfg, rng, bit_depth=depth, mags=mags,
        hips=np.asarray(catalogue.hip)[keep], noise_model=noise_model, snr_db=snr_db,
        sky_e=sky_electrons_per_pixel(focal_mm, pitch_um, sim_cfg), pixel_size_um=pitch_um,
        psf=psf, light_e=None if scene is None else scene.light_e,
        deposits=None if scene is None else (scene.deposits, scene.deposit_truth))
    if scene is not None:
        frame.labels = scene.labels
        frame.truth["scene"] = scene.bodies
    if len(ends) == 2:  # truth positions at the mid-exposure attitude, not the path mean
        mid = model.vector_to_pixel(vectors[keep] @ R.T)
        frame.stars["x"], frame.stars["y"] = mid[:, 0], mid[:, 1]
        for record, (x, y) in zip(frame.truth["stars"], mid, strict=True):
            record["x"], record["y"] = float(x), float(y)
    frame.R = R
    if t_tai_ns is not None:
        frame.truth.update(utc=utc_iso_from_tai_ns(t_tai_ns), observer_velocity_km_s=(
            None if observer_velocity_km_s is None
            else [float(v) for v in observer_velocity_km_s]))
    ra, dec, roll = radec_roll_from_matrix(R)
    frame.truth.update(
        q=[float(v) for v in quat_from_matrix(R)], ra_deg=float(np.degrees(ra)),
        dec_deg=float(np.degrees(dec)), roll_deg=float(np.degrees(roll)),
        epoch_year=float(catalogue.epoch_year), t_s=float(t_s),
        rate_deg_s=None if rate is None else [float(v) for v in np.degrees(rate)],
        camera={"width": model.width, "height": model.height, "pixel_size_um": pitch_um,
                "focal_length_mm": focal_mm, "f_px": model.f_px, "cx": model.cx,
                "cy": model.cy, "k1": model.k1, "k2": model.k2})
    return frame


def render_sequence(camera, catalogue, R0: np.ndarray, sim_cfg: SimConfig,
                    rng: np.random.Generator, n_frames: int, *, fps: float | None = None,
                    rate_deg_s=None, t_tai_ns: int | None = None,
                    **kwargs) -> Iterator[SimFrame]:
    """Frames i = 0..n_frames-1 at t = i / fps of a constant-rate slew starting at R0.

    ``fps`` and ``rate_deg_s`` default to ``sim_cfg.fps`` and
    ``sim_cfg.rate_deg_s``; ``t_tai_ns`` is the first frame's absolute time
    (later frames follow at 1 / fps); other keywords go to :func:`render_sky`.
    """
    fps = sim_cfg.fps if fps is None else float(fps)
    if not fps > 0:
        raise ValueError(f"fps must be > 0; got {fps}")
    rate_deg = sim_cfg.rate_deg_s if rate_deg_s is None else rate_deg_s
    rate = _rate_rad_s(rate_deg)
    for i in range(n_frames):
        t = i / fps
        t_abs = None if t_tai_ns is None else t_tai_ns + round(t * 1e9)
        yield render_sky(camera, catalogue, attitude_at(R0, rate, t), sim_cfg, rng, t_s=t,
                         rate_deg_s=rate_deg, t_tai_ns=t_abs, **kwargs)
