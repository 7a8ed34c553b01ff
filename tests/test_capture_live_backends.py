"""picamera2 and V4L2 backends through their adapters, with a real frame behind fakes.

The fakes stand in for picamera2.Picamera2/MappedArray and cv2.VideoCapture
and serve a real star image (data/real/openstartracker/img0.png, scaled to
10 bits) in the buffer layouts the Pi delivers. Pixels must come out
bit-exact; times within 1 ms of the conversion done here independently
(the BOOTTIME-MONOTONIC offset is read at two slightly different instants).
"""

import contextlib
import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from tracker.capture.base import Frame, FrameError
from tracker.capture.imagefile import read_image
from tracker.capture.live import CameraError
from tracker.capture.picamera2_source import Picamera2Source
from tracker.capture.v4l2_source import V4L2Source
from tracker.config import CaptureConfig

REAL = Path(__file__).resolve().parents[2] / "shared/data/real/openstartracker/img0.png"


@pytest.fixture(name="star10", scope="module")
def fixture_star10():
    """A real star field as 10-bit values (8-bit x 4 + 3), shape (1040, 1392)."""
    if not REAL.exists():
        pytest.skip(f"{REAL} not present")
    image, _ = read_image(REAL)
    return image.astype(np.uint16) * 4 + 3


def r16_buffer(image: np.ndarray, shift: int, pad: int = 64) -> np.ndarray:
    """(rows, stride) uint8 as libcamera hands out R16: words << shift, padded rows."""
    rows, cols = image.shape
    buf = np.zeros((rows, 2 * cols + pad), np.uint8)
    buf[:, : 2 * cols] = (image << shift).astype("<u2").view(np.uint8)
    return buf


# --------------------------------------------------------------------------- picamera2


class FakeRequest:
    def __init__(self, buf, md):
        self.buf, self.md, self.released = buf, md, False

    def get_metadata(self):
        return dict(self.md)

    def release(self):
        self.released = True


class FakeMappedArray:
    def __init__(self, request, stream):
        assert stream == "raw"
        self.array = request.buf

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class FakePicamera2:
    """Serves a script: FakeRequest items, or exceptions to raise from the capture."""

    def __init__(self, script, granted="R16"):
        self.script, self.granted = list(script), granted
        self.config = self.controls = None
        self.started = self.closed = False
        self.served = []

    def create_still_configuration(self, **kw):
        return kw

    def configure(self, config):
        self.config = config

    def camera_configuration(self):
        return {"raw": {"format": self.granted, "size": self.config["raw"]["size"]}}

    def start(self):
        self.started = True

    def stop(self):
        self.started = False

    def close(self):
        self.closed = True

    def set_controls(self, controls):
        self.controls = controls

    @contextlib.contextmanager
    def captured_request(self, wait=None):
        item = self.script.pop(0)
        if isinstance(item, BaseException):
            raise item
        self.served.append(item)
        try:
            yield item
        finally:
            item.release()


def picamera2_source(script, shape, granted="R16", **cfg):
    cam = FakePicamera2(script, granted)
    cfg = dataclasses.replace(CaptureConfig(), backend="picamera2", **cfg)
    return Picamera2Source(cfg, shape, modules=(lambda num: cam, FakeMappedArray)), cam


def boot_ns(mono_ns: int) -> int:
    return mono_ns + time.clock_gettime_ns(time.CLOCK_BOOTTIME) - time.monotonic_ns()


def test_picamera2_frames_are_bit_exact_with_sensor_metadata(star10):
    t_end = time.monotonic_ns()
    md = {"SensorTimestamp": boot_ns(t_end), "ExposureTime": 20000, "AnalogueGain": 4.0,
          "FrameDuration": 100000}
    script = [FakeRequest(r16_buffer(star10 + k, 6), md) for k in range(3)]
    source, cam = picamera2_source(script, star10.shape, raw_shift=6)
    frames = []
    with source:
        for item in source:
            assert isinstance(item, Frame)
            np.testing.assert_array_equal(item.image, star10 + item.index)
            frames.append(item)
            if len(frames) == 3:
                break
    assert all(f.image is frames[0].image for f in frames)   # one reused buffer
    assert all(r.released for r in cam.served)
    f = frames[0]
    assert (f.bit_depth, f.exposure_us, f.gain) == (10, 20000, 4.0)
    # mid-exposure = end - exposure/2 = t_end - 10 ms, on the monotonic clock
    assert abs(f.t_ns - (t_end - 10_000_000)) < 1_000_000
    assert cam.closed


def test_picamera2_asks_for_manual_raw_capture():
    shape = (1300, 1600)
    source, cam = picamera2_source([], shape, exposure_us=5000.0, gain=2.0, fps=10.0,
                                   buffer_count=3)
    source.open()
    assert cam.config["raw"] == {"format": "R16", "size": (1600, 1300)}
    assert cam.config["queue"] is False and cam.config["buffer_count"] == 3
    assert cam.config["controls"] == {"AeEnable": False, "ExposureTime": 5000,
                                      "AnalogueGain": 2.0,
                                      "FrameDurationLimits": (100000, 100000)}
    assert source.set_controls(1234.4, 3.5)
    assert (cam.controls["ExposureTime"], cam.controls["AnalogueGain"]) == (1234, 3.5)
    source.close()


