"""The daemon's STATUS as one immutable value, built from the ICD's message table.

:class:`StatusSnapshot` has one attribute per STATUS field of
``tracker/protocol/messages.py`` except the three the link fills in from its
own counters (``tracker.protocol.link.LINK_STATUS_FIELDS``). It is generated
from the table, so a field added to STATUS there appears here by itself
(default 0, or NaN for a float) and the loop sets it by name. The frame
loop builds a new snapshot on every tick and hands it to the link, which
reads it on its own thread for REQUEST_STATUS; the link never reads the
daemon's state. Integers saturate at their wire type when sent.
"""

from __future__ import annotations

import dataclasses
import math

from tracker.protocol.link import LINK_STATUS_FIELDS
from tracker.protocol.messages import BY_ID, MsgId

__all__ = ["StatusSnapshot", "status_values"]


def _snapshot_class() -> type:
    spec = []
    for f in BY_ID[MsgId.STATUS].fields:
        if f.name in LINK_STATUS_FIELDS:
            continue
        is_float = f.type == "f32"
        spec.append((f.name, float if is_float else int,
                     dataclasses.field(default=math.nan if is_float else 0)))
    cls = dataclasses.make_dataclass("StatusSnapshot", spec, frozen=True, slots=True)
    cls.__module__ = __name__
    cls.__doc__ = ("The daemon's STATUS fields at one instant (see the module docstring); "
                   "units as in the ICD's STATUS table.")
    return cls


StatusSnapshot = _snapshot_class()


def status_values(snapshot) -> dict:
    """The snapshot as STATUS field values (name -> value)."""
    return {f.name: getattr(snapshot, f.name) for f in dataclasses.fields(snapshot)}
