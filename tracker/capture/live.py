"""What the live backends share, and the factory that picks a backend by name.

A live source raises :class:`CameraError` from its iterator when the camera
is gone or cannot be configured (the service closes it, waits and opens a
new one); a single late or bad frame is yielded as a
:class:`~tracker.capture.base.FrameError` instead and the stream goes on.
Live sources also offer ``set_controls(exposure_us, gain)``.

Times: ``Frame.t_ns`` is the exposure mid-point on CLOCK_MONOTONIC.
libcamera stamps frames on CLOCK_BOOTTIME; :func:`boottime_to_monotonic`
converts (the two clocks differ by the time spent suspended).
"""

from __future__ import annotations

import time
from pathlib import Path

from tracker.config import Config

__all__ = ["CameraError", "TIMEOUT_REASON", "LiveSource", "boottime_to_monotonic",
           "make_source", "cpu_temperature_c"]

# FrameError.reason of a frame that did not arrive in time starts with this.
TIMEOUT_REASON = "no frame within"

_THERMAL = Path("/sys/class/thermal/thermal_zone0/temp")


class CameraError(RuntimeError):
    """The camera vanished, timed out for good or refused its configuration."""


class LiveSource:
    """Context-manager part of the FrameSource protocol for the live backends."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def boottime_to_monotonic(t_boot_ns: int) -> int:
    """A CLOCK_BOOTTIME instant expressed on CLOCK_MONOTONIC, in ns."""
    offset = time.clock_gettime_ns(time.CLOCK_BOOTTIME) - time.monotonic_ns()
    return t_boot_ns - offset


def cpu_temperature_c(path: Path = _THERMAL) -> float | None:
    """SoC temperature in degrees C from sysfs, or None where there is none."""
    try:
        return int(path.read_text().strip()) / 1000.0
    except (OSError, ValueError):
        return None


def make_source(cfg: Config, paths: list[str] | None = None):
    """A new FrameSource for ``cfg.capture.backend``.

    ``paths`` (replay only) overrides ``capture.replay_path``. Live backends
    are imported here, so picamera2 is loaded only when it is chosen.
    Raises FileNotFoundError when replay has nothing to read.
    """
    cap = cfg.capture
    shape = (cfg.camera.height, cfg.camera.width)
    if cap.backend == "picamera2":
        from tracker.capture.picamera2_source import Picamera2Source

        return Picamera2Source(cap, shape)
    if cap.backend == "v4l2":
        from tracker.capture.v4l2_source import V4L2Source

        return V4L2Source(cap, shape)
    from tracker.capture.replay import ReplaySource

    paths = list(paths or ([cap.replay_path] if cap.replay_path else []))
    if not paths:
        raise FileNotFoundError("replay backend: no frames given (capture.replay_path or "
                                "--replay PATH)")
    return ReplaySource(paths, loop=cap.loop, fps=cap.fps, bits16_depth=cfg.camera.bit_depth,
                        expect_shape=shape)
