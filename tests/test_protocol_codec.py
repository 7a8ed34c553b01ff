"""Framing, CRC, encoder and message table (tracker.protocol), and the generated docs."""

import math

import numpy as np
import pytest

from tracker.protocol import docgen
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.framing import build_packet, crc16
from tracker.protocol.messages import BY_ID, MESSAGES, Direction, MsgId, Reason


def test_crc_is_ccitt_false_with_its_check_value():
    # The catalogue check value of CRC-16/CCITT-FALSE (ICD section 3).
    assert crc16(b"123456789") == 0x29B1


def test_command_frames_match_the_icd_examples():
    enc = Encoder(Direction.TC)
    assert enc.encode(MsgId.PING) == bytes.fromhex("1A CF FC 1D 10 24 C0 00 00 01 36 A3")
    assert enc.encode(MsgId.SET_MODE, mode=2) == \
        bytes.fromhex("1A CF FC 1D 10 20 C0 00 00 02 02 86 25")


def test_sequence_count_is_per_id_and_wraps_at_2_to_14():
    enc = Encoder(Direction.TC)
    seqs = [StreamDecoder(Direction.TC).feed(enc.encode(MsgId.PING))[0].seq
            for _ in range(16385)]
    assert seqs[:2] == [0, 1] and seqs[16383] == 16383 and seqs[16384] == 0
    assert StreamDecoder(Direction.TC).feed(enc.encode(MsgId.SET_MODE, mode=1))[0].seq == 0


def test_every_message_round_trips_and_has_its_documented_size():
    rng = np.random.default_rng(3)
    for msg in MESSAGES:
        enc = Encoder(msg.direction)
        values = {}
        for f in msg.fields:
            if f.choices:
                values[f.name] = f.choices[-1]
            elif f.type == "f32":
                values[f.name] = float(np.float32(rng.uniform(f.lo or 0, f.hi or 10)))
            else:
                values[f.name] = int(rng.integers(f.lo or 0, f.hi or 200))
        items = None
        if msg.item:
            items = np.zeros(7, dtype=msg.item_dtype)
            items["x"] = rng.uniform(0, 1600, 7).astype(np.float32)
            items["hip"] = rng.integers(0, 2**32, 7)
            values.pop(msg.count_field)
        frame = enc.encode(msg.id, items, **values)
        assert len(frame) == 12 + msg.min_size + (7 * msg.item_size if msg.item else 0)
        (p,) = StreamDecoder(msg.direction).feed(frame)
        assert p.msg is msg
        for k, v in values.items():
            assert p.values[k] == v
        if msg.item:
            assert p.values["count"] == 7
            assert np.array_equal(p.items, items)


def test_centroids_split_into_parts_of_40_that_stand_alone():
    stars = np.zeros(95, dtype=BY_ID[MsgId.CENTROIDS].item_dtype)
    stars["flux"] = np.arange(95)
    frames = Encoder().centroids(9, 123, stars, total=120)
    got = StreamDecoder().feed(frames[1] + frames[2])   # part 0 lost
    assert [(p.values["part"], p.values["parts"], p.values["count"]) for p in got] == \
        [(1, 3, 40), (2, 3, 15)]
    assert all(p.values["frame_id"] == 9 and p.values["total"] == 120 for p in got)
    assert got[1].items["flux"].tolist() == list(range(80, 95))


def test_encoder_refuses_bad_values_with_a_clear_message():
    enc = Encoder()
    with pytest.raises(ValueError, match="STATUS: missing field uptime_s"):
        enc.encode(MsgId.STATUS)
    with pytest.raises(ValueError, match="SET_MODE is TC, this encoder sends TM"):
        enc.encode(MsgId.SET_MODE, mode=1)
    with pytest.raises(ValueError, match="ACK: a value does not fit"):
        enc.encode(MsgId.ACK, cmd_id=-1, cmd_seq=0, code=0, rx_t_ns=0)


def test_command_ranges_reject_nan_and_out_of_range():
    gain = BY_ID[MsgId.SET_GAIN].fields[0]
    assert gain.valid(1.0) and gain.valid(16.0)
    assert not gain.valid(math.nan) and not gain.valid(0.99) and not gain.valid(math.inf)
    assert Reason.OUT_OF_RANGE == 4


def test_icd_and_c_header_match_the_message_table():
    # docs/protocol.md's generated tables and tools/fc/st_protocol.h on disk
    # must be what the table renders now.
    text = docgen.ICD_PATH.read_text(encoding="utf-8")
    assert docgen.apply_sections(text, docgen.render_sections()) == text
    assert docgen.HEADER_PATH.read_text(encoding="utf-8") == docgen.render_c_header()


def test_frame_builder_puts_length_minus_one_in_the_header():
    frame = build_packet(0x7FF, False, 5, b"\x00" * 10)
    assert frame[8:10] == (10 + 2 - 1).to_bytes(2, "big")
