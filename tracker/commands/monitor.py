"""``tracker monitor PORT``: the flight computer's view of the link, for integrators.

Decodes telemetry live and prints one line per packet (ATTITUDE as boresight
RA/Dec and roll, rates, counters), sends commands (``--send ping``,
``--send set-mode tracking``, repeatable), and logs the raw bytes or the
decoded packets (JSON lines) to a file. Stops after ``--count`` packets,
``--duration`` seconds, or Ctrl-C, then prints the counters (packets per
message, sequence gaps, decoder drops).
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np
import serial

from tracker.attitude import matrix_from_quat, radec_roll_from_matrix
from tracker.config import UserError
from tracker.protocol.decoder import Packet, StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.framing import SEQ_MODULO
from tracker.protocol.messages import AttitudeFlag, Direction, Mode, MsgId, Reason

_MODES = {"standby": Mode.STANDBY, "lost-in-space": Mode.LOST_IN_SPACE,
          "tracking": Mode.TRACKING}
_OUTPUTS = {"attitude": MsgId.ATTITUDE, "centroids": MsgId.CENTROIDS, "status": MsgId.STATUS}
_USAGE = ("ping | request-status | time-sync | set-mode standby|lost-in-space|tracking | "
          "set-exposure US | set-gain X | set-output attitude|centroids|status HZ")


def register(sub, common) -> None:
    p = sub.add_parser("monitor", parents=[common], help="FC side: decode and print the "
                       "tracker's packets live, send commands, log")
    p.add_argument("port", help="serial device or pyserial URL, e.g. /dev/ttyUSB0")
    p.add_argument("--baud", type=int, default=None, help="baud rate (default: link.baudrate)")
    p.add_argument("--send", nargs="+", action="append", default=[], metavar="CMD",
                   help=f"send a command first (repeatable): {_USAGE}")
    p.add_argument("--count", type=int, default=0, help="stop after N packets (0 = no limit)")
    p.add_argument("--duration", type=float, default=0.0,
                   help="stop after S seconds (0 = no limit)")
    p.add_argument("--log", metavar="FILE", help="also write to FILE")
    p.add_argument("--log-format", choices=("raw", "jsonl"), default="jsonl",
                   help="raw bytes as received, or decoded packets as JSON lines")
    p.add_argument("--quiet", action="store_true", help="print only the final counters")
    p.set_defaults(func=run)


def build_command(encoder: Encoder, words: list[str]) -> bytes:
    """The frame for one ``--send`` command; UserError if it cannot be encoded."""
    name, args = words[0].lower(), words[1:]
    want = {"ping": 0, "request-status": 0, "time-sync": 0, "set-mode": 1,
            "set-exposure": 1, "set-gain": 1, "set-output": 2}
    if name not in want:
        raise UserError(f"--send {name}: unknown command; expected one of: {_USAGE}")
    if len(args) != want[name]:
        raise UserError(f"--send {name}: expected {want[name]} argument(s), found {len(args)}")
    try:
        if name == "ping":
            return encoder.encode(MsgId.PING)
        if name == "request-status":
            return encoder.encode(MsgId.REQUEST_STATUS)
        if name == "time-sync":
            return encoder.encode(MsgId.TIME_SYNC, fc_time_ns=time.time_ns())
        if name == "set-mode":
            mode = _MODES[args[0]] if args[0] in _MODES else int(args[0])
            return encoder.encode(MsgId.SET_MODE, mode=mode)
        if name == "set-exposure":
            return encoder.encode(MsgId.SET_EXPOSURE, exposure_us=int(args[0]))
        if name == "set-gain":
            return encoder.encode(MsgId.SET_GAIN, gain=float(args[0]))
        return encoder.encode(MsgId.SET_OUTPUT, msg_id=_OUTPUTS[args[0]],
                              rate_hz=float(args[1]))
    except (ValueError, KeyError) as exc:
        raise UserError(f"--send {' '.join(words)}: {exc}; expected {_USAGE}") from None


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
        text = f"{head}  frame {v['frame_id']}  t {v['t_ns'] / 1e9:.6f} s"
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
                f"0x{v['config_crc']:08x}")
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
    commands = [build_command(encoder, words) for words in args.send]
    try:
        port = serial.serial_for_url(args.port, baudrate=args.baud or cfg.link.baudrate,
                                     timeout=0.1)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise UserError(f"cannot open {args.port}: {exc}") from None
    decoder = StreamDecoder(Direction.TM, validate=False)
    counts: dict[str, int] = {}
    gaps: dict[str, int] = {}
    last_seq: dict[int, int] = {}
    log = open(args.log, "ab" if args.log_format == "raw" else "a") if args.log else None
    t_end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    seen = 0
    try:
        for frame in commands:
            port.write(frame)
        while time.monotonic() < t_end and not (args.count and seen >= args.count):
            data = port.read(max(1, port.in_waiting))
            if log is not None and args.log_format == "raw":
                log.write(data)
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
                if args.count and seen >= args.count:
                    break
    except KeyboardInterrupt:
        pass
    except (serial.SerialException, OSError) as exc:
        print(f"tracker monitor: port error: {exc}", file=sys.stderr)
    finally:
        port.close()
        if log is not None:
            log.close()
    print(f"packets {json.dumps(counts)}  sequence gaps {json.dumps(gaps)}  decoder "
          f"{json.dumps(decoder.counters)}")
    return 0
