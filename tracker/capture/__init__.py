"""Frame sources: replay of files here; picamera2 and V4L2 on the Pi.

Live backends import their hardware libraries lazily, only when chosen.
"""

from tracker.capture.base import Frame, FrameError, FrameSource, Waiting
from tracker.capture.replay import ReplaySource

__all__ = ["Frame", "FrameError", "FrameSource", "ReplaySource", "Waiting"]
