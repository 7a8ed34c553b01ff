"""Replay source and image files: every format, and every way a file can be bad."""

import time

import cv2
import numpy as np
import pytest

from tracker.capture import Frame, FrameError, ReplaySource
from tracker.capture.imagefile import ImageReadError, read_image
from tracker.errors import UserError


@pytest.fixture(name="frame10")
def fixture_frame10():
    rng = np.random.default_rng(5)
    return rng.integers(0, 1024, size=(48, 64), dtype=np.uint16)


def test_16bit_png_holding_10bit_values_round_trips(tmp_path, frame10):
    cv2.imwrite(str(tmp_path / "a.png"), frame10)
    image, depth = read_image(tmp_path / "a.png")
    assert depth == 10 and image.dtype == np.uint16
    np.testing.assert_array_equal(image, frame10)


def test_16bit_values_above_10_bits_report_16(tmp_path, frame10):
    frame10[0, 0] = 4000
    np.save(tmp_path / "a.npy", frame10)
    assert read_image(tmp_path / "a.npy")[1] == 16


@pytest.mark.parametrize("suffix", [".png", ".tiff", ".tif", ".npy"])
def test_8bit_formats(tmp_path, suffix):
    img = np.arange(48 * 64, dtype=np.uint32).reshape(48, 64).astype(np.uint8)
    path = tmp_path / f"a{suffix}"
    np.save(path, img) if suffix == ".npy" else cv2.imwrite(str(path), img)
    image, depth = read_image(path)
    assert depth == 8
    np.testing.assert_array_equal(image, img)


def test_colour_jpeg_becomes_grey(tmp_path):
    img = np.zeros((40, 40, 3), np.uint8)
    img[10:20, 10:20] = (200, 200, 200)
    cv2.imwrite(str(tmp_path / "c.jpg"), img)
    image, depth = read_image(tmp_path / "c.jpg")
    assert image.shape == (40, 40) and depth == 8
    assert abs(int(image[15, 15]) - 200) <= 3


def test_rgba_png_becomes_grey(tmp_path):
    img = np.full((20, 30, 4), 255, np.uint8)
    img[..., :3] = 90
    cv2.imwrite(str(tmp_path / "c.png"), img)
    image, _ = read_image(tmp_path / "c.png")
    assert image.shape == (20, 30) and int(image[5, 5]) == 90


