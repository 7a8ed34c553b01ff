"""Serial protocol between the star tracker and the flight computer (FC).

The contract is docs/protocol.md (the ICD); this package implements it.

- :mod:`~tracker.protocol.messages`: every message, declared once
  (:data:`MESSAGES`); encoder, decoder, the ICD's tables and the FC's C
  header (tools/fc/st_protocol.h, via :mod:`~tracker.protocol.docgen`) all
  come from it.
- :mod:`~tracker.protocol.framing`: CCSDS sync marker + space-packet
  primary header + CRC-16/CCITT-FALSE, big-endian.
- :mod:`~tracker.protocol.encoder` / :mod:`~tracker.protocol.decoder`:
  packets out; a streaming decoder that resynchronises after noise and
  counts what it drops, never raising on wire bytes.
- :mod:`~tracker.protocol.link`: the tracker's end of the UART (pyserial):
  a paced writer thread with a bounded queue per class (ATTITUDE first), a
  command reader that answers every command, reopening with backoff. The
  daemon implements :class:`CommandHandler` (tracker.daemon.link).
- :mod:`~tracker.protocol.budget`: what fits at a baud rate.
- :mod:`~tracker.protocol.nullmodem`: pseudo-terminals standing in for the
  cable (demo, benchmarks, tests).

Words: a *packet* is one unit on the wire; a *frame* is a camera image.

The daemon's use::

    from tracker.protocol import Link, Mode, Reason

    with Link(cfg.link, handler) as link:        # handler: a CommandHandler
        link.send_attitude(frame_id=n, t_ns=t, q=q, sigma_cross_arcsec=s1,
                           sigma_roll_arcsec=s2, matched=m, mode=Mode.TRACKING)
        link.send_centroids(n, t, stars)          # x, y, flux, hip, flags rows
        link.send_status(uptime_s=..., ...)       # STATUS fields
        link.stats()                              # counters for health
"""

from tracker.protocol.decoder import Packet, Rejection, StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.link import CommandHandler, Link
from tracker.protocol.messages import (
    BY_ID,
    MESSAGES,
    AttitudeFlag,
    Direction,
    Mode,
    MsgId,
    Reason,
)

__all__ = ["Packet", "Rejection", "StreamDecoder", "Encoder", "CommandHandler", "Link",
           "BY_ID", "MESSAGES", "AttitudeFlag", "Direction", "Mode", "MsgId", "Reason"]
