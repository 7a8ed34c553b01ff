"""tracker: a star tracker for a Raspberry Pi 5 with an OV2311 camera.

Each frame flows one way::

    capture -> detect -> identify -> attitude -> link

* :mod:`tracker.capture` delivers frames (replayed files; picamera2 or V4L2
  on the Pi) as :class:`~tracker.capture.base.Frame` or
  :class:`~tracker.capture.base.FrameError`
  (``tracker.capture.backends.make_source(cfg)`` picks the backend).
* :mod:`tracker.detect` finds stars with a fixed-memory detector
  (``make_detector(cfg.detect, shape, bit_depth).detect(image)``).
* :mod:`tracker.identify` identifies them lost in space (four-star patterns
  whose code does not depend on the focal length, so a lens label a few
  percent off is found) or by tracking, and solves the attitude and the
  focal length (``make_solver(cfg.identify, camera, catalogue)``; the
  pattern database for the field is built once into a cache);
  :mod:`tracker.attitude` holds the conventions and Wahba's problem.
* :mod:`tracker.protocol` frames packets for the flight computer, as
  ``docs/protocol.md`` specifies, and runs the serial link.
* :mod:`tracker.pipeline` chains detect and identify for one frame (shared
  by ``tracker replay`` and the daemon).
* :mod:`tracker.daemon` is what ``tracker run`` and systemd run: the frame
  loop, its modes, the daemon's side of the link (FC commands in as values,
  STATUS out as a snapshot), exposure control, health and sd_notify.
* :mod:`tracker.astrometry` holds time (TAI on the wire, UTC at the edges),
  the Earth's velocity and aberration; each frame's
  :class:`~tracker.astrometry.observer.Observer` (its absolute time and the
  observer's velocity) goes with it to the solver, which then reports the
  ICRS attitude.
* :mod:`tracker.focus` maps the PSF's width across the field for
  ``tracker focus``.
* :mod:`tracker.sim` renders synthetic frames with truth;
  :mod:`tracker.catalogue` loads the bundled Hipparcos stars;
  :mod:`tracker.camera` maps pixels to directions.

The library API is three names at the package root (loaded on first use,
so ``import tracker`` stays light): :func:`tracker.solve` (an image file or
array -> attitude), :func:`tracker.solve_centroids` (star centroids ->
attitude) and :class:`tracker.UserError` (what both raise for a mistake a
caller can fix); see :mod:`tracker.api`.

Conventions: pixel (0, 0) is the centre of the top-left pixel, x = column,
y = row; camera +Z is the boresight, +X toward increasing x; the attitude
quaternion [w, x, y, z] (w >= 0) rotates ICRS into the camera frame
(v_cam = R v_icrs); radians inside, degrees and arcseconds only at the
edges with the unit in the name. The README says how to run everything.
"""

__version__ = "0.1.0"

__all__ = ["solve", "solve_centroids", "SolveResult", "UserError", "__version__"]

_LAZY = {"solve": "tracker.api", "solve_centroids": "tracker.api",
         "SolveResult": "tracker.api", "UserError": "tracker.errors"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tracker' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
