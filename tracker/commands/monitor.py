"""``tracker monitor PORT``: the flight computer's view of the link, for integrators.

Decodes telemetry live and prints one line per packet (ATTITUDE as boresight
RA/Dec and roll, rates, counters), sends commands (``--send ping``,
``--send set-mode tracking``, repeatable; the port may come before or after
them), and logs the raw bytes or the decoded packets (JSON lines, flushed
per packet) to a file. A port error is reported and the port reopened.
Stops after ``--count`` packets, ``--duration`` seconds, or Ctrl-C, then
prints the counters (packets per message, sequence gaps, decoder drops,
port errors).
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
import serial

from tracker.astrometry.observer import Correction, TimeSource
from tracker.astrometry.timescale import TimeError, tai_minus_utc_s, utc_iso_from_tai_ns
from tracker.attitude import matrix_from_quat, radec_roll_from_matrix
from tracker.commands.argtypes import count, non_negative, positive_count
from tracker.commands.outputs import close_output, open_output
from tracker.errors import UserError
from tracker.protocol.decoder import Packet, StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.framing import SEQ_MODULO
from tracker.protocol.messages import AttitudeFlag, Direction, Mode, MsgId, Reason

_MODES = {"standby": Mode.STANDBY, "lost-in-space": Mode.LOST_IN_SPACE,
          "tracking": Mode.TRACKING}
_OUTPUTS = {"attitude": MsgId.ATTITUDE, "centroids": MsgId.CENTROIDS, "status": MsgId.STATUS}
_REOPEN_WAIT_S = 0.5
_USAGE = ("ping | request-status | time-sync | set-mode standby|lost-in-space|tracking | "
          "set-exposure US | set-gain X | set-output attitude|centroids|status HZ | "
          "set-velocity VX VY VZ")


def register(sub, common) -> None:
    p = sub.add_parser("monitor", parents=[common], help="FC side: decode and print the "
                       "tracker's packets live, send commands, log")
    p.add_argument("port", nargs="?", help="serial device or pyserial URL, e.g. /dev/ttyUSB0")
    p.add_argument("--baud", type=positive_count, default=None,
                   help="baud rate (default: link.baudrate)")
    p.add_argument("--send", nargs="+", action="append", default=[], metavar="CMD",
                   help=f"send a command first (repeatable): {_USAGE}")
    p.add_argument("--count", type=count, default=0, help="stop after N packets (0 = no limit)")
    p.add_argument("--duration", type=non_negative, default=0.0,
                   help="stop after S seconds (0 = no limit)")
    p.add_argument("--log", metavar="FILE", help="also write to FILE")
    p.add_argument("--log-format", choices=("raw", "jsonl"), default="jsonl",
                   help="raw bytes as received, or decoded packets as JSON lines")
    p.add_argument("--quiet", action="store_true", help="print only the final counters")
    p.set_defaults(func=run)


# command -> its arguments' names, as the usage shows them
_ARGUMENTS = {"ping": (), "request-status": (), "time-sync": (), "set-mode": ("MODE",),
              "set-exposure": ("US",), "set-gain": ("X",), "set-output": ("MESSAGE", "HZ"),
              "set-velocity": ("VX", "VY", "VZ")}


def host_tai_ns() -> int:
    """This computer's clock as TAI ns since 1970 (its UTC plus the leap seconds)."""
    utc_ns = time.time_ns()
    return utc_ns + tai_minus_utc_s(utc_ns / 1e9) * 1_000_000_000


def split_port(port: str | None, sends: list[list[str]]) -> tuple[str, list[list[str]]]:
    """The port and the ``--send`` groups, when the port came after a ``--send``.

    ``--send ping /dev/ttyUSB0`` gives argparse one group of two words; the
    words past what the last command takes are the port.
    """
    if port is None and sends and sends[-1][0].lower() in _ARGUMENTS:
        last = sends[-1]
        takes = len(_ARGUMENTS[last[0].lower()])
        if len(last) == takes + 2:
            return last[-1], [*sends[:-1], last[:-1]]
    if port is None:
        raise UserError("no serial port given: tracker monitor PORT [--send CMD ...]")
    return port, sends


