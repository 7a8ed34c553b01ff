"""The library API: the attitude of a star-field image, or of star centroids, in one call.

Each call is independent (lost in space: no tracking state carries over)::

    >>> import tracker
    >>> result = tracker.solve("tests/data/real/cedar-solve/orion_belt.jpg",
    ...                        config="tests/data/real/cedar-solve/orion_belt.yaml")
    >>> result.ok, result.matched >= 5
    (True, True)
    >>> truth = {"ra_deg": 84.0115, "dec_deg": -0.7716}    # astrometry.net's solution
    >>> bool(abs(result.ra_deg - truth["ra_deg"]) < 0.01 and
    ...      abs(result.dec_deg - truth["dec_deg"]) < 0.01)
    True

The image may be a file (PNG, TIFF, JPEG, .npy, read as ``tracker replay``
reads it) or an array: uint8, uint16 (10-bit values by default, see
``camera.bit_depth``), float (0..1 of full scale, or ADU) or colour
(rows x cols x 3, OpenCV's BGR order); tracker.frame_array has the rule.
It must be the size of the configured camera: the camera model is what
turns pixels into directions.

``config`` is a YAML file, a :class:`tracker.config.Config`, a mapping of
sections (as YAML would give), or None for the built-in defaults (the OV2311
with a 16 mm lens). Centroids alone (from any detector) are solved with
:func:`solve_centroids`::

    >>> stars = [(s["x"], s["y"]) for s in result.stars]   # brightest first
    >>> again = tracker.solve_centroids(
    ...     stars, config="tests/data/real/cedar-solve/orion_belt.yaml")
    >>> bool(abs(again.ra_deg - result.ra_deg) < 0.01 and again.matched >= 5)
    True

Conventions (as everywhere in tracker): pixel (0, 0) is the centre of the
top-left pixel (tetra3 and cedar-solve put it at (0.5, 0.5): subtract 0.5);
``q = [w, x, y, z]``, w >= 0, rotates ICRS into the camera frame
(v_cam = R(q) v_icrs); RA/Dec (ICRS) and roll are of the image centre, roll
as tetra3 defines it. Errors a caller can fix (a bad file or configuration,
an image of another size than the camera, a missing catalogue) raise
:class:`tracker.errors.UserError` with a one-line message; an image without
a solution is not an error: ``ok`` is False and ``reason`` says why.

Aberration: the attitude is the ICRS one (as an observer at rest at the
solar system's barycentre would report it) when the call says when the
image was taken, ``utc="2026-03-20T21:04:05.5Z"`` (the exposure mid-point,
ISO 8601 UTC), and for a camera in orbit its velocity relative to the
Earth's centre, ``observer_velocity_km_s=(vx, vy, vz)`` (ICRS axes). The
time also sets the catalogue's proper-motion epoch. Without ``utc`` the
attitude is the apparent one, up to 25 arcsec away; ``corrections`` in the
result says which were applied.

Calls are serialised by a lock, and the configurations of the last two calls
keep their loaded catalogue, database and detector (the first call with a
configuration takes about a second to load them).
"""

from __future__ import annotations

import math
import os
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tracker.astrometry.observer import Observer, TimeSource
from tracker.astrometry.timescale import TimeError, tai_ns_from_utc_iso
from tracker.capture.imagefile import read_image
from tracker.config import Config, check_config, config_from_dict, load_config
from tracker.errors import UserError
from tracker.frame_array import as_frame
from tracker.pipeline import Pipeline

__all__ = ["solve", "solve_centroids", "SolveResult", "RESULT_STAR_DTYPE"]

# The stars of a result: the detector's centroids (or those given), with the
# HIP number of those identified (0 otherwise).
RESULT_STAR_DTYPE = np.dtype([("x", np.float64), ("y", np.float64), ("flux", np.float64),
                              ("snr", np.float64), ("flags", np.uint16), ("hip", np.int32)])

_PIPELINES_KEPT = 2
_lock = threading.Lock()
_pipelines: OrderedDict[Config, Pipeline] = OrderedDict()


