"""Bad frames never raise: every method returns a reason code and recovers."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.config import DetectConfig, SimConfig
from tracker.detect import METHODS, make_detector
from tracker.detect.frame_input import FrameInput
from tracker.detect.slabs import SlabRunner
from tracker.sim import render_points

SHAPE = (48, 64)
# every method, and the default detector set up for multiplicative noise
CONFIGS = {m: DetectConfig(method=m) for m in sorted(METHODS)}
CONFIGS["default-multiplicative"] = DetectConfig(centroid_noise="multiplicative")


def _good_frame():
    rng = np.random.default_rng(1)
    frame = render_points(SHAPE, [20.3, 41.7], [15.2, 30.6], [6000.0, 9000.0], SimConfig(),
                          rng, noise_model="realistic")
    return frame.image


def _bad_frames():
    good = _good_frame()
    readonly = good.copy()
    readonly.flags.writeable = False
    nan = good.astype(np.float32)
    nan[5, 5] = np.nan
    inf = good.astype(np.float64)
    inf[7, 9] = -np.inf
    return [
        ("all zero", np.zeros(SHAPE, np.uint16), "empty"),
        ("saturated", np.full(SHAPE, 1023, np.uint16), "saturated"),
        ("flat", np.full(SHAPE, 100, np.uint16), "flat"),
        ("NaN", nan, "non_finite"),
        ("infinity", inf, "non_finite"),
        ("1x1", np.ones((1, 1), np.uint16), "wrong_shape"),
        ("transposed", good.T.copy(), "wrong_shape"),
        ("colour", np.dstack([good] * 3), "wrong_shape"),
        ("complex", good.astype(np.complex64), "bad_dtype"),
        ("bool", good > 100, "bad_dtype"),
        ("object", good.astype(object), "bad_dtype"),
        ("list", good.tolist(), "bad_dtype"),
        ("None", None, "bad_dtype"),
        ("read-only", readonly, None),
        ("non-contiguous", np.asfortranarray(good), None),
        ("strided view", np.repeat(good, 2, axis=1)[:, ::2], None),
    ]


@pytest.mark.parametrize("config", sorted(CONFIGS))
@pytest.mark.parametrize("name,frame,reason", _bad_frames(), ids=[b[0] for b in _bad_frames()])
def test_bad_frame_gives_reason_and_next_frame_works(config, name, frame, reason):
    det = make_detector(CONFIGS[config], SHAPE, 10)
    good = _good_frame()
    expected = det.detect(good).stars.copy()
    result = det.detect(frame)
    assert result.reason == reason
    if reason is None:  # readable frames give exactly the contiguous frame's stars
        np.testing.assert_array_equal(result.stars, expected)
    else:
        assert result.count == 0
    again = det.detect(good)
    assert again.reason is None
    np.testing.assert_array_equal(again.stars, expected)
    assert len(expected) >= 1


@pytest.mark.parametrize("config", sorted(CONFIGS))
@pytest.mark.parametrize("shape", [(1, 1), (2, 5)])
def test_detector_for_a_tiny_frame_refuses_it_politely(config, shape):
    det = make_detector(CONFIGS[config], shape, 10)
    result = det.detect(np.full(shape, 7, np.uint16))
    assert result.reason == "too_small" and result.count == 0


@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_random_garbage_never_raises(config):
    """Uniform noise, huge values and negative floats: a result, never an exception."""
    rng = np.random.default_rng(3)
    det = make_detector(CONFIGS[config], SHAPE, 10)
    frames = [rng.integers(0, 1024, SHAPE).astype(np.uint16),
              rng.normal(0, 1e6, SHAPE),
              -np.abs(rng.normal(0, 5, SHAPE)).astype(np.float32),
              rng.integers(0, 2**31, SHAPE, dtype=np.int64)]
    for frame in frames:
        result = det.detect(frame)
        assert result.count <= DetectConfig().max_stars
        assert np.all(np.isfinite(result.stars["x"])) and np.all(np.isfinite(result.stars["y"]))


def _through_float(image: np.ndarray, full_scale: float) -> np.ndarray:
    """The uint16 work the float route makes of ``image``: clipped to 0..full scale, rounded."""
    return np.rint(np.clip(image.astype(np.float64), 0.0, full_scale)).astype(np.uint16)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_unsigned_frames_reach_the_work_as_the_float_route_makes_them(dtype, threads):
    """The one-pass copy of uint8/uint16 frames (clipped at full scale) gives the work and
    the reason the float route gives, including where the first row says nothing, also
    when the copy runs in two threads' slabs (tracker.detect.slabs) and from a frame
    with gaps between its pixels."""
    rng = np.random.default_rng(3)
    top = np.iinfo(dtype).max
    noisy = rng.integers(0, top, SHAPE, endpoint=True).astype(dtype)
    first_row_dark = noisy.copy()
    first_row_dark[0] = 0
    first_row_flat = np.full(SHAPE, 7, dtype)
    first_row_flat[1:, 3] = 9
    beyond = np.full(SHAPE, top, dtype)        # all at or over full scale, not all equal
    beyond[5, 5] = top - 1
    frames = [(noisy, None), (first_row_dark, None), (first_row_flat, None),
              (np.zeros(SHAPE, dtype), "empty"), (np.full(SHAPE, 7, dtype), "flat")]
    bit_depth = 10 if dtype == np.uint16 else 8
    full_scale = 2 ** bit_depth - 1
    if dtype == np.uint16:
        frames.append((beyond, "saturated"))
    wide = np.zeros((SHAPE[0], 2 * SHAPE[1]), dtype)
    wide[:, ::2] = noisy
    frames.append((wide[:, ::2], None))
    slabs = SlabRunner(SHAPE[0], SHAPE[1], 0, threads, np.uint16)
    assert slabs.threads == threads
    for image, reason in frames:
        frame_input = FrameInput(SHAPE, bit_depth, dtype=np.uint16)
        assert frame_input.load(image, rows=slabs.rows) == reason
        if reason is None:
            np.testing.assert_array_equal(frame_input.work, _through_float(image, full_scale))
