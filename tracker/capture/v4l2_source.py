"""Live raw frames from the Pi 5's camera front end through V4L2, without libcamera.

At open the rp1-cfe media graph is linked and every pad's format set
(:mod:`tracker.capture.mediactl`), then the video node ``rp1-cfe-csi2_ch0``
streams into ``capture.buffer_count`` memory-mapped buffers. Each frame is
dequeued when ready (waits cut into slices of
:data:`~tracker.capture.live.WAIT_SLICE_S`, yielding
:class:`~tracker.capture.base.Waiting`), converted into the next of a ring
of preallocated frames (:class:`~tracker.capture.rawformat.RawConverter`:
Y10P unpacked, Y16 shifted by ``capture.raw_shift``, GREY copied; a frame is
overwritten :data:`~tracker.capture.live.FRAME_BUFFERS` frames later) and
queued again at once.
A buffer the driver flags as an error becomes a ``FrameError``; a frame later
than its period plus ``capture.timeout_s`` too, and three late in a row raise
``CameraError``.

Controls live on the sensor's subdevice: ``EXPOSURE`` in lines (line time =
(width + HBLANK) / PIXEL_RATE), ``ANALOGUE_GAIN`` in
``capture.gain_code_per_x`` units per 1x (100 for arducam-pivariety, as its
libcamera helper), and ``VBLANK`` for the frame length: ``capture.fps``
sets it, lengthened when the exposure needs more (frame length >= exposure
+ 4 lines, as the Arducam helper's frameIntegrationDiff); it is set first,
since the exposure's range follows it. Values are clamped to the controls'
ranges. Frames report the exposure and gain last set (the
sensor applies them about two frames late; V4L2 gives no per-frame
metadata).

``t_ns``: the buffer's timestamp, which rp1-cfe takes on CLOCK_MONOTONIC at
the frame-start interrupt (``ktime_get_ns()`` in the SOF handler, cfe.c),
i.e. when readout begins; for a global-shutter sensor that is the end of the
exposure, so the mid-point is that minus half the exposure (the lag from the
exposure's end to the CSI-2 frame start is not measured: check on the Pi).
"""

from __future__ import annotations

import ctypes as C
import errno
import math
from collections.abc import Iterator

import numpy as np

from tracker.capture import v4l2_abi as abi
from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.live import (
    FRAME_BUFFERS,
    TIMEOUT_REASON,
    WAIT_SLICE_S,
    CameraError,
    LiveSource,
    frame_deadline_s,
)
from tracker.capture.mediactl import DeviceIO, Pipeline, find_pipeline, stream_errno_text
from tracker.capture.rawformat import RawConverter, RawFormatError, parse_format
from tracker.config import CaptureConfig

__all__ = ["V4L2Source", "SensorControls"]

_K = abi.CONST
_LATE_BEFORE_LOST = 3
_FRAME_INTEGRATION_DIFF = 4      # lines between the frame length and the longest exposure


