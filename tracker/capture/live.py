"""What the live backends (picamera2, V4L2) share: errors, waiting, clocks.

A live source raises :class:`CameraError` from its iterator when the camera
is gone or cannot be configured (the daemon closes it, waits and opens a
new one); a single late or bad frame is yielded as a
:class:`~tracker.capture.base.FrameError` instead and the stream goes on.
While it waits for a frame it yields :class:`~tracker.capture.base.Waiting`
at least every :data:`WAIT_SLICE_S` seconds, so the daemon keeps feeding
systemd's watchdog at any frame rate. A frame is late (``FrameError`` with
:data:`TIMEOUT_REASON`) when it has not come within the frame period plus
``capture.timeout_s``. Live sources also offer ``set_controls(exposure_us,
gain)``.

Frames: a live source writes its frames into a ring of :data:`FRAME_BUFFERS`
preallocated images (tracker.capture.rawformat.RawConverter); a frame's
image is overwritten when the source is asked for the frame
``FRAME_BUFFERS`` after it. ``live`` and ``frame_buffers`` on the source
tell its consumer so (tracker.daemon.capture_ahead).

Times: ``Frame.t_ns`` is the exposure mid-point on CLOCK_MONOTONIC.
libcamera stamps frames on CLOCK_BOOTTIME; :func:`boottime_to_monotonic`
converts (the two clocks differ by the time spent suspended).
"""

from __future__ import annotations

import time

__all__ = ["CameraError", "TIMEOUT_REASON", "WAIT_SLICE_S", "FRAME_BUFFERS", "LiveSource",
           "boottime_to_monotonic", "frame_deadline_s"]

# FrameError.reason of a frame that did not arrive in time starts with this.
TIMEOUT_REASON = "no frame within"
# Longest a live source blocks before it yields Waiting.
WAIT_SLICE_S = 0.25
# Frames a live source keeps valid at once: one processed, one waiting, one being captured.
FRAME_BUFFERS = 3


class CameraError(RuntimeError):
    """The camera vanished, timed out for good or refused its configuration."""


class LiveSource:
    """Context-manager part of the FrameSource protocol for the live backends.

    ``live``: frames come from a running camera, which does not wait for its
    consumer; ``frame_buffers``: the ring of images frames are written into.
    """

    live = True
    frame_buffers = FRAME_BUFFERS

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def frame_deadline_s(fps: float, exposure_us: float, timeout_s: float) -> float:
    """Seconds to wait for one frame before it is late: its period plus ``timeout_s``.

    The period is 1/fps, or (fps 0: the camera runs as fast as the exposure
    allows) the exposure time.
    """
    period = 1.0 / fps if fps > 0 else exposure_us * 1e-6
    return period + timeout_s


def boottime_to_monotonic(t_boot_ns: int) -> int:
    """A CLOCK_BOOTTIME instant expressed on CLOCK_MONOTONIC, in ns."""
    offset = time.clock_gettime_ns(time.CLOCK_BOOTTIME) - time.monotonic_ns()
    return t_boot_ns - offset