def test_picamera2_refuses_the_compressed_pi5_format():
    source, cam = picamera2_source([], (1300, 1600), granted="MONO_PISP_COMP1")
    with pytest.raises(CameraError, match="MONO_PISP_COMP1, a lossy compressed raw format"):
        source.open()
    assert cam.closed


def test_picamera2_timeouts_become_errors_then_camera_lost(star10):
    good = FakeRequest(r16_buffer(star10, 6), {"ExposureTime": 100, "AnalogueGain": 1.0})
    script = [TimeoutError(), good, TimeoutError(), TimeoutError(), TimeoutError()]
    source, _ = picamera2_source(script, star10.shape)
    items = []
    with pytest.raises(CameraError, match="no frame in 3 x 2 s; camera lost"):
        for item in source:
            items.append(item)
    assert [type(i).__name__ for i in items] == ["FrameError", "Frame", "FrameError",
                                                 "FrameError"]
    assert items[0].reason == "no frame within 2 s"


def test_picamera2_short_buffer_is_a_frame_error_and_the_request_is_released(star10):
    short = FakeRequest(np.zeros((10, 10), np.uint8), {})
    source, cam = picamera2_source([short, RuntimeError("device gone")], star10.shape)
    iterator = iter(source)
    item = next(iterator)
    assert isinstance(item, FrameError) and "too small" in item.reason
    assert short.released
    with pytest.raises(CameraError, match="capture failed: device gone"):
        next(iterator)


def test_picamera2_missing_is_a_camera_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "picamera2", None)      # import fails as off the Pi
    source = Picamera2Source(CaptureConfig(), (1300, 1600))
    with pytest.raises(CameraError, match="picamera2 is not importable"):
        source.open()


# ------------------------------------------------------------------------------- V4L2


class FakeCapture:
    """cv2.VideoCapture stand-in: negotiates like OpenCV, serves a script of frames."""

    def __init__(self, script, fourcc="Y16 ", size=None, opened=True):
        self.script, self.fourcc, self.size, self.opened = list(script), fourcc, size, opened
        self.props = {}
        self.released = False

    def isOpened(self):
        return self.opened

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_FOURCC:
            return float(cv2.VideoWriter_fourcc(*self.fourcc))
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return float(self.size[1] if self.size else self.props[prop])
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return float(self.size[0] if self.size else self.props[prop])
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.stamp_ms
        return 0.0

    def grab(self):
        if not self.script:
            return False
        self.current = self.script.pop(0)
        return self.current is not None

    def retrieve(self, image=None):
        self.stamp_ms = time.monotonic_ns() / 1e6
        np.copyto(image, self.current)
        return True, image

    def release(self):
        self.released = True


def v4l2_source(cap, shape, **cfg):
    cfg = dataclasses.replace(CaptureConfig(), backend="v4l2", device="/dev/video0", **cfg)
    return V4L2Source(cfg, shape, opener=lambda dev, api: cap)


def test_v4l2_y16_frames_are_shifted_and_bit_exact(star10):
    cap = FakeCapture([star10 << 6, (star10 + 1) << 6])
    source = v4l2_source(cap, star10.shape, raw_shift=6)
    with source:
        iterator = iter(source)
        for k in range(2):
            item = next(iterator)       # the image is a reused buffer: check it now
            np.testing.assert_array_equal(item.image, star10 + k)
            assert item.bit_depth == 10
    assert cap.props[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter_fourcc(*"Y16 ")
    assert cap.props[cv2.CAP_PROP_CONVERT_RGB] == 0
    assert cap.released and not source.set_controls(1000, 2.0)


def test_v4l2_grey_is_8bit(star10):
    grey = (star10 >> 2).astype(np.uint8)
    cap = FakeCapture([grey], fourcc="GREY")
    source = v4l2_source(cap, star10.shape, raw_format="R8")
    item = next(iter(source))
    np.testing.assert_array_equal(item.image, grey)
    assert item.bit_depth == 8


def test_v4l2_refuses_packed_palette_and_wrong_size():
    with pytest.raises(CameraError, match="granted pixel format 'Y10P'"):
        v4l2_source(FakeCapture([], fourcc="Y10P"), (1300, 1600)).open()
    with pytest.raises(CameraError, match="granted 1280x720, expected 1600x1300"):
        v4l2_source(FakeCapture([], size=(720, 1280)), (1300, 1600)).open()
    with pytest.raises(CameraError, match="cannot open V4L2 device '/dev/video0'"):
        v4l2_source(FakeCapture([], opened=False), (1300, 1600)).open()


def test_v4l2_failed_grabs_become_errors_then_camera_lost(star10):
    cap = FakeCapture([None, star10 << 6, None, None, None])
    source = v4l2_source(cap, star10.shape)
    items = []
    with pytest.raises(CameraError, match="in 3 tries; camera lost"):
        for item in source:
            items.append(item)
    assert [type(i).__name__ for i in items] == ["FrameError", "Frame", "FrameError",
                                                 "FrameError"]


@pytest.mark.hardware
def test_picamera2_on_the_pi_delivers_full_frames():
    source = Picamera2Source(CaptureConfig(backend="picamera2"), (1300, 1600))
    with source:
        frames = [i for _, i in zip(range(5), source, strict=False) if isinstance(i, Frame)]
    assert frames and frames[-1].image.shape == (1300, 1600)
    assert frames[-1].exposure_us and frames[-1].gain
