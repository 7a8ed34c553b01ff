"""Framing: sync marker, CCSDS space-packet primary header, payload, CRC.

One packet on the wire (the word "frame" is kept for camera images) (all big-endian)::

    ASM      4 bytes  0x1A 0xCF 0xFC 0x1D (CCSDS attached sync marker)
    header   6 bytes  CCSDS space packet primary header (CCSDS 133.0-B-2):
                      version 3 bits = 0, type 1 bit (0 TM, 1 TC),
                      secondary-header flag 1 bit = 0, APID 11 bits (message id),
                      sequence flags 2 bits = 0b11 (unsegmented),
                      sequence count 14 bits (per APID, wraps),
                      packet data length 16 bits = len(payload) + 2 - 1
    payload  n bytes  the message (tracker.protocol.messages)
    CRC      2 bytes  CRC-16/CCITT-FALSE over header + payload (not the ASM):
                      poly 0x1021, init 0xFFFF, no reflection, xorout 0,
                      check("123456789") = 0x29B1

The CRC sits inside the packet data field, as CCSDS's optional packet error
control does, so the length field counts it.
"""

from __future__ import annotations

import binascii
import struct

__all__ = ["ASM", "HEADER", "OVERHEAD", "SEQ_MODULO", "crc16", "build_packet", "parse_header"]

ASM = b"\x1a\xcf\xfc\x1d"
HEADER = struct.Struct(">HHH")
CRC = struct.Struct(">H")
OVERHEAD = len(ASM) + HEADER.size + CRC.size   # 12 bytes around every payload
SEQ_MODULO = 1 << 14
_UNSEGMENTED = 0b11


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of data (binascii.crc_hqx is this CRC given init 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


def build_packet(apid: int, telecommand: bool, seq: int, payload: bytes) -> bytes:
    """ASM + primary header + payload + CRC for one packet."""
    header = HEADER.pack((int(telecommand) << 12) | (apid & 0x7FF),
                         (_UNSEGMENTED << 14) | (seq % SEQ_MODULO),
                         len(payload) + CRC.size - 1)
    body = header + payload
    return ASM + body + CRC.pack(crc16(body))


def parse_header(w0: int, w1: int, w2: int) -> tuple[int, int, int, int] | None:
    """(apid, type bit, seq, payload length) of a plausible header, else None.

    Plausible: version 0, no secondary header, sequence flags 0b11, room for the CRC.
    """
    if w0 >> 13 or (w0 >> 11) & 1 or w1 >> 14 != _UNSEGMENTED or w2 < 1:
        return None
    return w0 & 0x7FF, (w0 >> 12) & 1, w1 & (SEQ_MODULO - 1), w2 + 1 - CRC.size