class SensorControls:
    """Exposure (us), gain (x) and frame rate on the sensor subdevice's V4L2 controls."""

    def __init__(self, io: DeviceIO, fd: int, height: int, width: int, gain_code_per_x: float):
        self.io, self.fd, self.height = io, fd, height
        self.gain_code_per_x = gain_code_per_x
        self.ranges = {name: self._query(name) for name in
                       ("V4L2_CID_EXPOSURE", "V4L2_CID_ANALOGUE_GAIN", "V4L2_CID_VBLANK")}
        pixel_rate = self._get("V4L2_CID_PIXEL_RATE", 64)
        hblank = self._get("V4L2_CID_HBLANK", 32)
        self.line_s = (width + (hblank or 0)) / pixel_rate if pixel_rate else None
        self.vblank = self._get("V4L2_CID_VBLANK", 32)
        self.exposure_us = math.nan
        self.gain = math.nan

    def _query(self, name: str) -> tuple[int, int] | None:
        q = abi.QueryCtrl(id=_K[name])
        try:
            self.io.ioctl(self.fd, "VIDIOC_QUERYCTRL", q)
        except OSError:
            return None
        return q.minimum, q.maximum

    def _ext(self, request: str, values: dict[str, int], bits: int = 32) -> list[int]:
        ctrls = (abi.ExtControl * len(values))()
        for c, (name, value) in zip(ctrls, values.items(), strict=True):
            c.id = _K[name]
            if bits == 64:
                c.u.value64 = value
            else:
                c.u.value = value
        arg = abi.ExtControls(which=_K["V4L2_CTRL_WHICH_CUR_VAL"], count=len(values),
                              controls=C.cast(ctrls, C.POINTER(abi.ExtControl)))
        self.io.ioctl(self.fd, request, arg)
        return [c.u.value64 if bits == 64 else c.u.value for c in ctrls]

    def _get(self, name: str, bits: int) -> int | None:
        try:
            return self._ext("VIDIOC_G_EXT_CTRLS", {name: 0}, bits)[0]
        except OSError:
            return None

    @property
    def available(self) -> bool:
        """Whether exposure and gain can be set (their controls and the line time exist)."""
        return (self.line_s is not None and self.ranges["V4L2_CID_EXPOSURE"] is not None
                and self.ranges["V4L2_CID_ANALOGUE_GAIN"] is not None)

    @staticmethod
    def _clamp(value: float, limits: tuple[int, int] | None) -> int:
        value = int(round(value))
        return value if limits is None else min(max(value, limits[0]), limits[1])

    def apply(self, exposure_us: float, gain: float, fps: float) -> bool:
        """Set the frame length, then exposure and gain; False if the sensor lacks them.

        VBLANK goes first: the EXPOSURE control's range follows the frame length.
        """
        if not self.available:
            return False
        lines = exposure_us * 1e-6 / self.line_s
        if self.ranges["V4L2_CID_VBLANK"] is not None:
            want = (round(1.0 / (fps * self.line_s)) - self.height) if fps > 0 else 0
            want = max(want, math.ceil(lines) + _FRAME_INTEGRATION_DIFF - self.height)
            vblank = self._clamp(want, self.ranges["V4L2_CID_VBLANK"])
            self._set({"V4L2_CID_VBLANK": vblank})
            self.vblank = vblank
            self.ranges["V4L2_CID_EXPOSURE"] = self._query("V4L2_CID_EXPOSURE")
        values = {"V4L2_CID_EXPOSURE": self._clamp(lines, self.ranges["V4L2_CID_EXPOSURE"]),
                  "V4L2_CID_ANALOGUE_GAIN": self._clamp(gain * self.gain_code_per_x,
                                                        self.ranges["V4L2_CID_ANALOGUE_GAIN"])}
        self._set(values)
        self.exposure_us = values["V4L2_CID_EXPOSURE"] * self.line_s * 1e6
        self.gain = values["V4L2_CID_ANALOGUE_GAIN"] / self.gain_code_per_x
        return True

    def _set(self, values: dict[str, int]) -> None:
        try:
            self._ext("VIDIOC_S_EXT_CTRLS", values)
        except OSError as exc:
            raise CameraError(f"setting sensor controls {values}: {exc.strerror}") from None