@dataclass(frozen=True)
class SolveResult:
    """The attitude of one image (or centroid list) and the stars it rests on.

    Angles in degrees (``ra_deg``, ``dec_deg``, ``roll_deg``; NaN without a
    solution) and arcseconds (``sigma_arcsec``: RMS error of the boresight,
    ``sigma_roll_arcsec``: about it). ``q`` is [w, x, y, z] or None.
    ``stars`` has :data:`RESULT_STAR_DTYPE` rows, brightest first for
    images. ``prob_false`` is the chance that the match is wrong.
    ``time_ms`` is the processing time (decoding a file excluded).
    ``corrections`` names the aberration corrections applied
    (``annual_aberration``, ``observer_velocity``; empty without ``utc``).
    """

    ok: bool
    reason: str | None
    ra_deg: float = math.nan
    dec_deg: float = math.nan
    roll_deg: float = math.nan
    q: tuple[float, float, float, float] | None = None
    matched: int = 0
    sigma_arcsec: float = math.nan
    sigma_roll_arcsec: float = math.nan
    prob_false: float = 1.0
    stars: np.ndarray = field(default_factory=lambda: np.zeros(0, RESULT_STAR_DTYPE))
    width: int = 0
    height: int = 0
    time_ms: float = 0.0
    corrections: tuple[str, ...] = ()

    def __repr__(self) -> str:
        if not self.ok:
            return f"SolveResult(ok=False, reason={self.reason!r}, stars={len(self.stars)})"
        return (f"SolveResult(ok=True, ra_deg={self.ra_deg:.5f}, dec_deg={self.dec_deg:.5f}, "
                f"roll_deg={self.roll_deg:.4f}, matched={self.matched}, "
                f"sigma_arcsec={self.sigma_arcsec:.2f}, stars={len(self.stars)})")


def _config(config) -> Config:
    if config is None:
        return Config()
    if isinstance(config, Config):
        return check_config(config)
    if isinstance(config, (str, os.PathLike)):
        return load_config(config)
    if isinstance(config, Mapping):
        return config_from_dict(dict(config))
    raise UserError(f"config: found a {type(config).__name__}, expected a YAML file path, "
                    "a tracker.config.Config, a mapping of sections or None")


def _pipeline(cfg: Config) -> Pipeline:
    """The kept pipeline of this configuration (call under the lock)."""
    pipeline = _pipelines.pop(cfg, None)
    if pipeline is None:
        while len(_pipelines) >= _PIPELINES_KEPT:
            _pipelines.popitem(last=False)
        pipeline = Pipeline(cfg)
        if cfg.identify.enabled:
            pipeline.solver  # noqa: B018 - the catalogue's and database's errors, now
    _pipelines[cfg] = pipeline
    pipeline.reset(lens=True)   # each call stands alone: no pointing or lens carried over
    return pipeline


def _observer(utc, observer_velocity_km_s) -> Observer:
    """The observer context of a call's ``utc`` and velocity; UserError if unusable."""
    if utc is None:
        if observer_velocity_km_s is not None:
            raise UserError("observer_velocity_km_s needs utc: without the time the Earth's "
                            "own 30 km/s cannot be corrected, so neither is the observer's")
        return Observer()
    try:
        return Observer(tai_ns_from_utc_iso(utc), observer_velocity_km_s, TimeSource.RECORD)
    except (TimeError, ValueError) as exc:
        raise UserError(str(exc)) from None


def _result(stars: np.ndarray, solution, reason: str | None, width: int, height: int,
            time_ms: float, observer: Observer) -> SolveResult:
    rows = np.zeros(len(stars), RESULT_STAR_DTYPE)
    rows["flux"] = rows["snr"] = math.nan
    for name in ("x", "y", "flux", "snr", "flags"):
        if name in stars.dtype.names:
            rows[name] = stars[name]
    if solution is not None:
        rows["hip"] = solution.hip
    common = {"stars": rows, "width": width, "height": height, "time_ms": time_ms}
    if solution is not None and solution.ok:
        common["corrections"] = tuple(observer.to_json()["corrections"])
    if solution is None or not solution.ok:
        return SolveResult(ok=False, reason=solution.reason if solution is not None else reason,
                           **common)
    return SolveResult(ok=True, reason=None, ra_deg=float(solution.ra_deg),
                       dec_deg=float(solution.dec_deg), roll_deg=float(solution.roll_deg),
                       q=tuple(float(v) for v in solution.q), matched=int(solution.matched),
                       sigma_arcsec=float(solution.sigma_cross_arcsec),
                       sigma_roll_arcsec=float(solution.sigma_roll_arcsec),
                       prob_false=float(solution.prob_false), **common)


