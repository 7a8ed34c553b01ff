"""picamera2 and V4L2 backends through their adapters, with a real frame behind fakes.

The fakes stand in for picamera2 (tests/fake_picamera2.py: its job and request
life cycle) and for the Pi 5's kernel (tests/fake_rp1_cfe.py: the rp1-cfe
media graph, pads, buffers and sensor controls) and serve a real star image
(tests/data/real/openstartracker/img0.png, scaled to 10 bits) in the buffer layouts
the Pi delivers. Pixels must come out bit-exact; picamera2 times within 1 ms
of the conversion done here independently (the BOOTTIME-MONOTONIC offset is
read at two slightly different instants).
"""

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fake_picamera2 import FakeMappedArray, FakePicamera2, frame_stream
from fake_rp1_cfe import FakeKernel

from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.imagefile import read_image
from tracker.capture.live import FRAME_BUFFERS, CameraError
from tracker.capture.picamera2_source import Picamera2Source, compatibility_problem
from tracker.capture.v4l2_source import V4L2Source
from tracker.config import CaptureConfig

REAL = Path(__file__).parent / "data" / "real" / "openstartracker" / "img0.png"


@pytest.fixture(name="star10", scope="module")
def fixture_star10():
    """A real star field as 10-bit values (8-bit x 4 + 3), shape (1040, 1392)."""
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
    n = FRAME_BUFFERS + 1
    buffers = [r16_buffer(star10 + k, 6) for k in range(n)]
    source, cam = picamera2_source(["frame"] * n, buffers, md, raw_shift=6)
    FakeMappedArray.writes.clear()
    with source:
        got = frames_of(source, n)
    for k, (_, pixels) in enumerate(got):
        np.testing.assert_array_equal(pixels, star10 + k)
    frames = [f for f, _ in got]
    # a ring of reused buffers: distinct for FRAME_BUFFERS frames, then round again
    assert len({id(f.image) for f in frames[:FRAME_BUFFERS]}) == FRAME_BUFFERS
    assert frames[FRAME_BUFFERS].image is frames[0].image
    np.testing.assert_array_equal(frames[1].image, star10 + 1)   # still valid
    assert FakeMappedArray.writes == [False] * n                # read-only mapping
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


def v4l2_source(kernel, shape=(1300, 1600), **cfg):
    cfg = dataclasses.replace(CaptureConfig(), backend="v4l2", device="0", **cfg)
    return V4L2Source(cfg, shape, io=kernel)


@pytest.fixture(name="field10", scope="module")
def fixture_field10(star10):
    """A real star field on the OV2311's 1600 x 1300 (10-bit), distinct per frame k."""
    image = np.zeros((1300, 1600), np.uint16)
    image[:1040, :1392] = star10
    return [(image + k).clip(0, 1023).astype(np.uint16) for k in range(3)]


def stamped(images, t0=10**12, period=10**8):
    return [(image, t0 + k * period) for k, image in enumerate(images)]


@pytest.mark.parametrize("raw_format, depth", [("R16", 10), ("R10_CSI2P", 10), ("R8", 8)])
def test_v4l2_sets_up_rp1_cfe_and_streams_bit_exact(field10, raw_format, depth):
    """Item 11: links, pad formats, controls and buffers as rp1-cfe needs them.

    libcamera left its own links enabled (csi2 -> pisp-fe, embedded data, ...):
    the CFE would not start the sensor until those nodes stream too, so the
    source must disable them.
    """
    kernel = FakeKernel(stamped(field10), ["frame"] * 3, libcamera_links=True)
    source = v4l2_source(kernel, raw_format=raw_format, raw_shift=6, exposure_us=20000.0,
                         gain=4.0, fps=10.0)
    got = frames_of(source, 3)
    for k, (frame, pixels) in enumerate(got):
        want = field10[k] if depth == 10 else (field10[k] >> 2).astype(np.uint8)
        np.testing.assert_array_equal(pixels, want)
        assert frame.bit_depth == depth
        # the buffer's CLOCK_MONOTONIC stamp (readout start) minus half the exposure
        assert frame.t_ns == 10**12 + k * 10**8 - 10_000_000
    enabled = {(a, b) for a, b, flags in kernel.links if flags & 1}
    assert enabled == {((10, 0), (1, 0)), ((1, 4), (12, 0))}
    code = 0x2001 if depth == 8 else 0x200A
    assert kernel.pad_fmt[(10, 0)] == kernel.pad_fmt[(1, 0)] == kernel.pad_fmt[(1, 4)] == \
        (1600, 1300, code)
    # line time (1600 + 400) / 200 MHz = 10 us: 20 ms = 2000 lines; 10 fps = 10000 lines
    assert dict(kernel.ctrl_log) == {"V4L2_CID_EXPOSURE": 2000,
                                     "V4L2_CID_ANALOGUE_GAIN": 400,
                                     "V4L2_CID_VBLANK": 10000 - 1300}
    assert got[0][0].exposure_us == pytest.approx(20000.0) and got[0][0].gain == 4.0
    source.close()
    assert not kernel.fds and not kernel.streaming


