"""Image files that lie about their size, files that are not files, and the shared path rule."""

import json
import os
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest
from bad_files import black_png, npy_claiming, png_claiming

from tracker.capture import Frame, FrameError, ReplaySource
from tracker.capture.image_header import image_size
from tracker.capture.imagefile import ImageReadError, read_image
from tracker.capture.input_paths import expand_inputs
from tracker.cli import main
from tracker.config import MAX_SENSOR_PIXELS, load_config
from tracker.errors import UserError
from tracker.frame_array import FrameArrayError, as_frame
from tracker.pipeline import DETECTORS_KEPT, Pipeline

REAL = Path(__file__).parent / "data" / "real" / "cedar-solve"


def test_header_bombs_are_refused_from_the_header_alone(tmp_path):
    (tmp_path / "bomb.png").write_bytes(png_claiming(60000, 60000))
    (tmp_path / "bomb.npy").write_bytes(npy_claiming((100000, 100000)))
    assert len((tmp_path / "bomb.png").read_bytes()) < 70
    assert len((tmp_path / "bomb.npy").read_bytes()) == 129
    tracemalloc.start()
    try:
        for name, size in (("bomb.png", "60000x60000"), ("bomb.npy", "100000x100000")):
            with pytest.raises(ImageReadError, match=rf"^{name}: image is {size} px, larger "
                                                     r"than the configured camera's 1600x1300"):
                read_image(tmp_path / name, max_size=(1600, 1300))
            with pytest.raises(ImageReadError, match=rf"more than the {MAX_SENSOR_PIXELS:,} "
                                                     "pixels a frame may have"):
                read_image(tmp_path / name)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


def test_a_real_20000_pixel_png_is_not_decoded(tmp_path):
    (tmp_path / "wide.png").write_bytes(black_png(20000, 20000))
    assert (tmp_path / "wide.png").stat().st_size < 1 << 20     # 400 MB of pixels
    assert image_size((tmp_path / "wide.png").read_bytes(), ".png") == (20000, 20000)
    with pytest.raises(ImageReadError, match=r"wide.png: image is 20000x20000 px"):
        read_image(tmp_path / "wide.png", max_size=(1600, 1300))


def test_sizes_read_from_each_header_match_the_decoder(tmp_path):
    img = np.arange(37 * 53, dtype=np.uint16).reshape(37, 53)
    for suffix in (".png", ".tiff", ".jpg"):
        path = tmp_path / f"a{suffix}"
        cv2.imwrite(str(path), img if suffix != ".jpg" else (img % 256).astype(np.uint8))
        assert image_size(path.read_bytes(), suffix) == (53, 37)
        assert read_image(path, max_size=(53, 37))[0].shape == (37, 53)
        with pytest.raises(ImageReadError, match=r"larger than the configured camera's 52x37"):
            read_image(path, max_size=(52, 37))
    np.save(tmp_path / "a.npy", img)
    assert read_image(tmp_path / "a.npy", max_size=(53, 37))[0].shape == (37, 53)


def test_fifo_and_devices_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    with pytest.raises(ImageReadError, match=r"pipe.png: a named pipe \(FIFO\), not a regular "):
        read_image(fifo)
    (tmp_path / "zero.npy").symlink_to("/dev/zero")
    with pytest.raises(ImageReadError, match=r"zero.npy: a character device, not a regular"):
        read_image(tmp_path / "zero.npy")
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(ImageReadError, match=r"dir.png: a folder, not a regular file"):
        read_image(tmp_path / "dir.png")