def solve(image, config=None, *, utc: str | None = None,
          observer_velocity_km_s=None) -> SolveResult:
    """Detect the stars of one image and solve its attitude lost in space.

    ``image``: a file path or an array (see the module docstring);
    ``config``: a YAML path, a Config, a mapping or None (the defaults);
    ``utc`` and ``observer_velocity_km_s``: when and how fast (module
    docstring). Raises :class:`~tracker.errors.UserError` for an unreadable
    file, a bad configuration or time, or an image whose size is not the
    camera's.
    """
    cfg = _config(config)
    observer = _observer(utc, observer_velocity_km_s)
    cam = cfg.camera
    where = ""
    if isinstance(image, (str, os.PathLike)):
        where = f"{Path(image).name}: "
        frame, bit_depth = read_image(Path(image), cam.bit_depth, (cam.width, cam.height))
    else:
        frame, bit_depth = as_frame(image, cam.bit_depth)
    height, width = frame.shape
    if (width, height) != (cam.width, cam.height):
        raise UserError(f"{where}image is {width}x{height} px, the camera configuration says "
                        f"{cam.width}x{cam.height}: give the configuration of the camera that "
                        "took it (camera.width, height, pixel_size_um, focal_length_mm)")
    with _lock:
        result = _pipeline(cfg).process(frame, bit_depth, 0, observer)
        stars = result.detections.stars.copy()
    return _result(stars, result.solution, result.solve_reason or result.detections.reason,
                   width, height, result.time_ms, observer)


def _centroid_rows(centroids) -> np.ndarray:
    """Records (x, y[, flux]) from (n, 2) x, y / (n, 3) x, y, flux / records with x, y[, flux].

    Without fluxes the order given is the brightness order and the solver
    skips its photometric check (tracker.identify.solver).
    """
    array = np.asarray(centroids)
    if array.dtype.names is not None:
        if not {"x", "y"} <= set(array.dtype.names):
            raise UserError(f"centroids: fields {array.dtype.names}, expected x, y and "
                            "optionally flux")
        columns = [array[name] for name in ("x", "y", "flux") if name in array.dtype.names]
    else:
        if array.ndim != 2 or array.shape[1] not in (2, 3) or array.dtype.kind not in "iuf":
            raise UserError(f"centroids: an array of shape {array.shape} ({array.dtype}), "
                            "expected n rows of x, y or of x, y, flux")
        columns = list(array.T)
    names = ("x", "y", "flux")[:len(columns)]
    rows = np.zeros(len(array), [(name, np.float64) for name in names])
    for name, column in zip(names, columns, strict=True):
        rows[name] = column
    if not all(np.all(np.isfinite(rows[name])) for name in names):
        raise UserError("centroids: NaN or infinity among the values")
    if "flux" in names:
        rows = rows[np.argsort(-rows["flux"], kind="stable")]
    return rows


def solve_centroids(centroids, config=None, *, utc: str | None = None,
                    observer_velocity_km_s=None) -> SolveResult:
    """Solve the attitude from star centroids (pixels of the configured camera).

    ``centroids``: an (n, 2) array-like of x, y, brightest first; (n, 3) of
    x, y, flux (any order: sorted by flux); or a record array with fields
    ``x``, ``y`` and optionally ``flux``. ``config``, ``utc`` and
    ``observer_velocity_km_s`` as for :func:`solve`. The result's ``stars``
    are the centroids, brightest first (flux and snr NaN where not given).
    """
    cfg = _config(config)
    observer = _observer(utc, observer_velocity_km_s)
    rows = _centroid_rows(centroids)
    with _lock:
        pipeline = _pipeline(cfg)
        if not cfg.identify.enabled:
            return _result(rows, None, "disabled", cfg.camera.width, cfg.camera.height, 0.0,
                           observer)
        solution = pipeline.solve_stars(rows, 0, observer)
    time_ms = sum(solution.stages_ms.values())
    return _result(rows, solution, None, cfg.camera.width, cfg.camera.height, time_ms,
                   observer)