class V4L2Source(LiveSource):
    """A FrameSource over rp1-cfe's raw video node; see the module docstring.

    ``shape`` is (rows, cols). ``io`` (tests) replaces the kernel.
    """

    name = "v4l2"

    def __init__(self, cfg: CaptureConfig, shape: tuple[int, int], *, io: DeviceIO | None = None):
        self.cfg = cfg
        self.shape = tuple(shape)
        self.io = io or DeviceIO()
        self.pipeline: Pipeline | None = None
        self.controls: SensorControls | None = None
        self._fds: list[int] = []
        self._video = -1
        self._maps: list = []
        self._views: list[np.ndarray] = []
        self._conv: RawConverter | None = None
        self._closed = False
        self._streaming = False
        self.granted = ""

    # -- set-up ----------------------------------------------------------------

    def _open_fd(self, path: str) -> int:
        try:
            fd = self.io.open(path)
        except OSError as exc:
            raise CameraError(f"cannot open {path}: {exc.strerror}") from None
        self._fds.append(fd)
        return fd

    def open(self) -> None:
        """Set up the graph, the buffers and the controls; start streaming. CameraError if not."""
        if self._streaming:
            return
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        cfg = self.cfg
        pipe = self.pipeline = find_pipeline(self.io, cfg.device, cfg.raw_format, self.shape)
        self.granted = pipe.describe()
        self._conv = RawConverter(parse_format(pipe.fmt.raw_format), self.shape, cfg.raw_shift,
                                  FRAME_BUFFERS)
        sensor = self._open_fd(pipe.sensor_subdev)
        self.controls = SensorControls(self.io, sensor, pipe.height, pipe.width,
                                       cfg.gain_code_per_x)
        self.controls.apply(cfg.exposure_us, cfg.gain, cfg.fps)
        self._video = self._open_fd(pipe.video)
        req = abi.RequestBuffers(count=cfg.buffer_count, type=_K["V4L2_BUF_TYPE_VIDEO_CAPTURE"],
                                 memory=_K["V4L2_MEMORY_MMAP"])
        self._ioctl("VIDIOC_REQBUFS", req, "asking for buffers")
        for index in range(req.count):
            buf = self._buffer(index)
            self._ioctl("VIDIOC_QUERYBUF", buf, f"buffer {index}")
            mapping = self.io.mmap(self._video, buf.length, buf.m.offset)
            self._maps.append(mapping)
            # no local name for the view: a traceback through here must not pin the mapping
            self._views.append(np.frombuffer(mapping, np.uint8, count=pipe.sizeimage)
                               .reshape(pipe.height, pipe.bytesperline))
            self._ioctl("VIDIOC_QBUF", buf, f"queueing buffer {index}")
        try:
            self.io.ioctl(self._video, "VIDIOC_STREAMON",
                          C.c_int(_K["V4L2_BUF_TYPE_VIDEO_CAPTURE"]))
        except OSError as exc:
            raise CameraError(f"{pipe.video}: STREAMON failed: "
                              f"{stream_errno_text(exc.errno or 0)}") from None
        self._streaming = True

    def _buffer(self, index: int = 0) -> abi.Buffer:
        return abi.Buffer(index=index, type=_K["V4L2_BUF_TYPE_VIDEO_CAPTURE"],
                          memory=_K["V4L2_MEMORY_MMAP"])

    def _ioctl(self, name: str, arg, what: str) -> None:
        try:
            self.io.ioctl(self._video, name, arg)
        except OSError as exc:
            raise CameraError(f"{self.pipeline.video}: {what}: {name} failed: "
                              f"{exc.strerror}") from None

    def set_controls(self, exposure_us: float, gain: float) -> bool:
        """New exposure (us) and analogue gain on the sensor; effective ~2 frames later."""
        if self.controls is None:
            return False
        return self.controls.apply(exposure_us, gain, self.cfg.fps)

    # -- frames ----------------------------------------------------------------

    def _exposure_us(self) -> float:
        exp = self.controls.exposure_us if self.controls else math.nan
        return self.cfg.exposure_us if math.isnan(exp) else exp

    def _dequeue(self, index: int) -> Frame | FrameError:
        buf = self._buffer()
        try:
            self.io.ioctl(self._video, "VIDIOC_DQBUF", buf)
        except OSError as exc:
            if exc.errno == errno.EAGAIN:
                return FrameError(index, "v4l2", "poll said ready, but no buffer was done")
            raise CameraError(f"{self.pipeline.video}: DQBUF failed: {exc.strerror}") from None
        try:
            if buf.flags & _K["V4L2_BUF_FLAG_ERROR"]:
                return FrameError(index, "v4l2", f"buffer {buf.index} flagged as an error "
                                  f"by the driver (sequence {buf.sequence})")
            image = self._conv.convert(self._views[buf.index])
        except RawFormatError as exc:
            return FrameError(index, "v4l2", str(exc))
        finally:
            self._ioctl("VIDIOC_QBUF", buf, f"requeueing buffer {buf.index}")
        stamp_ns = buf.timestamp.tv_sec * 1_000_000_000 + buf.timestamp.tv_usec * 1000
        monotonic = (buf.flags & _K["V4L2_BUF_FLAG_TIMESTAMP_MASK"]) == \
            _K["V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC"]
        if not monotonic:
            return FrameError(index, "v4l2", "buffer timestamp is not on CLOCK_MONOTONIC")
        exposure = self._exposure_us()
        gain = self.controls.gain if self.controls and self.controls.available else None
        return Frame(index, f"v4l2-{index:08d}", image, self._conv.bit_depth,
                     stamp_ns - int(500 * exposure),
                     exposure_us=exposure if self.controls.available else None, gain=gain,
                     meta={"sensor_timestamp_ns": stamp_ns, "sequence": buf.sequence})

    def __iter__(self) -> Iterator[Frame | FrameError | Waiting]:
        self.open()
        index = 0
        late = 0
        while not self._closed:
            deadline = frame_deadline_s(self.cfg.fps, self._exposure_us(), self.cfg.timeout_s)
            waited = 0.0
            while not self._closed and not self.io.poll(self._video, WAIT_SLICE_S):
                waited += WAIT_SLICE_S     # counted, not timed: the same run gives the same calls
                if waited >= deadline:
                    break
                yield Waiting(waited)
            if self._closed:
                return
            if waited >= deadline:
                late += 1
                if late >= _LATE_BEFORE_LOST:
                    raise CameraError(f"no frame in {late} x {deadline:g} s; camera lost")
                yield FrameError(index, "v4l2", f"{TIMEOUT_REASON} {deadline:g} s")
            else:
                late = 0
                yield self._dequeue(index)
            index += 1

    def close(self) -> None:
        self._closed = True
        if self._streaming:
            try:
                self.io.ioctl(self._video, "VIDIOC_STREAMOFF",
                              C.c_int(_K["V4L2_BUF_TYPE_VIDEO_CAPTURE"]))
            except OSError:
                pass
            self._streaming = False
        self._views.clear()
        for mapping in self._maps:
            mapping.close()
        self._maps.clear()
        for fd in self._fds:
            try:
                self.io.close(fd)
            except OSError:
                pass
        self._fds.clear()
