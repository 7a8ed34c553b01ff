"""Encoder: message values -> packets, with a sequence count per message id."""

from __future__ import annotations

import numpy as np

from tracker.protocol.framing import SEQ_MODULO, build_packet
from tracker.protocol.messages import BY_ID, MAX_STARS_PER_PACKET, Direction, MsgId

__all__ = ["Encoder"]


class Encoder:
    """Builds packets; each message id has its own 14-bit sequence count (CCSDS).

    The tracker uses one with ``Direction.TM``; the flight computer (and
    ``tracker monitor``) one with ``Direction.TC``. Not thread-safe: one
    encoder per sending thread.
    """

    def __init__(self, direction: Direction = Direction.TM) -> None:
        self.direction = Direction(direction)
        self._seq: dict[int, int] = {}

    def encode(self, msg_id: int, items: np.ndarray | None = None, /, **values) -> bytes:
        """One packet of message msg_id; values by field name (ValueError if one is bad)."""
        msg = BY_ID[MsgId(msg_id)]
        if msg.direction != self.direction:
            raise ValueError(f"{msg.name} is {msg.direction.name}, this encoder sends "
                             f"{self.direction.name}")
        seq = self._seq.get(msg.id, 0)
        self._seq[msg.id] = (seq + 1) % SEQ_MODULO
        return build_packet(msg.id, bool(self.direction), seq, msg.pack(values, items))

    def centroids(self, frame_id: int, t_ns: int, stars: np.ndarray,
                  total: int | None = None) -> list[bytes]:
        """CENTROIDS packets for stars (rows with x, y, flux, hip, flags), 40 per part.

        ``total`` is the number detected (default len(stars)); an image frame with
        no stars still gives one part with count 0.
        """
        n = len(stars)
        parts = max(1, -(-n // MAX_STARS_PER_PACKET))
        if parts > 255:
            raise ValueError(f"CENTROIDS: {n} stars need {parts} parts, at most 255")
        total = n if total is None else total
        return [self.encode(MsgId.CENTROIDS,
                            stars[k * MAX_STARS_PER_PACKET:(k + 1) * MAX_STARS_PER_PACKET],
                            frame_id=frame_id, t_ns=t_ns, part=k, parts=parts,
                            total=min(total, 0xFFFF))
                for k in range(parts)]