def test_jpeg_cut_short_is_refused_with_or_without_an_end_marker(tmp_path):
    data = (REAL / "orion_belt.jpg").read_bytes()
    half = data[: len(data) // 2]
    (tmp_path / "half.jpg").write_bytes(half)
    (tmp_path / "mended.jpg").write_bytes(half + b"\xff\xd9")
    with pytest.raises(ImageReadError, match=r"half.jpg: truncated JPEG \(no end-of-image"):
        read_image(tmp_path / "half.jpg")
    # the decoder fills the missing half with mid-grey (128) and says nothing
    decoded = cv2.imdecode(np.frombuffer(half + b"\xff\xd9", np.uint8), cv2.IMREAD_GRAYSCALE)
    assert decoded is not None and np.all(decoded[-8:] == 128)
    with pytest.raises(ImageReadError, match=r"mended.jpg: truncated JPEG \(the image data ends"):
        read_image(tmp_path / "mended.jpg")
    # the whole file is fine
    assert read_image(REAL / "orion_belt.jpg")[0].shape == (512, 512)


@pytest.mark.parametrize("content, message", [
    (npy_claiming((100, 100)), r"truncated .npy \(the header says \(100, 100\) uint16\)"),
    (npy_claiming((10, 10), "<f8"), r".npy dtype float64 is not uint8 or uint16"),
    (npy_claiming((10, 10), "|O"), r".npy dtype object is not uint8 or uint16"),
    (b"\x93NUMPY\x01\x00\x10\x00{'descr': __import__('os')}", r"unreadable .npy header"),
    (npy_claiming((-5, 10)), r"the header says 10x-5 px, an image with no pixels"),
])
def test_bad_npy_headers(tmp_path, content, message):
    (tmp_path / "x.npy").write_bytes(content)
    with pytest.raises(ImageReadError, match=message):
        read_image(tmp_path / "x.npy")


def test_big_endian_npy_is_read(tmp_path):
    img = np.arange(12, dtype=">u2").reshape(3, 4)
    np.save(tmp_path / "be.npy", img)
    image, depth = read_image(tmp_path / "be.npy")
    assert image.dtype == np.uint16 and depth == 10
    np.testing.assert_array_equal(image, img)


def test_replay_of_a_header_bomb_goes_on_to_the_next_frame(tmp_path):
    (tmp_path / "a.png").write_bytes(png_claiming(60000, 60000))
    cv2.imwrite(str(tmp_path / "b.png"), np.full((48, 64), 9, np.uint8))
    items = list(ReplaySource([tmp_path], expect_shape=(48, 64)))
    assert [type(i) for i in items] == [FrameError, Frame]
    assert "a.png: image is 60000x60000 px, larger than the configured camera's 64x48" \
        in items[0].reason


# --- the shared rule for files and folders ----------------------------------------------


def test_expand_inputs_rules(tmp_path):
    (tmp_path / "b.png").write_bytes(b"x")
    (tmp_path / "a.PNG").write_bytes(b"x")
    (tmp_path / "a.PNG.centroids.json").write_text("{}")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub").mkdir()
    os.mkfifo(tmp_path / "fifo.png")
    assert [p.name for p in expand_inputs([tmp_path], (".png",))] == ["a.PNG", "b.png"]
    assert [p.name for p in expand_inputs([tmp_path], (".png", ".centroids.json"),
                                          companion=".centroids.json")] == [
        "a.PNG.centroids.json", "b.png"]
    # files named are kept as named, in order
    assert expand_inputs([tmp_path / "notes.txt", tmp_path / "b.png"], (".png",)) == [
        tmp_path / "notes.txt", tmp_path / "b.png"]


@pytest.mark.parametrize("make, message", [
    (lambda d: d / "missing", r"missing: no such file or folder$"),
    (lambda d: (d / "empty").mkdir() or d / "empty",
     r"empty: no image files \(.png, .npy\) in this folder$"),
    (lambda d: os.mkfifo(d / "p.png") or d / "p.png",
     r"p.png: a named pipe \(FIFO\), expected one of the image files \(.png, .npy\) or a "
     r"folder of them$"),
    (lambda d: Path("/dev/null"), r"/dev/null: a character device, expected"),
])
def test_expand_inputs_refusals_are_one_line(tmp_path, make, message):
    with pytest.raises(UserError, match=message):
        expand_inputs([make(tmp_path)], (".png", ".npy"))


# --- arrays people hand in ----------------------------------------------------------------


def test_arrays_become_frames_by_one_rule():
    grey = np.zeros((4, 5), np.uint16)
    grey[1, 2] = 1000
    assert as_frame(grey)[1] == 10 and as_frame(grey, 12)[1] == 12
    grey[0, 0] = 1024
    assert as_frame(grey)[1] == 16
    assert as_frame(grey.astype(np.uint8))[1] == 8
    image, depth = as_frame(grey.astype(np.int64))
    assert image.dtype == np.uint16 and depth == 16
    image, depth = as_frame(np.full((3, 3), 0.5))
    assert (image.dtype, depth, int(image[0, 0])) == (np.uint16, 16, 32768)
    image, depth = as_frame(np.full((3, 3), 700.4, np.float32))
    assert (image.dtype, depth, int(image[0, 0])) == (np.uint16, 10, 700)
    bgr = np.zeros((3, 3, 3), np.uint8)
    bgr[..., 2] = 100                       # red only
    image, depth = as_frame(bgr)
    assert image.shape == (3, 3) and depth == 8 and int(image[0, 0]) == 30  # 0.299 * 100


@pytest.mark.parametrize("array, message", [
    (np.full((3, 3), np.nan), "NaN or infinity"),
    (np.full((3, 3), -1.0), r"float pixels in \[-1, -1\]"),
    (np.full((3, 3), 70000, np.int32), r"int32 pixels in \[70000, 70000\], expected 0..65535"),
    (np.zeros((3, 3, 2), np.uint8), r"shape \(3, 3, 2\)"),
    (np.zeros((0, 3), np.uint8), "has no pixels"),
    (np.array([["a"]]), "expected integer or float pixels"),
])
def test_arrays_that_cannot_be_frames(array, message):
    with pytest.raises(FrameArrayError, match=message):
        as_frame(array)


def test_pipeline_converts_colour_as_replay_does(tmp_path):
    rng = np.random.default_rng(3)
    bgr = rng.integers(0, 40, (96, 128, 3)).astype(np.float64)
    rows, cols = np.mgrid[:96, :128]
    for x, y in ((30, 40), (90, 20), (60, 70)):   # stars (a flat 3x3 box is a particle's)
        spot = np.exp(-((cols - x) ** 2 + (rows - y) ** 2) / (2 * 1.2 ** 2))
        bgr += spot[..., None] * (210, 160, 120)
    bgr = np.clip(np.rint(bgr), 0, 255).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "c.png"), bgr)
    grey, depth = read_image(tmp_path / "c.png")
    pipeline = Pipeline(load_config(None))
    from_file = pipeline.process(grey, depth, 0).detections.stars.copy()
    from_array = pipeline.process(bgr, 8, 0).detections.stars.copy()
    assert len(from_file) == 3
    np.testing.assert_array_equal(from_file, from_array)


