"""Bandwidth budget: what the UART carries at a baud rate.

8N1 framing puts 10 bits on the line per byte (start, 8 data, stop), so a
UART at ``baud`` carries ``baud / 10`` bytes per second. The link's writer
uses ``bandwidth_fraction`` of that (LinkConfig), leaving slack for jitter.
"""

from __future__ import annotations

from tracker.protocol.framing import OVERHEAD
from tracker.protocol.messages import BY_ID, MAX_STARS_PER_PACKET, MsgId

__all__ = ["BITS_PER_BYTE", "bytes_per_second", "packet_bytes", "centroids_bytes",
           "load_bytes_per_second"]

BITS_PER_BYTE = 10


def bytes_per_second(baudrate: float) -> float:
    """Bytes per second a UART at baudrate (8N1) carries."""
    return baudrate / BITS_PER_BYTE


def packet_bytes(msg_id: int, items: int = 0) -> int:
    """Bytes on the wire of one packet of msg_id carrying items repeated items."""
    msg = BY_ID[MsgId(msg_id)]
    return OVERHEAD + msg.min_size + items * msg.item_size


def centroids_bytes(stars: int) -> int:
    """Bytes on the wire of all CENTROIDS parts for one image frame with ``stars`` stars."""
    parts = max(1, -(-stars // MAX_STARS_PER_PACKET))
    return parts * packet_bytes(MsgId.CENTROIDS) + stars * BY_ID[MsgId.CENTROIDS].item_size


def load_bytes_per_second(attitude_hz: float, centroids_hz: float, status_hz: float,
                          stars: int) -> float:
    """Telemetry bytes per second at these output rates with stars per CENTROIDS frame."""
    return (attitude_hz * packet_bytes(MsgId.ATTITUDE)
            + centroids_hz * centroids_bytes(stars)
            + status_hz * packet_bytes(MsgId.STATUS))
