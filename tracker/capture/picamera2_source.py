"""Live frames from libcamera through picamera2 (Raspberry Pi OS only).

picamera2 is imported when the source opens, never at module import, so
this module loads on any machine. The camera is configured for the raw
stream at full sensor size (``sensor={'output_size', 'bit_depth'}`` picks
the sensor mode explicitly) with a small ``main`` stream (required by
picamera2, unused here), manual exposure and gain (auto-exposure off), and
``queue=False`` so every capture waits for a new frame.

Versions (checked at open, and by ``tracker selftest``): picamera2 0.3.20
or later, which can time out a capture and cancel it
(``cancel_all_and_flush``); and, with a libcamera that lacks the
``ExposureTimeMode`` control (Arducam's 0.3.x build for the OV2311
Pivariety), at most 0.3.25: from 0.3.26 picamera2 sets that control with
every request and fails on such a libcamera. ``tools/install_pi.sh`` pins
python3-picamera2 accordingly.

Each capture is a picamera2 *job* (``capture_request(wait=False)``) waited
for in slices of :data:`~tracker.capture.live.WAIT_SLICE_S`, yielding
:class:`~tracker.capture.base.Waiting` between them. A frame not there
within its period plus ``capture.timeout_s`` is late: the job is cancelled
with ``cancel_all_and_flush()`` (picamera2's own way out: a timed-out job
otherwise stays queued, later takes a request nobody releases, and makes
``stop()`` wait behind it for ever), a request that completed in between is
released, and a ``FrameError`` is yielded; three late frames in a row raise
``CameraError`` (the daemon closes and reopens the camera). ``close()``
cancels any job before ``stop()``. ``open()`` closes the camera again on
any failure after it was acquired.

A request is read through ``MappedArray(..., write=False)`` (a read-only
view of the camera's dmabuf, no copy); :class:`~tracker.capture.rawformat.
RawConverter` copies or unpacks it into the next of a ring of
preallocated frames, and the request is released at once. The yielded
``Frame.image`` is that buffer, overwritten by the frame
:data:`~tracker.capture.live.FRAME_BUFFERS` later.

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

import logging
import time
from collections.abc import Iterator

from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.live import (
    FRAME_BUFFERS,
    TIMEOUT_REASON,
    WAIT_SLICE_S,
    CameraError,
    LiveSource,
    boottime_to_monotonic,
    frame_deadline_s,
)
from tracker.capture.rawformat import RawConverter, RawFormatError, parse_format
from tracker.config import CaptureConfig

__all__ = ["Picamera2Source", "compatibility_problem", "installed_versions", "MIN_VERSION",
           "LAST_VERSION_WITHOUT_EXPOSURE_MODE"]

log = logging.getLogger(__name__)

# picamera2 0.3.20 added captured_request(wait=seconds) and cancel_all_and_flush().
MIN_VERSION = (0, 3, 20)
# picamera2 0.3.26 sets ExposureTimeMode/AnalogueGainMode, which libcamera < 0.5 lacks.
LAST_VERSION_WITHOUT_EXPOSURE_MODE = (0, 3, 25)
# Late frames in a row after which the camera counts as gone.
_LATE_BEFORE_LOST = 3
# The unused processed stream picamera2 insists on; small to spare the ISP.
_MAIN_STREAM = {"size": (320, 260), "format": "YUV420"}


def _version_tuple(text: str) -> tuple[int, ...]:
    parts = []
    for word in text.replace("-", ".").split("."):
        if not word.isdigit():
            break
        parts.append(int(word))
    return tuple(parts)


def _dotted(version: tuple[int, ...]) -> str:
    return ".".join(map(str, version))


def compatibility_problem(picamera2_version: str | None,
                          has_exposure_time_mode: bool | None) -> str | None:
    """Why this picamera2 / libcamera pair cannot run the tracker, or None if it can.

    ``picamera2_version`` as installed (None if unknown); ``has_exposure_time_mode``
    whether libcamera's controls include ExposureTimeMode (None if unknown).
    """
    if picamera2_version is None:
        return None
    version = _version_tuple(picamera2_version)
    if version < MIN_VERSION:
        return (f"picamera2 {picamera2_version} is too old: the tracker needs >= "
                f"{_dotted(MIN_VERSION)} (captures that time out and can be cancelled)")
    if version > LAST_VERSION_WITHOUT_EXPOSURE_MODE and has_exposure_time_mode is False:
        return (f"picamera2 {picamera2_version} sets ExposureTimeMode, which this libcamera "
                "(Arducam's 0.3.x?) lacks: install python3-picamera2 "
                f"{_dotted(MIN_VERSION)} .. {_dotted(LAST_VERSION_WITHOUT_EXPOSURE_MODE)} "
                "and hold it (tools/install_pi.sh does)")
    return None


def installed_versions() -> tuple[str | None, bool | None]:
    """(picamera2 version, whether libcamera has ExposureTimeMode); None where unknown."""
    from importlib import metadata

    try:
        version = metadata.version("picamera2")
    except metadata.PackageNotFoundError:
        version = None
    try:
        import libcamera
    except ImportError:
        return version, None
    return version, hasattr(libcamera.controls, "ExposureTimeMode")


def _import_picamera2():
    try:
        from picamera2 import MappedArray, Picamera2
    except ImportError as exc:
        raise CameraError(f"picamera2 is not importable ({exc}); on Raspberry Pi OS install "
                          "python3-picamera2 and use a --system-site-packages venv") from None
    return Picamera2, MappedArray, installed_versions()


def _camera_error(what: str, exc: Exception) -> CameraError:
    text = f"{what} ({type(exc).__name__}: {exc})"
    if "busy" in str(exc).lower():
        text += ("; another process holds the camera (is the startracker service running? "
                 "sudo systemctl stop startracker)")
    return CameraError(text)


class Picamera2Source(LiveSource):
    """A FrameSource over a picamera2 camera; see the module docstring.

    ``shape`` is (rows, cols); ``sensor_bit_depth`` the sensor mode's depth
    (``camera.bit_depth``). ``modules`` is ``(Picamera2, MappedArray,
    (picamera2 version, has ExposureTimeMode))``, given by tests; by default
    picamera2 is imported on open.
    """

    name = "picamera2"

    def __init__(self, cfg: CaptureConfig, shape: tuple[int, int], *,
                 sensor_bit_depth: int = 10, modules=None):
        self.cfg = cfg
        self.shape = tuple(shape)
        self.sensor_bit_depth = 8 if cfg.raw_format.startswith("R8") else sensor_bit_depth
        self._modules = modules
        self._cam = None
        self._mapped = None
        self._conv: RawConverter | None = None
        self._closed = False
        self._exposure_us = float(cfg.exposure_us)
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
        picamera2_cls, self._mapped, versions = self._modules or _import_picamera2()
        problem = compatibility_problem(*versions)
        if problem:
            raise CameraError(problem)
        rows, cols = self.shape
        try:
            cam = picamera2_cls(int(self.cfg.device))
        except Exception as exc:      # no camera, busy, a bad number: nothing to release
            raise _camera_error(f"no camera {self.cfg.device!r}", exc) from None
        if not callable(getattr(cam, "cancel_all_and_flush", None)):
            cam.close()
            raise CameraError(compatibility_problem("0", None))   # too old, whatever it says
        try:
            config = cam.create_still_configuration(
                main=dict(_MAIN_STREAM), raw={"format": self.cfg.raw_format, "size": (cols, rows)},
                sensor={"output_size": (cols, rows), "bit_depth": self.sensor_bit_depth},
                buffer_count=self.cfg.buffer_count, queue=False,
                controls=self._controls(self.cfg.exposure_us, self.cfg.gain))
            cam.configure(config)
            self.granted = dict(cam.camera_configuration()["raw"])
            fmt = parse_format(str(self.granted.get("format")))
            size = tuple(self.granted.get("size", ()))
            if size != (cols, rows):
                raise RawFormatError(f"camera granted a {size} raw stream, expected "
                                     f"{(cols, rows)} (camera.width, camera.height)")
            self._conv = RawConverter(fmt, self.shape, self.cfg.raw_shift, FRAME_BUFFERS)
            cam.start()
        except Exception as exc:      # whatever failed, the camera is released again
            try:
                self._release(cam)
            except Exception as close_exc:
                log.warning("releasing the camera after a failed open: %s", close_exc)
            raise _camera_error("camera configuration failed", exc) from None
        self._cam = cam

    def set_controls(self, exposure_us: float, gain: float) -> bool:
        """Ask for a new exposure (us) and analogue gain; effective ~2 frames later."""
        if self._cam is None:
            return False
        self._cam.set_controls(self._controls(exposure_us, gain))
        self._exposure_us = float(exposure_us)
        return True

    # -- frames ----------------------------------------------------------------

    def _read(self, index: int, request) -> Frame | FrameError:
        """The frame in a completed request, which is released before returning."""
        try:
            with self._mapped(request, "raw", write=False) as mapped:
                image = self._conv.convert(mapped.array)
            md = request.get_metadata()
        except RawFormatError as exc:
            return FrameError(index, "picamera2", str(exc))
        finally:
            request.release()
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

    def _cancel(self, job) -> None:
        """Drop a capture job that is late; release its request if it completed meanwhile."""
        self._cam.cancel_all_and_flush()
        try:
            request = job.get_result(timeout=0)
        except Exception:            # CancelledError (the usual case) or still pending
            return
        request.release()

    def _wait(self, job) -> Iterator[Waiting | object | None]:
        """Waiting items while the job runs, then its request (None if it was late)."""
        deadline = frame_deadline_s(self.cfg.fps, self._exposure_us, self.cfg.timeout_s)
        waited = 0.0
        while True:
            try:
                yield self._cam.wait(job, timeout=WAIT_SLICE_S)
                return
            except TimeoutError:
                waited += WAIT_SLICE_S    # counted, not timed: the same run gives the same calls
            except Exception as exc:
                raise _camera_error("capture failed", exc) from None
            if waited >= deadline or self._closed:
                self._cancel(job)
                yield None
                return
            yield Waiting(waited)

    def __iter__(self) -> Iterator[Frame | FrameError | Waiting]:
        self.open()
        index = 0
        late = 0
        while not self._closed:
            job = self._cam.capture_request(wait=False)
            request = None
            for item in self._wait(job):
                if isinstance(item, Waiting):
                    yield item
                else:
                    request = item
            if self._closed:
                if request is not None:
                    request.release()
                return
            if request is None:
                late += 1
                deadline = frame_deadline_s(self.cfg.fps, self._exposure_us, self.cfg.timeout_s)
                if late >= _LATE_BEFORE_LOST:
                    raise CameraError(f"no frame in {late} x {deadline:g} s; camera lost")
                yield FrameError(index, "picamera2", f"{TIMEOUT_REASON} {deadline:g} s")
            else:
                late = 0
                yield self._read(index, request)
            index += 1

    # -- closing ---------------------------------------------------------------

    @staticmethod
    def _release(cam) -> None:
        """Cancel queued jobs (else stop() waits behind them for ever), stop, close."""
        try:
            cam.cancel_all_and_flush()
            cam.stop()
        finally:
            cam.close()

    def close(self) -> None:
        self._closed = True
        cam, self._cam = self._cam, None
        if cam is not None:
            self._release(cam)
