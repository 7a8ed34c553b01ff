"""Raw formats: CSI-2 10-bit unpacking, R16 shifts, refusals; bit-exact against packers."""

import numpy as np
import pytest

from tracker.capture.rawformat import (
    RawConverter,
    RawFormatError,
    parse_format,
    unpack_raw10,
)


def pack_raw10_by_pixel(image: np.ndarray, stride: int) -> np.ndarray:
    """CSI-2 RAW10 packing written pixel by pixel from the layout (reference).

    Per group of 4 pixels: bytes 0..3 = bits 9..2 of pixels 0..3, byte 4 =
    bits 1:0 of pixel k in bits 2k+1:2k. Rows padded with 0xAA to stride.
    """
    rows, width = image.shape
    out = np.full((rows, stride), 0xAA, np.uint8)
    for r in range(rows):
        for g in range(width // 4):
            low = 0
            for k in range(4):
                v = int(image[r, 4 * g + k])
                out[r, 5 * g + k] = v >> 2
                low |= (v & 3) << (2 * k)
            out[r, 5 * g + 4] = low
    return out


def pack_raw10(image: np.ndarray, stride: int) -> np.ndarray:
    """The same packing, vectorised (checked against the reference below)."""
    rows, width = image.shape
    out = np.full((rows, stride), 0xAA, np.uint8)
    q = image.reshape(rows, width // 4, 4).astype(np.uint16)
    groups = out[:, : width * 5 // 4].reshape(rows, width // 4, 5)
    groups[..., :4] = q >> 2
    groups[..., 4] = ((q & 3) << np.array([0, 2, 4, 6], np.uint16)).sum(axis=-1)
    return out


def test_vectorised_test_packer_matches_the_by_pixel_reference():
    image = np.random.default_rng(1).integers(0, 1024, (3, 16), dtype=np.uint16)
    np.testing.assert_array_equal(pack_raw10(image, 24), pack_raw10_by_pixel(image, 24))


def test_unpack_raw10_is_bit_exact_for_every_value():
    image = np.arange(1024, dtype=np.uint16).reshape(8, 128)   # all 10-bit values
    out = np.zeros_like(image)
    tmp = np.zeros((8, 32), np.uint16)
    got = unpack_raw10(pack_raw10_by_pixel(image, 176), out, tmp)
    assert got is out
    np.testing.assert_array_equal(out, image)


def test_csi2p_converter_ignores_stride_padding_and_reuses_its_buffer():
    rng = np.random.default_rng(2)
    conv = RawConverter(parse_format("R10_CSI2P"), (130, 160), shift=0)
    first = conv.frame
    for _ in range(3):
        image = rng.integers(0, 1024, (130, 160), dtype=np.uint16)
        got = conv.convert(pack_raw10(image, 256))
        assert got is first
        np.testing.assert_array_equal(got, image)
    assert conv.bit_depth == 10


def test_a_ring_of_frames_keeps_each_frame_until_the_ring_comes_round():
    """With three buffers a frame survives the next two conversions (capture running ahead)."""
    rng = np.random.default_rng(6)
    conv = RawConverter(parse_format("R16"), (12, 16), shift=6, buffers=3)
    images = [rng.integers(0, 1024, (12, 16), dtype=np.uint16) for _ in range(4)]
    got = [conv.convert((image << 6).astype("<u2").view(np.uint8)) for image in images]
    assert got[0] is not got[1] and got[1] is not got[2] and got[3] is got[0]
    for frame, image in zip(got[1:], images[1:], strict=True):
        np.testing.assert_array_equal(frame, image)
    with pytest.raises(RawFormatError):
        conv.convert(np.zeros((12, 8), np.uint8))   # a failed conversion keeps its turn
    assert conv.frame is got[1]


@pytest.mark.parametrize("shift", [0, 6])
def test_r16_words_are_shifted_into_the_frame(shift):
    """10-bit values stored high (x64, shift 6) or low (shift 0) in 16-bit words."""
    image = np.random.default_rng(3).integers(0, 1024, (20, 40), dtype=np.uint16)
    words = (image << shift).astype("<u2")
    buf = np.zeros((20, 96), np.uint8)            # stride 96 bytes > 80 of pixels
    buf[:, :80] = words.view(np.uint8)
    conv = RawConverter(parse_format("R16"), (20, 40), shift=shift)
    np.testing.assert_array_equal(conv.convert(buf), image if shift else words)
    assert conv.bit_depth == 16 - shift


def test_r8_copies_bytes():
    buf = np.random.default_rng(4).integers(0, 256, (10, 32), dtype=np.uint8)
    conv = RawConverter(parse_format("R8"), (10, 24))
    np.testing.assert_array_equal(conv.convert(buf), buf[:, :24])
    assert conv.frame.dtype == np.uint8 and conv.bit_depth == 8


def test_typed_16bit_buffer_is_stored_directly():
    image = np.random.default_rng(5).integers(0, 1024, (6, 8), dtype=np.uint16)
    conv = RawConverter(parse_format("R10"), (6, 8))
    np.testing.assert_array_equal(conv.convert(image), image)


def test_pisp_compressed_format_is_refused():
    with pytest.raises(RawFormatError, match="MONO_PISP_COMP1, a lossy compressed raw"):
        parse_format("MONO_PISP_COMP1")


def test_colour_or_unknown_format_is_refused():
    with pytest.raises(RawFormatError, match="raw format 'SRGGB10', expected a mono format"):
        parse_format("SRGGB10")


def test_buffer_too_small_is_an_error_not_a_crash():
    conv = RawConverter(parse_format("R16"), (20, 40))
    with pytest.raises(RawFormatError, match=r"too small for 40x20 R16 \(80 bytes per row\)"):
        conv.convert(np.zeros((20, 60), np.uint8))


def test_packed_width_must_be_a_multiple_of_four():
    with pytest.raises(RawFormatError, match="divisible by 4, got 1602"):
        RawConverter(parse_format("R10_CSI2P"), (4, 1602))
