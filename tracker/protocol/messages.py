"""Every message of the serial protocol, declared once.

The table :data:`MESSAGES` is the single source of truth: the encoder and the
decoder pack and unpack with it, :mod:`tracker.protocol.docgen` renders the
ICD's tables (docs/protocol.md) and the C header (tools/fc/) from it, and a
test checks that both files on disk still match.

Byte order is big-endian (network order) throughout. Integers are unsigned
and in the unit given; floats are IEEE-754 binary32. There is no scaling:
a field's value on the wire is its value in its unit.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tracker.astrometry.observer import VELOCITY_LIMIT_KM_S, Correction, TimeSource
from tracker.astrometry.timescale import TAI_NS_MAX, TAI_NS_MIN

__all__ = [
    "Field", "MessageDef", "MsgId", "Mode", "Reason", "AttitudeFlag", "ErrorCode",
    "ERROR_MEANING", "Direction", "TimeSource", "Correction",
    "MESSAGES", "BY_ID", "TYPES", "MAX_STARS_PER_PACKET", "PayloadError", "saturate",
]

# wire type -> (struct code, size in bytes, C type, numpy big-endian dtype)
TYPES = {
    "u8": ("B", 1, "uint8_t", ">u1"),
    "u16": ("H", 2, "uint16_t", ">u2"),
    "u32": ("I", 4, "uint32_t", ">u4"),
    "u64": ("Q", 8, "uint64_t", ">u8"),
    "f32": ("f", 4, "float", ">f4"),
}

MAX_STARS_PER_PACKET = 40


class Direction(enum.IntEnum):
    """The CCSDS packet-type bit: 0 telemetry (tracker -> FC), 1 telecommand (FC -> tracker)."""

    TM = 0
    TC = 1


class MsgId(enum.IntEnum):
    """Message ids; each is the packet's CCSDS APID (11 bits)."""

    ATTITUDE = 0x001
    CENTROIDS = 0x002
    STATUS = 0x003
    ACK = 0x010
    NACK = 0x011
    SET_MODE = 0x020
    SET_EXPOSURE = 0x021
    SET_GAIN = 0x022
    SET_OUTPUT = 0x023
    PING = 0x024
    REQUEST_STATUS = 0x025
    TIME_SYNC = 0x026
    SET_VELOCITY = 0x027


class Mode(enum.IntEnum):
    """Operating mode (SET_MODE, ATTITUDE.mode, STATUS.mode)."""

    STANDBY = 0
    LOST_IN_SPACE = 1
    TRACKING = 2
    FAULT = 3          # reported only (no camera, or frames failing); SET_MODE refuses it


class Reason(enum.IntEnum):
    """ACK/NACK code: 0 in every ACK, one of the others in a NACK."""

    OK = 0
    BAD_CRC = 1        # header plausible, CRC wrong; id and seq echoed may be corrupt
    UNKNOWN_ID = 2     # CRC good, no such command
    WRONG_LENGTH = 3   # CRC good, payload length not the command's
    OUT_OF_RANGE = 4   # a field outside its valid range (NaN included)
    REJECTED = 5       # valid, but refused in the tracker's present state
    INTERNAL = 6       # the tracker failed while applying it


class AttitudeFlag(enum.IntFlag):
    """Bits of ATTITUDE.flags; the other bits are reserved and sent as 0."""

    VALID = 1          # the quaternion and sigmas hold a solution for this frame
    RATE_VALID = 2     # rate_x/y/z hold a rate from two solutions at most
    #                    identify.track_max_gap_s apart, 1-sigma below
    #                    identify.rate_valid_sigma_deg_s on every axis (section 2.2)
    TIME_SYNCED = 4    # t_ns is TAI ns since 1970 (STATUS time_source: from where), else the
    #                    tracker's monotonic clock
    ANNUAL_ABERRATION = 8    # with VALID: corrected for the Earth's velocity (q is ICRS)
    OBSERVER_VELOCITY = 16   # with VALID: also for the observer's velocity (SET_VELOCITY)


class ErrorCode(enum.IntEnum):
    """STATUS.last_error: the latest fault the tracker survived (:data:`ERROR_MEANING`)."""

    NONE = 0
    FRAME_UNREADABLE = 1
    CAMERA_TIMEOUT = 2
    CAMERA_LOST = 3
    STAGE_ERROR = 4
    LINK_ERROR = 5
    RX_REJECT = 6
    TX_DROP = 7
    LINK_INTERNAL = 8