def _number(words: list[str], word: str, kind: type, expected: str):
    try:
        value = kind(word)
    except ValueError:
        value = None
    if value is None or (kind is float and not math.isfinite(value)):
        raise UserError(f"--send {' '.join(words)}: found {word!r}, expected {expected}")
    return value


def build_command(encoder: Encoder, words: list[str]) -> bytes:
    """The frame for one ``--send`` command; UserError if it cannot be encoded."""
    name, args = words[0].lower(), words[1:]
    if name not in _ARGUMENTS:
        raise UserError(f"--send {name}: unknown command; expected one of: {_USAGE}")
    if len(args) != len(_ARGUMENTS[name]):
        shown = " ".join((name, *_ARGUMENTS[name]))
        raise UserError(f"--send {' '.join(words)}: found {len(args)} argument(s), expected "
                        f"{shown}")
    if name == "ping":
        values = (MsgId.PING, {})
    elif name == "request-status":
        values = (MsgId.REQUEST_STATUS, {})
    elif name == "time-sync":
        values = (MsgId.TIME_SYNC, {"fc_time_ns": host_tai_ns()})
    elif name == "set-velocity":
        v = [_number(words, a, float, "a velocity in km/s (ICRS axes, relative to the "
                                      "Earth's centre)") for a in args]
        values = (MsgId.SET_VELOCITY, {"t_ns": host_tai_ns(), "vx_km_s": v[0],
                                       "vy_km_s": v[1], "vz_km_s": v[2]})
    elif name == "set-mode":
        mode = _MODES.get(args[0].lower())
        if mode is None:
            mode = _number(words, args[0], int, "standby, lost-in-space, tracking or a mode "
                                                "number (to test the NACK)")
        values = (MsgId.SET_MODE, {"mode": mode})
    elif name == "set-exposure":
        values = (MsgId.SET_EXPOSURE, {"exposure_us": _number(
            words, args[0], int, "a whole number of microseconds")})
    elif name == "set-gain":
        values = (MsgId.SET_GAIN, {"gain": _number(words, args[0], float, "a number")})
    else:
        if args[0].lower() not in _OUTPUTS:
            raise UserError(f"--send {' '.join(words)}: found {args[0]!r}, expected attitude, "
                            "centroids or status")
        values = (MsgId.SET_OUTPUT, {"msg_id": _OUTPUTS[args[0].lower()],
                                     "rate_hz": _number(words, args[1], float, "a rate in Hz")})
    try:
        return encoder.encode(values[0], **values[1])
    except ValueError as exc:
        raise UserError(f"--send {' '.join(words)}: {exc}") from None


