"""Live frames from a V4L2 video node through OpenCV (no libcamera).

On a Pi 5 the sensor sits behind the rp1-cfe media graph, which must be set
up first with ``media-ctl`` (see PI5-NOTES.md section 3); exposure, gain and
frame rate are then sensor-subdevice controls (``v4l2-ctl -d
/dev/v4l-subdevN``), which OpenCV does not reach: :meth:`set_controls`
returns False and the service keeps the exposure it has.

OpenCV negotiates only unpacked mono palettes: ``GREY`` (8-bit) and
``Y16``/``Y10`` (16-bit words); packed ``Y10P`` is not supported, so
``capture.raw_format`` R8/R8_CSI2P asks for GREY and anything else for Y16.
Frames are retrieved into one preallocated buffer and converted into the
frame buffer (:class:`~tracker.capture.rawformat.RawConverter`); the yielded
image is overwritten by the next frame.

``t_ns`` is the driver's buffer timestamp (``CAP_PROP_POS_MSEC``,
CLOCK_MONOTONIC on V4L2) minus half the configured exposure; unverified on
the Pi.
"""

from __future__ import annotations

import time
from collections.abc import Iterator

import cv2
import numpy as np

from tracker.capture.base import Frame, FrameError
from tracker.capture.live import TIMEOUT_REASON, CameraError, LiveSource
from tracker.capture.rawformat import RawConverter, RawFormatError, parse_format
from tracker.config import CaptureConfig

__all__ = ["V4L2Source", "fourcc_name"]

_FAILURES_BEFORE_LOST = 3
# V4L2 fourcc -> the raw format it carries.
_PALETTES = {"GREY": "R8", "Y16 ": "R16", "Y10 ": "R10"}


def fourcc_name(code: float) -> str:
    """The four characters of an OpenCV CAP_PROP_FOURCC value."""
    value = int(code)
    return "".join(chr((value >> (8 * k)) & 0xFF) for k in range(4))


class V4L2Source(LiveSource):
    """A FrameSource over a V4L2 node via ``cv2.VideoCapture``; see the module docstring.

    ``shape`` is (rows, cols). ``opener(device, api)`` makes the capture
    object (``cv2.VideoCapture`` unless a test gives another).
    """

    name = "v4l2"

    def __init__(self, cfg: CaptureConfig, shape: tuple[int, int], *, opener=None):
        self.cfg = cfg
        self.shape = tuple(shape)
        self._opener = opener or cv2.VideoCapture
        self._cap = None
        self._conv: RawConverter | None = None
        self._raw: np.ndarray | None = None
        self._closed = False
        self.granted = ""

    def open(self) -> None:
        """Open the node and negotiate size and palette; CameraError if that fails."""
        if self._cap is not None:
            return
        dev = self.cfg.device
        cap = self._opener(int(dev) if dev.isdigit() else dev, cv2.CAP_V4L2)
        if not cap.isOpened():
            raise CameraError(f"cannot open V4L2 device {dev!r}")
        rows, cols = self.shape
        want = "GREY" if self.cfg.raw_format.startswith("R8") else "Y16 "
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*want))
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, cols)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, rows)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, self.cfg.buffer_count)
        cap.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(self.cfg.timeout_s * 1000))
        if self.cfg.fps > 0:
            cap.set(cv2.CAP_PROP_FPS, self.cfg.fps)
        self.granted = fourcc_name(cap.get(cv2.CAP_PROP_FOURCC))
        size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        try:
            if self.granted not in _PALETTES:
                raise RawFormatError(f"device granted pixel format {self.granted!r}, expected "
                                     f"one of {', '.join(map(repr, _PALETTES))}")
            if size != (cols, rows):
                raise RawFormatError(f"device granted {size[0]}x{size[1]}, expected {cols}x{rows}")
            fmt = parse_format(_PALETTES[self.granted])
            self._conv = RawConverter(fmt, self.shape, self.cfg.raw_shift)
        except RawFormatError as exc:
            cap.release()
            raise CameraError(str(exc)) from None
        self._raw = np.zeros(self.shape, self._conv.frame.dtype)
        self._cap = cap

    def set_controls(self, exposure_us: float, gain: float) -> bool:
        """Not reachable through OpenCV on the Pi 5 CFE; see the module docstring."""
        return False

    def _read(self, index: int) -> Frame | FrameError | None:
        if not self._cap.grab():
            return None
        ok, image = self._cap.retrieve(self._raw)
        if not ok or image is None:
            return FrameError(index, "v4l2", "frame grabbed but not retrievable")
        try:
            frame = self._conv.convert(image)
        except RawFormatError as exc:
            return FrameError(index, "v4l2", str(exc))
        stamp_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
        half_exposure_ns = int(500 * self.cfg.exposure_us)
        t_ns = int(stamp_ms * 1e6) - half_exposure_ns if stamp_ms > 0 else time.monotonic_ns()
        return Frame(index, f"v4l2-{index:08d}", frame, self._conv.bit_depth, t_ns,
                     exposure_us=None, gain=None, meta={"sensor_timestamp_ns": int(stamp_ms * 1e6)})

    def __iter__(self) -> Iterator[Frame | FrameError]:
        self.open()
        index = 0
        failures = 0
        while not self._closed:
            item = self._read(index)
            if item is None:
                failures += 1
                if failures >= _FAILURES_BEFORE_LOST:
                    raise CameraError(f"no frame from {self.cfg.device!r} in {failures} tries; "
                                      "camera lost")
                item = FrameError(index, "v4l2", f"{TIMEOUT_REASON} {self.cfg.timeout_s:g} s")
            else:
                failures = 0
            yield item
            index += 1

    def close(self) -> None:
        self._closed = True
        cap, self._cap = self._cap, None
        if cap is not None:
            cap.release()
