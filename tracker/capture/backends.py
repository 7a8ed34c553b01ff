"""The backend registry: a new FrameSource for ``capture.backend``.

Live backends are imported here, when chosen, so picamera2 is loaded only on
the Pi and only when it is the configured backend.
"""

from __future__ import annotations

from tracker.config import Config

__all__ = ["make_source", "BACKENDS"]

BACKENDS = ("replay", "picamera2", "v4l2")


def make_source(cfg: Config, paths: list[str] | None = None):
    """A new FrameSource for ``cfg.capture.backend``.

    ``paths`` (replay only) overrides ``capture.replay_path``. Raises
    FileNotFoundError when replay has nothing to read.
    """
    cap = cfg.capture
    shape = (cfg.camera.height, cfg.camera.width)
    if cap.backend == "picamera2":
        from tracker.capture.picamera2_source import Picamera2Source

        return Picamera2Source(cap, shape, sensor_bit_depth=cfg.camera.bit_depth)
    if cap.backend == "v4l2":
        from tracker.capture.v4l2_source import V4L2Source

        return V4L2Source(cap, shape)
    from tracker.capture.replay import ReplaySource

    paths = list(paths or ([cap.replay_path] if cap.replay_path else []))
    if not paths:
        raise FileNotFoundError("replay backend: no frames given (capture.replay_path or "
                                "--replay PATH)")
    return ReplaySource(paths, loop=cap.loop, fps=cap.fps, bits16_depth=cfg.camera.bit_depth,
                        expect_shape=shape, interval_s=cap.replay_interval_s)
