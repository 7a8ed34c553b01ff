"""Streaming decoder: bytes in any chunking -> intact packets, with drop counters.

Algorithm (the ICD's "resynchronisation" section says the same):

1. Search the buffer for the ASM. Bytes before it are discarded.
2. With 10 bytes from the ASM, check the header is plausible (version 0,
   expected type bit, no secondary header, sequence flags 0b11, payload no
   longer than the largest message of that direction). If not, discard one
   byte and search again.
3. Wait for the whole packet, then check the CRC. If it fails, discard one
   byte (not the packet: a false ASM in noise may claim bytes that hold a
   real packet) and search again.
4. With a good CRC the packet is consumed. An unknown id, a wrong length or
   (when validating) an out-of-range field drops the packet with that reason.

It never raises on input bytes, and its buffer never exceeds one chunk
(4096 bytes) plus the largest packet. Counters (:attr:`StreamDecoder.counters`):
``packets`` delivered, ``bad_header`` (plausibility failures), ``bad_crc``,
``unknown_id``, ``wrong_length``, ``out_of_range``, ``truncated`` (a packet
still unfinished at :meth:`StreamDecoder.flush`), and ``bytes_dropped``
(every byte not in a delivered packet: bytes fed = bytes_dropped + the
bytes of delivered packets + the bytes still buffered).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.protocol.framing import ASM, CRC, HEADER, OVERHEAD, crc16, parse_header
from tracker.protocol.messages import BY_ID, Direction, MessageDef, PayloadError, Reason

__all__ = ["Packet", "Rejection", "StreamDecoder"]

_CHUNK = 4096
_REASON_KEY = {Reason.BAD_CRC: "bad_crc", Reason.UNKNOWN_ID: "unknown_id",
               Reason.WRONG_LENGTH: "wrong_length", Reason.OUT_OF_RANGE: "out_of_range"}


@dataclass
class Packet:
    """One decoded packet: its definition, header fields, values and items."""

    msg: MessageDef
    seq: int
    values: dict
    items: np.ndarray | None
    wire: bytes          # the whole packet as received: ASM, header, payload, CRC

    @property
    def id(self) -> int:
        return self.msg.id

    @property
    def name(self) -> str:
        return self.msg.name


@dataclass
class Rejection:
    """A packet with a plausible header that was dropped, and why (the tracker NACKs it)."""

    apid: int
    seq: int
    reason: Reason


class StreamDecoder:
    """Decode packets of one direction from a byte stream.

    Parameters
    ----------
    direction : Direction
        Which packets to accept: TM (the FC's side) or TC (the tracker's side).
    validate : bool
        Check fields against their valid ranges (commands have them).
    keep_rejects : bool
        Also return a :class:`Rejection`, in stream order, for each packet
        whose header was plausible but which is dropped for BAD_CRC,
        UNKNOWN_ID, WRONG_LENGTH or OUT_OF_RANGE: the tracker NACKs these.
    """

    def __init__(self, direction: Direction = Direction.TM, validate: bool = True,
                 keep_rejects: bool = False) -> None:
        self.direction = Direction(direction)
        self.validate = validate
        self.keep_rejects = keep_rejects
        self._defs = {m.id: m for m in BY_ID.values() if m.direction == self.direction}
        self.max_payload = max(m.max_size for m in self._defs.values())
        self.max_buffer = _CHUNK + self.max_payload + OVERHEAD
        self._buf = bytearray()
        self.counters = dict.fromkeys(("packets", "bad_header", "bad_crc", "unknown_id",
                                       "wrong_length", "out_of_range", "truncated",
                                       "bytes_dropped"), 0)

    def feed(self, data: bytes) -> list[Packet | Rejection]:
        """Packets completed by data (any length, any split), in stream order."""
        out: list[Packet | Rejection] = []
        for off in range(0, len(data), _CHUNK):
            self._buf += data[off:off + _CHUNK]
            self._scan(out)
        return out

    def flush(self) -> list[Packet | Rejection]:
        """End of stream: no more bytes will come, so an unfinished packet is truncated.

        Each one is counted as ``truncated``, one byte is dropped, and the
        search goes on in the bytes after it (which may hold whole packets).
        """
        out: list[Packet | Rejection] = []
        self._scan(out, eof=True)
        return out

    def _reject(self, out: list, apid: int, seq: int, reason: Reason) -> None:
        self.counters[_REASON_KEY[reason]] += 1
        if self.keep_rejects:
            out.append(Rejection(apid, seq, reason))

    def _scan(self, out: list, eof: bool = False) -> None:
        buf = self._buf
        pos = 0
        dropped = 0
        while True:
            i = buf.find(ASM, pos)
            if i < 0:
                keep = len(buf) if eof else max(pos, len(buf) - (len(ASM) - 1))
                dropped += keep - pos
                pos = keep
                break
            dropped += i - pos
            pos = i
            end = self._packet_at(buf, i, eof, out)
            if end == 0:
                break
            if end < 0:
                dropped += 1
                pos = i + 1
            else:
                pos = end
        self.counters["bytes_dropped"] += dropped
        del buf[:pos]

    def _packet_at(self, buf: bytearray, i: int, eof: bool, out: list) -> int:
        """Take the packet whose ASM is at i: its end if consumed, 0 to wait, -1 to skip a byte."""
        short = len(buf) - i < len(ASM) + HEADER.size
        hdr = None if short else parse_header(*HEADER.unpack_from(buf, i + len(ASM)))
        if not short and (hdr is None or hdr[1] != self.direction or hdr[3] > self.max_payload):
            self.counters["bad_header"] += 1
            return -1
        end = i + OVERHEAD + (0 if short else hdr[3])
        if short or len(buf) < end:
            if not eof:
                return 0
            self.counters["truncated"] += 1
            return -1
        apid, _, seq, _ = hdr
        body = bytes(buf[i + len(ASM):end - CRC.size])
        if crc16(body) != CRC.unpack_from(buf, end - CRC.size)[0]:
            self._reject(out, apid, seq, Reason.BAD_CRC)
            return -1
        packet = self._parse(out, apid, seq, body[HEADER.size:], bytes(buf[i:end]))
        if packet is None:
            self.counters["bytes_dropped"] += end - i
        else:
            out.append(packet)
        return end

    def _parse(self, out: list, apid: int, seq: int, payload: bytes,
               wire: bytes) -> Packet | None:
        msg = self._defs.get(apid)
        if msg is None:
            self._reject(out, apid, seq, Reason.UNKNOWN_ID)
            return None
        try:
            values, items = msg.unpack(payload, self.validate)
        except PayloadError as exc:
            self._reject(out, apid, seq, exc.reason)
            return None
        self.counters["packets"] += 1
        return Packet(msg, seq, values, items, wire)