def test_v4l2_long_exposure_lengthens_the_frame_and_is_clamped(field10):
    kernel = FakeKernel(stamped(field10), ["frame"])
    source = v4l2_source(kernel, fps=30.0, exposure_us=20000.0)
    source.open()
    assert source.set_controls(150_000.0, 99.0)        # 15000 lines > a 30 fps frame
    values = dict(kernel.ctrl_log[-3:])        # VBLANK first, then EXPOSURE and GAIN
    assert values["V4L2_CID_EXPOSURE"] == 15000
    assert values["V4L2_CID_VBLANK"] == 15000 + 4 - 1300
    assert values["V4L2_CID_ANALOGUE_GAIN"] == 1600       # the control's maximum
    source.close()


def test_v4l2_no_sensor_is_a_camera_error_naming_what_was_looked_at():
    with pytest.raises(CameraError, match=r"no rp1-cfe media device with a sensor on csi2 "
                                          r"\(number '0'; looked at /dev/media0"):
        v4l2_source(FakeKernel(sensor_present=False)).open()


def test_v4l2_a_format_the_sensor_refuses_is_reported(field10):
    with pytest.raises(CameraError, match="rp1-cfe delivers R16, R10_CSI2P, R8"):
        v4l2_source(FakeKernel(), raw_format="R10").open()
    kernel = FakeKernel()
    kernel.pad_fmt[(10, 0)] = (1600, 1300, 0x200A)
    with pytest.raises(CameraError, match=r"asked for 1280x720 code 0x200a, granted 1600x1300"):
        v4l2_source(kernel, shape=(720, 1280)).open()
    assert not kernel.fds


def test_v4l2_streamon_failure_says_why(field10, monkeypatch):
    """Another program changing csi2's source pad after our set-up: EPIPE, said plainly."""
    kernel = FakeKernel()
    source = v4l2_source(kernel)
    real = kernel._video

    def pad_changed(name, arg):
        if name == "VIDIOC_REQBUFS":
            kernel.pad_fmt[(1, 4)] = (1600, 1298, kernel.pad_fmt[(1, 4)][2])
        return real(name, arg)

    monkeypatch.setattr(kernel, "_video", pad_changed)
    with pytest.raises(CameraError, match="STREAMON failed: the pads' formats do not match"):
        source.open()
    assert not kernel.fds


def test_v4l2_slow_late_and_broken_frames(field10):
    """Waiting while no frame; a late one is a FrameError; three late in a row lose it."""
    kernel = FakeKernel(stamped(field10), ["nothing"] * 3 + ["frame"] + ["nothing"] * 20)
    source = v4l2_source(kernel, fps=10.0, timeout_s=0.5)
    items = []
    with pytest.raises(CameraError, match=r"no frame in 3 x 0.6 s; camera lost"):
        for item in source:
            items.append(type(item).__name__)
    # 10 fps + 0.5 s: late after 0.6 s, i.e. in the third slice of 0.25 s
    assert items == ["Waiting"] * 2 + ["FrameError", "Frame"] + \
        (["Waiting"] * 2 + ["FrameError"]) * 2 + ["Waiting"] * 2
    source.close()


def test_v4l2_a_buffer_flagged_as_error_is_a_frame_error_and_requeued(field10, monkeypatch):
    kernel = FakeKernel(stamped(field10), ["frame"] * 3)
    source = v4l2_source(kernel)
    real = kernel._video

    def flag_first(name, arg):
        out = real(name, arg)
        if name == "VIDIOC_DQBUF" and arg.sequence == 0:
            arg.flags |= 0x40
        return out

    monkeypatch.setattr(kernel, "_video", flag_first)
    got = frames_of(source, 3)
    assert [type(f).__name__ for f, _ in got] == ["FrameError", "Frame", "Frame"]
    assert "flagged as an error" in got[0][0].reason
    assert sum(b[1] == "queued" for b in kernel.buffers) == len(kernel.buffers) - 0
    source.close()


def _first_frames(source, n=5):
    """The first n frames (Waiting and lost frames skipped; the source gives up by itself)."""
    with source:
        frames = []
        for item in source:
            if isinstance(item, Frame):
                frames.append((item.t_ns, item.exposure_us, item.gain, item.image.shape))
            if len(frames) == n:
                return frames
    return frames


@pytest.mark.hardware
def test_picamera2_on_the_pi_delivers_full_frames():
    frames = _first_frames(Picamera2Source(CaptureConfig(backend="picamera2"), (1300, 1600)))
    assert len(frames) == 5 and frames[-1][3] == (1300, 1600)
    assert frames[-1][1] and frames[-1][2]
    times = [t for t, *_ in frames]
    assert times == sorted(times)


@pytest.mark.hardware
def test_v4l2_on_the_pi_sets_up_rp1_cfe_and_streams():
    """Run with the service stopped: libcamera (picamera2) must not hold the camera."""
    source = V4L2Source(CaptureConfig(backend="v4l2", fps=10.0), (1300, 1600))
    frames = _first_frames(source)
    assert len(frames) == 5 and frames[-1][3] == (1300, 1600)
    assert source.controls is not None and source.controls.available
    gaps_s = np.diff([t for t, *_ in frames]) / 1e9
    assert np.all(np.abs(gaps_s - 0.1) < 0.02)      # 10 fps from VBLANK, buffer times
