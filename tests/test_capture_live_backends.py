"""picamera2 and V4L2 backends through their adapters, with a real frame behind fakes.

The fakes stand in for picamera2.Picamera2/MappedArray and cv2.VideoCapture
and serve a real star image (data/real/openstartracker/img0.png, scaled to
10 bits) in the buffer layouts the Pi delivers. Pixels must come out
bit-exact; times within 1 ms of the conversion done here independently
(the BOOTTIME-MONOTONIC offset is read at two slightly different instants).
"""

import dataclasses
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from fake_picamera2 import FakeMappedArray, FakePicamera2, frame_stream

from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.imagefile import read_image
from tracker.capture.live import CameraError
from tracker.capture.picamera2_source import Picamera2Source, compatibility_problem
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

VERSIONS = ("0.3.25", False)      # the pinned pair with Arducam's libcamera 0.3.x


def picamera2_source(script, buffer, md=None, granted="R16", versions=VERSIONS, cam_kw=None,
                     **cfg):
    cam = FakePicamera2(script, frame_stream(buffer, md or {}), granted=granted,
                        **(cam_kw or {}))
    cfg = dataclasses.replace(CaptureConfig(), backend="picamera2", **cfg)
    first = buffer if isinstance(buffer, np.ndarray) else buffer[0]
    rows, cols = first.shape[0], (first.shape[1] - 64) // 2
    source = Picamera2Source(cfg, (rows, cols),
                             modules=(lambda num: cam, FakeMappedArray, versions))
    return source, cam


def boot_ns(mono_ns: int) -> int:
    return mono_ns + time.clock_gettime_ns(time.CLOCK_BOOTTIME) - time.monotonic_ns()


def frames_of(source, n):
    """The first n items that are not Waiting, each checked while its buffer is valid."""
    out = []
    for item in source:
        if isinstance(item, Waiting):
            continue
        out.append((item, item.image.copy() if isinstance(item, Frame) else None))
        if len(out) == n:
            break
    return out


def test_picamera2_frames_are_bit_exact_with_sensor_metadata(star10):
    t_end = time.monotonic_ns()
    md = {"SensorTimestamp": boot_ns(t_end), "ExposureTime": 20000, "AnalogueGain": 4.0,
          "FrameDuration": 100000}
    buffers = [r16_buffer(star10 + k, 6) for k in range(3)]
    source, cam = picamera2_source(["frame"] * 3, buffers, md, raw_shift=6)
    FakeMappedArray.writes.clear()
    with source:
        got = frames_of(source, 3)
    for k, (_, pixels) in enumerate(got):
        np.testing.assert_array_equal(pixels, star10 + k)
    frames = [f for f, _ in got]
    assert all(f.image is frames[0].image for f in frames)   # one reused buffer
    assert FakeMappedArray.writes == [False] * 3                # read-only mapping
    assert cam.free_buffers == 4                                # every request released
    f = frames[0]
    assert (f.bit_depth, f.exposure_us, f.gain) == (10, 20000, 4.0)
    # mid-exposure = end - exposure/2 = t_end - 10 ms, on the monotonic clock
    assert abs(f.t_ns - (t_end - 10_000_000)) < 1_000_000
    assert cam.closed


def test_picamera2_asks_for_manual_raw_capture_in_an_explicit_sensor_mode(star10):
    source, cam = picamera2_source([], r16_buffer(star10, 6), exposure_us=5000.0, gain=2.0,
                                   fps=10.0, buffer_count=3)
    source.open()
    rows, cols = star10.shape
    assert cam.config["raw"] == {"format": "R16", "size": (cols, rows)}
    assert cam.config["sensor"] == {"output_size": (cols, rows), "bit_depth": 10}
    assert cam.config["queue"] is False and cam.config["buffer_count"] == 3
    assert cam.config["controls"] == {"AeEnable": False, "ExposureTime": 5000,
                                      "AnalogueGain": 2.0,
                                      "FrameDurationLimits": (100000, 100000)}
    assert source.set_controls(1234.4, 3.5)
    assert (cam.controls["ExposureTime"], cam.controls["AnalogueGain"]) == (1234, 3.5)
    source.close()