def _name(enum, value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return str(value)


def describe(p: Packet) -> str:
    """One human-readable line for a packet."""
    v = p.values
    head = f"{p.name:<10}seq {p.seq:5d}"
    if p.id == MsgId.ATTITUDE:
        if v["flags"] & AttitudeFlag.TIME_SYNCED:
            try:
                when = utc_iso_from_tai_ns(v["t_ns"])[:-7] + "Z"       # to the microsecond
            except TimeError:
                when = f"{v['t_ns']} ns TAI"
        else:
            when = f"{v['t_ns'] / 1e9:.6f} s"
        text = f"{head}  frame {v['frame_id']}  t {when}"
        if v["flags"] & AttitudeFlag.VALID:
            ra, dec, roll = radec_roll_from_matrix(matrix_from_quat(
                [v["q_w"], v["q_x"], v["q_y"], v["q_z"]]))
            text += (f"  RA {math.degrees(ra):9.4f} Dec {math.degrees(dec):+8.4f} "
                     f"roll {math.degrees(roll):8.4f} deg  sigma {v['sigma_cross_arcsec']:.1f}/"
                     f"{v['sigma_roll_arcsec']:.1f} arcsec")
        else:
            text += "  no attitude"
        if v["flags"] & AttitudeFlag.RATE_VALID:
            text += f"  rate ({v['rate_x']:+.4f}, {v['rate_y']:+.4f}, {v['rate_z']:+.4f}) deg/s"
        flags = AttitudeFlag(v["flags"] & sum(AttitudeFlag))
        return (text + f"  matched {v['matched']}  {_name(Mode, v['mode'])}  "
                f"{flags.name or '-'}")
    if p.id == MsgId.CENTROIDS:
        ident = int(np.count_nonzero(p.items["hip"])) if p.items is not None else 0
        return (f"{head}  frame {v['frame_id']}  part {v['part'] + 1}/{v['parts']}  "
                f"{v['count']} stars of {v['total']} ({ident} identified)")
    if p.id == MsgId.STATUS:
        return (f"{head}  up {v['uptime_s']} s  {v['frame_rate_hz']:.1f} fps  exp "
                f"{v['exposure_us']} us  gain {v['gain']:.2f}  cpu {v['cpu_temp_c']:.1f} C  "
                f"{_name(Mode, v['mode'])}  frames {v['frames']}  capture faults "
                f"{v['capture_faults']}  solve failures {v['solve_failures']}  link drops "
                f"{v['link_drops']}  reopens {v['link_reopens']}  rx rejects "
                f"{v['rx_rejects']}  last error {v['last_error']}  config "
                f"0x{v['config_crc']:08x}  time {_name(TimeSource, v['time_source'])}  "
                f"corrections {Correction(v['corrections'] & 7).name or '-'}")
    return (f"{head}  {_name(MsgId, v['cmd_id'])} seq {v['cmd_seq']}  "
            f"{_name(Reason, v['code'])}")


def _jsonable(p: Packet) -> dict:
    def clean(x):
        x = x.item() if hasattr(x, "item") else x
        return None if isinstance(x, float) and not math.isfinite(x) else x
    rec = {"name": p.name, "seq": p.seq, "values": {k: clean(x) for k, x in p.values.items()}}
    if p.items is not None:
        rec["items"] = [{k: clean(row[k]) for k in p.items.dtype.names} for row in p.items]
    return rec


def run(args, cfg) -> int:
    encoder = Encoder(Direction.TC)
    port_name, sends = split_port(args.port, args.send)
    commands = [build_command(encoder, words) for words in sends]
    try:
        port = serial.serial_for_url(port_name, baudrate=args.baud or cfg.link.baudrate,
                                     timeout=0.1)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise UserError(f"cannot open {port_name}: {exc}") from None
    log = None
    if args.log:
        # made once the port is open (and its stale input dropped): a log that exists means
        # every byte from now on is logged, which tracker demo waits for
        try:
            log = open_output(args.log, "--log", "ab" if args.log_format == "raw" else "a")
        except UserError:
            port.close()
            raise
    decoder = StreamDecoder(Direction.TM, validate=False)
    counts: dict[str, int] = {}
    gaps: dict[str, int] = {}
    last_seq: dict[int, int] = {}
    t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    seen = port_errors = 0
    try:
        for frame in commands:
            port.write(frame)
        while time.monotonic() < t_end and not (args.count and seen >= args.count):
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                port_errors += 1
                _reopen(port, exc)
                continue
            if log is not None and args.log_format == "raw":
                log.write(data)
                log.flush()
            for p in decoder.feed(data):
                seen += 1
                counts[p.name] = counts.get(p.name, 0) + 1
                if p.id in last_seq:
                    gaps[p.name] = gaps.get(p.name, 0) + (p.seq - last_seq[p.id] - 1) % SEQ_MODULO
                last_seq[p.id] = p.seq
                if not args.quiet:
                    print(describe(p), flush=True)
                if log is not None and args.log_format == "jsonl":
                    log.write(json.dumps(_jsonable(p)) + "\n")
                    log.flush()
                if args.count and seen >= args.count:
                    break
    except KeyboardInterrupt:
        pass
    finally:
        port.close()
        close_output(log)
    print(f"packets {json.dumps(counts)}  sequence gaps {json.dumps(gaps)}  decoder "
          f"{json.dumps(decoder.counters)}  port errors {port_errors}")
    return 0


def _reopen(port, exc: Exception) -> None:
    """After a port error: say so, wait a little and open the port again (as an FC would).

    A pseudo-terminal whose far end is being reopened, or a USB adapter
    pulled and put back, recovers; the wait keeps a dead port from spinning.
    """
    print(f"tracker monitor: port error: {exc}; reopening", file=sys.stderr, flush=True)
    try:
        port.close()
    except (serial.SerialException, OSError):
        pass
    time.sleep(_REOPEN_WAIT_S)
    try:
        port.open()
    except (serial.SerialException, OSError):
        pass        # the next read fails and says so again