# What each ErrorCode means; the ICD's table is rendered from this.
ERROR_MEANING = {
    ErrorCode.NONE: "no fault since the service started",
    ErrorCode.FRAME_UNREADABLE: "a frame arrived broken (bad buffer, corrupt file); skipped",
    ErrorCode.CAMERA_TIMEOUT: "no frame within the frame period + capture.timeout_s",
    ErrorCode.CAMERA_LOST: "the camera is absent or failed; closed and reopened every "
                           "service.retry_max_s at most",
    ErrorCode.STAGE_ERROR: "detection or identification failed on a frame; that frame dropped",
    ErrorCode.LINK_ERROR: "the serial port failed or would not open; reopened with backoff",
    ErrorCode.RX_REJECT: "an FC packet was dropped or NACKed (header, CRC, id, length, range)",
    ErrorCode.TX_DROP: "a telemetry packet or reply was shed (its queue full, or stale)",
    ErrorCode.LINK_INTERNAL: "the link's own code failed while serving the FC; caught, "
                             "the link goes on",
}


class PayloadError(ValueError):
    """A payload that does not fit its message; ``reason`` says how."""

    def __init__(self, reason: Reason, text: str) -> None:
        super().__init__(text)
        self.reason = reason


@dataclass(frozen=True)
class Field:
    """One payload field: wire type, unit, meaning, and for commands the valid values."""

    name: str
    type: str
    unit: str
    doc: str
    lo: float | None = None
    hi: float | None = None
    choices: tuple[int, ...] | None = None
    also: tuple[float, ...] = ()     # values valid outside lo .. hi (e.g. 0 = off)

    def bounds(self) -> tuple[float | None, float | None]:
        """lo and hi as the wire holds them: rounded to binary32 for f32 fields.

        So a bound such as 0.01 accepts the FC's 0.01f, as the C check does.
        """
        if self.type != "f32":
            return self.lo, self.hi
        return tuple(None if b is None else float(np.float32(b)) for b in (self.lo, self.hi))

    def valid(self, value) -> bool:
        """True when value is allowed (NaN never is when a range is given)."""
        if value in self.also:
            return True
        if self.choices is not None and value not in self.choices:
            return False
        lo, hi = self.bounds()
        if lo is not None and not value >= lo:
            return False
        return not (hi is not None and not value <= hi)

    def range_text(self) -> str:
        if self.choices is not None:
            return ", ".join(str(c) for c in self.choices)
        if self.lo is None or self.hi is None:
            return ""
        text = " .. ".join(str(b) if isinstance(b, int) else f"{b:g}" for b in (self.lo, self.hi))
        return ", ".join([*(f"{a:g}" for a in self.also), text]) if self.also else text


@dataclass(frozen=True)
class MessageDef:
    """A message: id, direction, fixed fields, and optionally a repeated item group.

    With ``item`` set, the fixed fields are followed by ``count`` items
    (``count_field`` holds count, at most ``max_items``).
    """

    id: MsgId
    direction: Direction
    doc: str
    fields: tuple[Field, ...]
    item: tuple[Field, ...] = ()
    count_field: str | None = None
    max_items: int = 0
    priority: int | None = None   # link queue class, 0 = first; None for commands

    @property
    def name(self) -> str:
        return self.id.name

    @cached_property
    def head(self) -> struct.Struct:
        return struct.Struct(">" + "".join(TYPES[f.type][0] for f in self.fields))

    @cached_property
    def item_dtype(self) -> np.dtype:
        """Big-endian numpy dtype of one item (empty when there is no item group)."""
        return np.dtype([(f.name, TYPES[f.type][3]) for f in self.item])

    @property
    def item_size(self) -> int:
        return sum(TYPES[f.type][1] for f in self.item)

    @property
    def min_size(self) -> int:
        return self.head.size

    @property
    def max_size(self) -> int:
        return self.head.size + self.max_items * self.item_size

    def pack(self, values: dict, items: np.ndarray | None = None) -> bytes:
        """The payload of values (dict by field name) and items (rows with the item fields).

        Raises ValueError naming the message if a value is missing or does not fit.
        """
        vals = dict(values)
        n = 0
        if self.item:
            n = 0 if items is None else len(items)
            if n > self.max_items:
                raise ValueError(f"{self.name}: {n} items, at most {self.max_items}")
            vals[self.count_field] = n
        try:
            head = self.head.pack(*[vals[f.name] for f in self.fields])
        except KeyError as exc:
            raise ValueError(f"{self.name}: missing field {exc.args[0]}") from None
        except struct.error as exc:
            raise ValueError(f"{self.name}: a value does not fit: {exc}") from None
        if not n:
            return head
        body = np.empty(n, dtype=self.item_dtype)
        for f in self.item:
            body[f.name] = items[f.name]
        return head + body.tobytes()

    def unpack(self, payload: bytes, validate: bool = True) -> tuple[dict, np.ndarray | None]:
        """Values and items of a payload; PayloadError (WRONG_LENGTH/OUT_OF_RANGE) if bad."""
        if len(payload) < self.head.size:
            raise PayloadError(Reason.WRONG_LENGTH, f"{self.name}: {len(payload)} bytes, "
                               f"expected at least {self.head.size}")
        values = dict(zip((f.name for f in self.fields), self.head.unpack_from(payload),
                          strict=True))
        items = None
        n = values[self.count_field] if self.item else 0
        expected = self.head.size + n * self.item_size
        if len(payload) != expected:
            raise PayloadError(Reason.WRONG_LENGTH, f"{self.name}: {len(payload)} bytes, "
                               f"expected {expected}")
        if self.item:
            if n > self.max_items:
                raise PayloadError(Reason.OUT_OF_RANGE, f"{self.name}: {n} items, at most "
                                   f"{self.max_items}")
            items = np.frombuffer(payload, dtype=self.item_dtype, count=n,
                                  offset=self.head.size)
        if validate:
            for f in self.fields:
                if not f.valid(values[f.name]):
                    raise PayloadError(Reason.OUT_OF_RANGE, f"{self.name}.{f.name}: "
                                       f"{values[f.name]!r} outside {f.range_text()}")
        return values, items