def test_picamera2_refuses_the_compressed_pi5_format(star10):
    source, cam = picamera2_source([], r16_buffer(star10, 6), granted="MONO_PISP_COMP1")
    with pytest.raises(CameraError, match="MONO_PISP_COMP1, a lossy compressed raw format"):
        source.open()
    assert cam.closed


@pytest.mark.parametrize("fail_in", ["configure", "start"])
def test_picamera2_open_releases_the_camera_on_any_failure(star10, fail_in):
    """Item 2: any exception after the camera was acquired closes it again."""
    source, cam = picamera2_source([], r16_buffer(star10, 6), cam_kw={"fail_in": fail_in})
    with pytest.raises(CameraError, match="camera configuration failed"):
        source.open()
    assert cam.closed
    if fail_in == "start":
        with pytest.raises(CameraError, match="is the startracker service running"):
            picamera2_source([], r16_buffer(star10, 6), cam_kw={"fail_in": "start"})[0].open()


def test_picamera2_a_late_frame_is_cancelled_not_leaked(star10):
    """Item 2: a timed-out capture job must not take a later request nor block stop().

    At 10 fps with timeout_s 0.5 a frame is late after 0.6 s, i.e. 3 slices of
    0.25 s without a frame. Late frames here, then good ones: every buffer
    comes back and close() returns.
    """
    late = ["nothing"] * 3
    script = ["frame"] + late + ["frame"] + late + late + ["frame"] * 8
    source, cam = picamera2_source(script, r16_buffer(star10, 6), fps=10.0, timeout_s=0.5)
    items = []
    with source:
        for item in source:
            items.append(type(item).__name__)
            if items.count("Frame") == 6:
                break
    assert items == ["Frame", "Waiting", "Waiting", "FrameError", "Frame", "Waiting",
                     "Waiting", "FrameError", "Waiting", "Waiting", "FrameError",
                     "Frame", "Frame", "Frame", "Frame"]
    assert cam.free_buffers == 4 and cam.closed and not cam._job_list


def test_picamera2_three_late_frames_in_a_row_lose_the_camera(star10):
    source, cam = picamera2_source(["nothing"] * 9, r16_buffer(star10, 6), fps=10.0,
                                   timeout_s=0.5)
    items = []
    with pytest.raises(CameraError, match=r"no frame in 3 x 0.6 s; camera lost"):
        for item in source:
            items.append(item)
    errors = [i for i in items if isinstance(i, FrameError)]
    assert [e.reason for e in errors] == ["no frame within 0.6 s"] * 2
    source.close()
    assert cam.closed                      # stop() was not stuck behind a stale job


def test_picamera2_slow_frames_yield_waiting_and_are_not_late(star10):
    """capture.fps 0.15: a frame every 6.7 s is waited for in 0.25 s slices, not timed out."""
    script = (["nothing"] * 26 + ["frame"]) * 2
    source, cam = picamera2_source(script, r16_buffer(star10, 6), fps=0.15)
    items = [type(i).__name__ for _, i in zip(range(54), source, strict=False)]
    assert items == (["Waiting"] * 26 + ["Frame"]) * 2
    source.close()


def test_picamera2_short_buffer_is_a_frame_error_and_the_request_is_released(star10):
    source, cam = picamera2_source(["frame"] * 2, np.zeros((10, 10 + 64), np.uint8))
    source.shape = star10.shape
    item = next(iter(source))
    assert isinstance(item, FrameError) and "too small" in item.reason
    assert cam.free_buffers == 4
    source.close()


@pytest.mark.parametrize("versions, problem", [
    (("0.3.19", True), "too old"), (("0.3.25", False), None), (("0.3.26", True), None),
    (("0.3.26", False), "sets ExposureTimeMode"), (("0.3.36", False), "0.3.20 .. 0.3.25"),
    ((None, None), None)])
def test_picamera2_and_libcamera_pairs(versions, problem):
    """Item 12: the pinned pair, checked at open and by selftest."""
    got = compatibility_problem(*versions)
    assert (got is None) if problem is None else (problem in got)


def test_picamera2_without_cancel_all_and_flush_is_refused(star10):
    source, cam = picamera2_source([], r16_buffer(star10, 6), versions=(None, None),
                                   cam_kw={"with_cancel": False})
    with pytest.raises(CameraError, match="too old"):
        source.open()


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