def test_detectors_kept_are_bounded_however_many_sizes_come():
    pipeline = Pipeline(load_config(None))
    rng = np.random.default_rng(4)
    tracemalloc.start()
    try:
        sizes = []
        for k in range(24):
            frame = rng.integers(0, 50, (200 + k, 300 + k), dtype=np.uint16)
            pipeline.process(frame, 10, 0)
            sizes.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    # memory after 24 sizes is that of the last DETECTORS_KEPT, not of all 24
    assert DETECTORS_KEPT == 2
    assert sizes[-1] < 1.5 * sizes[DETECTORS_KEPT], sizes


def test_the_service_reaches_the_frames_after_header_bombs(tmp_path):
    """Before, the decoder's exception left the source: the service reopened it and started
    the replay again from the bomb, never reaching the frames after it."""
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "a.png").write_bytes(png_claiming(60000, 60000))
    (folder / "b.npy").write_bytes(npy_claiming((100000, 100000)))
    rng = np.random.default_rng(8)
    np.save(folder / "c.npy", rng.integers(0, 60, (1300, 1600), dtype=np.uint16))
    summary = tmp_path / "summary.json"
    assert main(["run", "--replay", str(folder), "--frames", "3", "--port", "loop://",
                 "--summary", str(summary)]) == 0
    result = json.loads(summary.read_text())
    assert (result["frames"], result["processed"]) == (3, 1)
    assert result["faults"]["frame_unreadable"] == 2 and "camera_lost" not in result["faults"]