def _f(name, type_, unit, doc, **kw) -> Field:
    return Field(name, type_, unit, doc, **kw)


_FRAME_ID = _f("frame_id", "u32", "", "frame counter since start, wraps at 2^32")
_T_NS = _f("t_ns", "u64", "ns", "exposure mid-point: TAI ns since 1970 when TIME_SYNCED, "
           "else the tracker's monotonic clock (section 6)")
_REPLY = (
    _f("cmd_id", "u16", "", "id (APID) of the command answered"),
    _f("cmd_seq", "u16", "", "sequence count of the command answered"),
    _f("code", "u8", "", "reason code (0 in ACK)"),
    _f("rx_t_ns", "u64", "ns", "tracker monotonic time when the command was received"),
)
_TM, _TC = Direction.TM, Direction.TC

MESSAGES: tuple[MessageDef, ...] = (
    MessageDef(MsgId.ATTITUDE, _TM, "attitude of one frame", (
        _FRAME_ID, _T_NS,
        _f("q_w", "f32", "", "quaternion scalar part, >= 0; v_cam = R(q) v_icrs"),
        _f("q_x", "f32", "", "quaternion x"),
        _f("q_y", "f32", "", "quaternion y"),
        _f("q_z", "f32", "", "quaternion z"),
        _f("sigma_cross_arcsec", "f32", "arcsec", "1-sigma cross-boresight error"),
        _f("sigma_roll_arcsec", "f32", "arcsec", "1-sigma error about the boresight"),
        _f("rate_x", "f32", "deg/s", "angular rate about camera +X; NaN unless RATE_VALID"),
        _f("rate_y", "f32", "deg/s", "angular rate about camera +Y; NaN unless RATE_VALID"),
        _f("rate_z", "f32", "deg/s", "angular rate about camera +Z; NaN unless RATE_VALID"),
        _f("matched", "u16", "stars", "catalogue stars matched"),
        _f("mode", "u8", "", "Mode"),
        _f("flags", "u16", "", "AttitudeFlag bits"),
    ), priority=0),
    MessageDef(MsgId.CENTROIDS, _TM, "star centroids of one frame, brightest first, "
               "split over parts", (
        _FRAME_ID, _T_NS,
        _f("part", "u8", "", "index of this packet among the frame's parts, from 0"),
        _f("parts", "u8", "", "number of parts for this frame"),
        _f("total", "u16", "stars", "stars detected in the frame (may exceed those sent)"),
        _f("count", "u8", "stars", f"items in this packet, 0 .. {MAX_STARS_PER_PACKET}"),
    ), item=(
        _f("x", "f32", "px", "column; origin at the centre of the top-left pixel"),
        _f("y", "f32", "px", "row; same origin"),
        _f("flux", "f32", "ADU", "background-subtracted sum"),
        _f("hip", "u32", "", "Hipparcos number of the matched star, 0 if none"),
        _f("flags", "u16", "", "StarFlag bits: 1 saturated, 2 edge, 4 elongated, 8 blended, "
                            "16 extended"),
    ), count_field="count", max_items=MAX_STARS_PER_PACKET, priority=2),
    MessageDef(MsgId.STATUS, _TM, "health and settings", (
        _f("uptime_s", "u32", "s", "time since the service started"),
        _f("frame_rate_hz", "f32", "Hz", "frames processed per second, last few seconds"),
        _f("exposure_us", "u32", "us", "exposure time in use"),
        _f("gain", "f32", "x", "analogue gain in use (factor)"),
        _f("cpu_temp_c", "f32", "degC", "SoC temperature; NaN if unknown"),
        _f("mode", "u8", "", "Mode"),
        _f("frames", "u32", "", "frames received from the camera (processed, skipped in "
           "STANDBY, or lost)"),
        _f("capture_faults", "u32", "", "frames lost: unreadable, timed out, camera lost, "
           "or dropped by a failing stage"),
        _f("solve_failures", "u32", "", "frames with stars but no attitude"),
        _f("link_drops", "u32", "", "telemetry packets and replies the link shed (queue "
           "full or stale)"),
        _f("link_reopens", "u16", "", "times the serial port was reopened"),
        _f("rx_rejects", "u32", "", "FC packets dropped or NACKed: implausible header, bad "
           "CRC, unknown id, wrong length, out of range"),
        _f("last_error", "u16", "", "ErrorCode of the latest fault, 0 = none since start"),
        _f("config_crc", "u32", "", "checksum of the effective configuration"),
        _f("time_source", "u8", "", "TimeSource of the latest frame's absolute time "
           "(before the first frame: what one would get now)"),
        _f("corrections", "u8", "", "Correction bits the solver applies to the latest frame "
           "(before the first frame: what it would apply now)"),
        _f("psf_fwhm_px", "f32", "px", "the stars' full width at half maximum as the detector "
           "measures it, smoothed over frames (the focus); NaN until measured"),
    ), priority=3),
    MessageDef(MsgId.ACK, _TM, "command accepted", _REPLY, priority=1),
    MessageDef(MsgId.NACK, _TM, "command refused; nothing changed", _REPLY, priority=1),
    MessageDef(MsgId.SET_MODE, _TC, "change operating mode", (
        _f("mode", "u8", "", "Mode", choices=(Mode.STANDBY, Mode.LOST_IN_SPACE,
                                              Mode.TRACKING)),)),
    MessageDef(MsgId.SET_EXPOSURE, _TC, "set the exposure time", (
        _f("exposure_us", "u32", "us", "exposure time; clamped to the tracker's configured "
           "limits", lo=10, hi=1_000_000),)),
    MessageDef(MsgId.SET_GAIN, _TC, "set the analogue gain", (
        _f("gain", "f32", "x", "analogue gain factor; clamped to the tracker's configured "
           "limit", lo=1.0, hi=16.0),)),
    MessageDef(MsgId.SET_OUTPUT, _TC, "set one telemetry message's output rate", (
        _f("msg_id", "u16", "", "ATTITUDE, CENTROIDS or STATUS id",
           choices=(MsgId.ATTITUDE, MsgId.CENTROIDS, MsgId.STATUS)),
        _f("rate_hz", "f32", "Hz", "output rate, 0 = off", lo=0.01, hi=100.0, also=(0.0,)),
    )),
    MessageDef(MsgId.PING, _TC, "link check; answered by ACK", ()),
    MessageDef(MsgId.REQUEST_STATUS, _TC, "ACK, then one STATUS at once", ()),
    MessageDef(MsgId.TIME_SYNC, _TC, "the FC's absolute time (TAI) at the first byte of "
               "this packet", (
        _f("fc_time_ns", "u64", "ns", "TAI ns since 1970-01-01T00:00:00 TAI when the first "
           "ASM byte left the FC's UART (1972 .. 2200)", lo=TAI_NS_MIN, hi=TAI_NS_MAX),)),
    MessageDef(MsgId.SET_VELOCITY, _TC, "the observer's velocity relative to the Earth's "
               "centre, for aberration (section 6.2)", (
        _f("t_ns", "u64", "ns", "TAI ns since 1970 at which the velocity holds (1972 .. 2200)",
           lo=TAI_NS_MIN, hi=TAI_NS_MAX),
        _f("vx_km_s", "f32", "km/s", "along ICRS +X (RA 0, Dec 0)",
           lo=-VELOCITY_LIMIT_KM_S, hi=VELOCITY_LIMIT_KM_S),
        _f("vy_km_s", "f32", "km/s", "along ICRS +Y (RA 90 deg, Dec 0)",
           lo=-VELOCITY_LIMIT_KM_S, hi=VELOCITY_LIMIT_KM_S),
        _f("vz_km_s", "f32", "km/s", "along ICRS +Z (Dec +90 deg)",
           lo=-VELOCITY_LIMIT_KM_S, hi=VELOCITY_LIMIT_KM_S),
    )),
)

BY_ID: dict[int, MessageDef] = {m.id: m for m in MESSAGES}


def saturate(msg_id: int, values: dict) -> dict:
    """values with every integer field of msg_id clamped to its wire type (0 .. 2^bits - 1).

    Counters and times saturate at their type's maximum instead of failing to
    pack (ICD section 5.2); values of other fields pass unchanged.
    """
    out = dict(values)
    for f in BY_ID[MsgId(msg_id)].fields:
        if f.type != "f32" and f.name in out:
            out[f.name] = min(max(int(out[f.name]), 0), (1 << (8 * TYPES[f.type][1])) - 1)
    return out