@pytest.mark.parametrize("name, content, message", [
    ("t.png", None, r"t.png: truncated PNG \(no IEND chunk\)"),
    ("t.jpg", None, r"t.jpg: truncated JPEG"),
    ("e.png", b"", r"e.png: empty file"),
    ("g.png", b"GIF89a....", r"g.png: not a PNG file"),
    ("g.tiff", b"hello world", r"g.tiff: not a TIFF file"),
    ("x.bmp", b"BM", r"x.bmp: unsupported file type .bmp"),
    ("n.npy", b"\x93NUMPY garbage", r"n.npy: unreadable .npy"),
])
def test_bad_files_raise_one_line_errors(tmp_path, frame10, name, content, message):
    path = tmp_path / name
    if content is None:  # a real file cut in half
        ok, buf = cv2.imencode(path.suffix, (frame10 >> 2).astype(np.uint8))
        content = buf.tobytes()[: len(buf) // 2]
    path.write_bytes(content)
    with pytest.raises(ImageReadError, match=message):
        read_image(path)


def test_float_npy_is_refused(tmp_path):
    np.save(tmp_path / "f.npy", np.zeros((4, 4), np.float32))
    with pytest.raises(ImageReadError, match=r"dtype float32 is not uint8 or uint16"):
        read_image(tmp_path / "f.npy")


def test_corrupt_png_body_is_an_error_not_a_picture(tmp_path, frame10):
    ok, buf = cv2.imencode(".png", frame10)
    data = bytearray(buf.tobytes())
    data[60:200] = bytes(140)  # zero the compressed data, keep the IEND chunk
    (tmp_path / "z.png").write_bytes(bytes(data))
    with pytest.raises(ImageReadError, match=r"z.png: corrupt or undecodable"):
        read_image(tmp_path / "z.png")


def make_folder(tmp_path, frame10):
    cv2.imwrite(str(tmp_path / "f002.png"), frame10)
    cv2.imwrite(str(tmp_path / "f001.png"), frame10)
    (tmp_path / "f003.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    cv2.imwrite(str(tmp_path / "f004.png"), frame10[:10])
    (tmp_path / "notes.txt").write_text("not an image")
    return tmp_path


def test_replay_folder_in_name_order_errors_do_not_stop_it(tmp_path, frame10):
    items = list(ReplaySource([make_folder(tmp_path, frame10)], expect_shape=(48, 64)))
    assert [i.name for i in items] == ["f001.png", "f002.png", "f003.png", "f004.png"]
    assert [type(i) for i in items] == [Frame, Frame, FrameError, FrameError]
    assert "truncated PNG" in items[2].reason
    assert items[3].reason == "f004.png: frame is 64x10, expected 64x48"
    assert items[0].bit_depth == 10 and items[0].image.shape == (48, 64)
    assert [i.index for i in items] == [0, 1, 2, 3]


def test_replay_loop_and_pacing(tmp_path, frame10):
    cv2.imwrite(str(tmp_path / "a.png"), frame10)
    source = ReplaySource([tmp_path / "a.png"], loop=True, fps=200.0)
    times = []
    t0 = time.monotonic_ns()
    with source:
        for item in source:
            times.append(item.t_ns)
            if len(times) == 5:
                source.close()
    assert len(times) == 5
    # paced at 5 ms: four intervals take at least ~20 ms (sleep never returns early) ...
    assert time.monotonic_ns() - t0 >= 19e6
    # ... and the frames are stamped exactly 1/fps apart
    assert np.diff(times).tolist() == [5_000_000] * 4


def test_unrecorded_frames_are_stamped_on_a_fixed_time_base(tmp_path, frame10, monkeypatch):
    """However long each frame takes to process, frame k is stamped start + k x interval."""
    from tracker.capture import replay as replay_module

    clock = _FakeClock()
    monkeypatch.setattr(replay_module, "time", clock)
    for name in ("a.png", "b.png", "c.png"):
        cv2.imwrite(str(tmp_path / name), frame10)
    start = clock.now_ns
    times = []
    for item, busy_s in zip(ReplaySource([tmp_path], interval_s=0.04), (0.5, 0.001, 3.0),
                            strict=True):
        times.append(item.t_ns)
        clock.now_ns += int(busy_s * 1e9)    # a slow, uneven consumer
    assert times == [start, start + 40_000_000, start + 80_000_000]


def test_missing_path_is_named(tmp_path):
    with pytest.raises(UserError, match=r"nothing.png: no such file or folder"):
        ReplaySource([tmp_path / "nothing.png"])


def test_frames_jsonl_metadata_is_carried(tmp_path, frame10):
    cv2.imwrite(str(tmp_path / "a.png"), frame10)
    cv2.imwrite(str(tmp_path / "b.png"), frame10)
    (tmp_path / "frames.jsonl").write_text(
        '{"file": "a.png", "t_ns": 1000, "exposure_us": 20000, "gain": 4.0}\n'
        'not json\n{"file": "b.png", "t_ns": 34333333}\n')
    a, b = list(ReplaySource([tmp_path]))
    assert (a.t_ns, a.exposure_us, a.gain) == (1000, 20000, 4.0)
    assert (b.t_ns, b.exposure_us, b.gain) == (34333333, None, None)


class _FakeClock:
    """monotonic_ns/sleep on a virtual clock: sleeps are recorded and advance it."""

    def __init__(self):
        self.now_ns = 10**12
        self.sleeps = []

    def monotonic_ns(self):
        return self.now_ns

    def sleep(self, seconds):
        self.sleeps.append(seconds)
        self.now_ns += int(seconds * 1e9)


def test_slow_pacing_waits_in_slices_and_says_so(tmp_path, frame10, monkeypatch):
    """At 0.15 fps a frame is 6.7 s away: the source yields Waiting every slice meanwhile."""
    from tracker.capture import Waiting
    from tracker.capture import replay as replay_module
    from tracker.capture.live import WAIT_SLICE_S

    clock = _FakeClock()
    monkeypatch.setattr(replay_module, "time", clock)
    cv2.imwrite(str(tmp_path / "a.png"), frame10)
    cv2.imwrite(str(tmp_path / "b.png"), frame10)
    items = list(ReplaySource([tmp_path], fps=0.15))
    frames = [i for i in items if isinstance(i, Frame)]
    assert [f.name for f in frames] == ["a.png", "b.png"]
    assert max(clock.sleeps) <= WAIT_SLICE_S
    between = items[items.index(frames[0]) + 1:items.index(frames[1])]
    assert between and all(isinstance(i, Waiting) for i in between)
    assert len(between) == int(np.ceil((1 / 0.15) / WAIT_SLICE_S)) - 1
    assert between[-1].waited_s == pytest.approx(1 / 0.15 - WAIT_SLICE_S, abs=WAIT_SLICE_S)
