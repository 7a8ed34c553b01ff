"""The daemon's STATUS as one immutable value, built from the ICD's message table.

:data:`StatusSnapshot` is a named tuple with one field per STATUS field of
``tracker/protocol/messages.py`` except the three the link fills in from its
own counters (``tracker.protocol.link.LINK_STATUS_FIELDS``). It is generated
from the table, so a field added to STATUS there appears here by itself
(default 0, or NaN for a float) and the loop sets it by name. The frame loop
builds a new snapshot on every tick and hands it to the link, which reads it
on its own thread for REQUEST_STATUS; the link never reads the daemon's
state. Integers saturate at their wire type when sent.

A named tuple rather than a frozen dataclass: the loop makes one per tick
for as long as the service runs, and under CPython 3.11 with the link's
threads alive a frozen, slotted dataclass made this way held on to about one
allocated block per four ticks (``sys.getallocatedblocks``), a tuple none.
"""

from __future__ import annotations

import collections
import math

from tracker.protocol.link import LINK_STATUS_FIELDS
from tracker.protocol.messages import BY_ID, MsgId

__all__ = ["StatusSnapshot", "status_values"]

_FIELDS = [f for f in BY_ID[MsgId.STATUS].fields if f.name not in LINK_STATUS_FIELDS]

StatusSnapshot = collections.namedtuple(
    "StatusSnapshot", [f.name for f in _FIELDS],
    defaults=[math.nan if f.type == "f32" else 0 for f in _FIELDS])
StatusSnapshot.__doc__ = ("The daemon's STATUS fields at one instant (see the module "
                          "docstring); units as in the ICD's STATUS table.")


def status_values(snapshot) -> dict:
    """The snapshot as STATUS field values (name -> value)."""
    return snapshot._asdict()
