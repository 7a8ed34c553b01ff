"""Live frames from libcamera through picamera2 (Raspberry Pi OS only).

picamera2 is imported when the source opens, never at module import, so
this module loads on any machine. The camera is configured for the raw
stream at full sensor size with a small ``main`` stream (required by
picamera2, unused here), manual exposure and gain (auto-exposure off), and
``queue=False`` so every capture waits for a new frame.

Each frame is captured with ``captured_request`` (released on leaving the
block) and read through ``MappedArray`` (a view of the camera's dmabuf, no
copy); :class:`~tracker.capture.rawformat.RawConverter` copies or unpacks it
into one preallocated frame. The yielded ``Frame.image`` is that buffer,
overwritten by the next frame.

The granted raw format is checked at start: the Pi 5's lossy
``*_PISP_COMP*`` formats are refused, as is a size other than the camera
section's. Per frame: ``exposure_us`` and ``gain`` are what the sensor
reported (controls apply about two frames late), ``t_ns`` is the exposure
mid-point on CLOCK_MONOTONIC taking ``SensorTimestamp`` as the end of
exposure, as picamera2 itself does (unverified on the OV2311: measure it),
and ``meta`` holds the raw ``sensor_timestamp_ns``, ``frame_duration_us`` and
``sensor_temperature_c`` (None when the sensor reports none).
"""

from __future__ import annotations

import time
from collections.abc import Iterator

from tracker.capture.base import Frame, FrameError
from tracker.capture.live import TIMEOUT_REASON, CameraError, LiveSource, boottime_to_monotonic
from tracker.capture.rawformat import RawConverter, RawFormatError, parse_format
from tracker.config import CaptureConfig

__all__ = ["Picamera2Source"]

# Consecutive timeouts after which the camera counts as gone.
_TIMEOUTS_BEFORE_LOST = 3
# The unused processed stream picamera2 insists on; small to spare the ISP.
_MAIN_STREAM = {"size": (320, 260), "format": "YUV420"}


def _import_picamera2():
    try:
        from picamera2 import MappedArray, Picamera2
    except ImportError as exc:
        raise CameraError(f"picamera2 is not importable ({exc}); on Raspberry Pi OS install "
                          "python3-picamera2 and use a --system-site-packages venv") from None
    return Picamera2, MappedArray


class Picamera2Source(LiveSource):
    """A FrameSource over a picamera2 camera; see the module docstring.

    ``shape`` is (rows, cols). ``modules`` is ``(Picamera2, MappedArray)``,
    given by tests; by default picamera2 is imported on open.
    """

    name = "picamera2"

    def __init__(self, cfg: CaptureConfig, shape: tuple[int, int], *, modules=None):
        self.cfg = cfg
        self.shape = tuple(shape)
        self._modules = modules
        self._cam = None
        self._mapped = None
        self._conv: RawConverter | None = None
        self._closed = False
        self.granted: dict = {}

    # -- set-up ----------------------------------------------------------------

    def _controls(self, exposure_us: float, gain: float) -> dict:
        controls = {"AeEnable": False, "ExposureTime": int(round(exposure_us)),
                    "AnalogueGain": float(gain)}
        if self.cfg.fps > 0:
            period = int(round(1e6 / self.cfg.fps))
            controls["FrameDurationLimits"] = (period, period)
        return controls

    def open(self) -> None:
        """Open, configure and start the camera; CameraError if that fails."""
        if self._cam is not None:
            return
        picamera2_cls, self._mapped = self._modules or _import_picamera2()
        rows, cols = self.shape
        try:
            cam = picamera2_cls(int(self.cfg.device))
        except (IndexError, RuntimeError, ValueError, OSError) as exc:
            raise CameraError(f"no camera {self.cfg.device!r} ({exc})") from None
        try:
            config = cam.create_still_configuration(
                main=dict(_MAIN_STREAM), raw={"format": self.cfg.raw_format, "size": (cols, rows)},
                buffer_count=self.cfg.buffer_count, queue=False,
                controls=self._controls(self.cfg.exposure_us, self.cfg.gain))
            cam.configure(config)
            self.granted = dict(cam.camera_configuration()["raw"])
            fmt = parse_format(str(self.granted.get("format")))
            size = tuple(self.granted.get("size", ()))
            if size != (cols, rows):
                raise RawFormatError(f"camera granted a {size} raw stream, expected "
                                     f"{(cols, rows)} (camera.width, camera.height)")
            self._conv = RawConverter(fmt, self.shape, self.cfg.raw_shift)
            cam.start()
        except (RawFormatError, RuntimeError, KeyError, ValueError, OSError) as exc:
            cam.close()
            raise CameraError(f"camera configuration failed: {exc}") from None
        self._cam = cam

    def set_controls(self, exposure_us: float, gain: float) -> bool:
        """Ask for a new exposure (us) and analogue gain; effective ~2 frames later."""
        if self._cam is None:
            return False
        self._cam.set_controls(self._controls(exposure_us, gain))
        return True

    # -- frames ----------------------------------------------------------------

    def _capture(self, index: int) -> Frame:
        with self._cam.captured_request(wait=self.cfg.timeout_s) as request:
            with self._mapped(request, "raw") as mapped:
                image = self._conv.convert(mapped.array)
            md = request.get_metadata()
        exposure = md.get("ExposureTime")
        stamp = md.get("SensorTimestamp")
        if stamp:
            t_ns = boottime_to_monotonic(int(stamp)) - int(500 * (exposure or 0))
        else:
            t_ns = time.monotonic_ns()
        meta = {"sensor_timestamp_ns": stamp, "frame_duration_us": md.get("FrameDuration"),
                "sensor_temperature_c": md.get("SensorTemperature")}
        return Frame(index, f"picamera2-{index:08d}", image, self._conv.bit_depth, t_ns,
                     exposure_us=exposure, gain=md.get("AnalogueGain"), meta=meta)

    def __iter__(self) -> Iterator[Frame | FrameError]:
        self.open()
        index = 0
        timeouts = 0
        while not self._closed:
            try:
                item = self._capture(index)
                timeouts = 0
            except TimeoutError:
                timeouts += 1
                if timeouts >= _TIMEOUTS_BEFORE_LOST:
                    raise CameraError(f"no frame in {timeouts} x {self.cfg.timeout_s:g} s; "
                                      "camera lost") from None
                item = FrameError(index, "picamera2", f"{TIMEOUT_REASON} {self.cfg.timeout_s:g} s")
            except RawFormatError as exc:
                item = FrameError(index, "picamera2", str(exc))
            except (RuntimeError, OSError) as exc:
                raise CameraError(f"capture failed: {exc}") from None
            yield item
            index += 1

    def close(self) -> None:
        self._closed = True
        cam, self._cam = self._cam, None
        if cam is not None:
            try:
                cam.stop()
            finally:
                cam.close()
