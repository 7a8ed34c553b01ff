"""``tracker demo``: the whole system on one machine, no hardware.

1. Simulates a slew over Orion (OV2311 + 16 mm lens, realistic sensor noise,
   hot pixels, cosmic rays; 0.5 deg/s at 10 fps) into ``OUT/frames`` with
   truth files (kept and reused while the parameters are unchanged), as seen
   on 2026-03-20 from low Earth orbit (7.5 km/s): aberrated, with ``utc``
   and the velocity in ``frames.jsonl``, so the service reports the ICRS
   attitude.
2. Joins two pseudo-terminals into a null-modem cable.
3. Starts the service (``tracker run``) on the replay backend, writing to one
   end, and ``tracker monitor`` (the flight computer's tool) on the other,
   which prints one line per packet and logs them to ``OUT/fc.jsonl``.
4. Prints a summary: frames, solve rate, latency, packets sent and decoded,
   and the attitude the FC received compared with the simulator's truth.

Exit status 0 when every frame was processed, the FC decoded every ATTITUDE
the service sent (nothing lost on the cable), every ATTITUDE queued was sent
or dropped as stale (older than ``link.max_age_ms`` when its turn came, as on
a machine too busy for the frame rate: counted and printed), and at least
90 % of those the FC decoded were valid. A frame that came sooner after the
previous one than ``link.attitude_rate_hz`` allows (a late frame on a busy
machine, then the next on time) has its ATTITUDE held back: counted and
printed as well.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from tracker.attitude import attitude_error, matrix_from_quat
from tracker.capture.replay import METADATA_FILE
from tracker.commands.argtypes import positive_count
from tracker.errors import UserError
from tracker.protocol.messages import AttitudeFlag
from tracker.protocol.nullmodem import NullModem

__all__ = ["register", "run"]

_MONITOR_STOP_S = 10.0
_WAIT_LIMIT_S = 120.0  # a hung monitor's limit, never reached by a working one
_POLL_S = 0.02
_SCENE = ["--ra", "83.8", "--dec", "-5.4", "--roll", "20", "--rate-deg-s", "0", "0.5", "0",
          "--fps", "10", "--seed", "1", "--utc", "2026-03-20T21:00:00Z",
          "--observer-velocity-km-s", "-5.1", "4.2", "3.3"]


def register(sub, common) -> None:
    p = sub.add_parser("demo", parents=[common], help="simulate a slew, run the service on a "
                       "pseudo-terminal, decode it as the FC, summarise")
    p.add_argument("--out", default="build/demo", metavar="DIR", help="working folder")
    p.add_argument("--frames", type=positive_count, default=40, metavar="N",
                   help="frames (default 40)")
    p.set_defaults(func=run)


def _tracker(*argv: str, config: str | None) -> list[str]:
    extra = ["--config", config] if config else []
    return [sys.executable, "-m", "tracker.cli", *argv, *extra]


def _frames(out: Path, n: int, config: str | None) -> Path:
    """Simulate the sequence unless the same one is already there."""
    folder = out / "frames"
    stamp = folder / "scene.json"
    want = {"argv": _SCENE, "frames": n,
            "config": Path(config).read_text() if config else None}
    if stamp.exists() and json.loads(stamp.read_text()) == want \
            and (folder / METADATA_FILE).exists():
        print(f"demo: reusing {n} simulated frames in {folder}")
        return folder
    print(f"demo: simulating {n} frames into {folder} ...", flush=True)
    code = subprocess.run(_tracker("simulate", "--out", str(folder), "--frames", str(n),
                                   *_SCENE, config=config)).returncode
    if code != 0:
        raise UserError(f"simulating the frames failed (tracker simulate exited with {code})")
    stamp.write_text(json.dumps(want))
    return folder


def _stop(monitor: subprocess.Popen) -> None:
    """Ctrl-C to the monitor (it closes its log and prints its counters); kill it if it hangs.

    The monitor flushes its log per packet, so what it decoded is on disk
    either way.
    """
    monitor.send_signal(signal.SIGINT)
    try:
        monitor.wait(timeout=_MONITOR_STOP_S)
    except subprocess.TimeoutExpired:
        monitor.kill()
        monitor.wait()
        print(f"demo: the FC monitor did not stop within {_MONITOR_STOP_S:g} s of Ctrl-C; "
              "killed it", file=sys.stderr)


def _wait_for(done, monitor: subprocess.Popen) -> bool:
    """Poll ``done()`` until it holds (True) or the monitor has exited (False).

    :data:`_WAIT_LIMIT_S` only stops a wait on a monitor that hangs; on any
    machine, loaded or not, the count of what arrived decides the result.
    """
    deadline = time.monotonic() + _WAIT_LIMIT_S
    while not done():
        if monitor.poll() is not None or time.monotonic() > deadline:
            return done()
        time.sleep(_POLL_S)
    return True


def _packets_sent(summary: dict) -> int:
    """Packets the service wrote to its port, from its summary's link counters."""
    return sum(v for k, v in summary.get("link", {}).items() if k.startswith("sent_"))


def _fc_packets(fc_log: Path) -> list[dict]:
    """The packets the monitor logged (none if it wrote no log; a cut last line skipped)."""
    packets = []
    lines = fc_log.read_text().splitlines() if fc_log.exists() else []
    for line in lines:
        try:
            packet = json.loads(line)
        except ValueError:
            continue
        if isinstance(packet, dict):
            packets.append(packet)
    return packets


def _attitude_errors(packets: list[dict], folder: Path) -> list[tuple[float, float]]:
    """(cross-boresight, roll) arcsec of each ATTITUDE the FC decoded against its truth.

    The truth is the ICRS attitude; the tracker reports it when it corrected
    aberration (ATTITUDE flag ANNUAL_ABERRATION).
    """
    errors = []
    for packet in packets:
        if packet.get("name") != "ATTITUDE":
            continue
        values = packet["values"]
        truth_file = folder / f"f{values['frame_id']:04d}.png.truth.json"
        if not values["flags"] & AttitudeFlag.VALID or not truth_file.exists():
            continue
        q = [values["q_w"], values["q_x"], values["q_y"], values["q_z"]]
        truth = json.loads(truth_file.read_text())
        cross, roll = attitude_error(matrix_from_quat(q), matrix_from_quat(truth["q"]))
        errors.append((np.degrees(cross) * 3600, np.degrees(roll) * 3600))
    return errors


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    folder = _frames(out, args.frames, args.config)
    fc_log = out / "fc.jsonl"
    fc_log.unlink(missing_ok=True)
    summary_file = out / "service.json"
    with NullModem() as (tracker_port, fc_port):
        monitor = subprocess.Popen(_tracker("monitor", fc_port, "--log", str(fc_log),
                                            config=args.config))
        try:
            # the monitor makes its log once its port is open: nothing sent is flushed unread
            if not _wait_for(fc_log.exists, monitor):
                raise UserError("the FC monitor exited before opening its port")
            service = subprocess.run(_tracker("run", "--replay", str(folder), "--frames",
                                              str(args.frames), "--fps", "10", "--port",
                                              tracker_port, "--summary", str(summary_file),
                                              config=args.config))
            if service.returncode == 0:
                sent = _packets_sent(json.loads(summary_file.read_text()))
                _wait_for(lambda: len(_fc_packets(fc_log)) >= sent, monitor)
        finally:
            _stop(monitor)
    if service.returncode != 0:
        print(f"demo: the service exited with status {service.returncode}", file=sys.stderr)
        return 1
    result = json.loads(summary_file.read_text())
    packets = _fc_packets(fc_log)
    decoded: dict[str, int] = {}
    for packet in packets:
        name = packet.get("name", "?")
        decoded[name] = decoded.get(name, 0) + 1
    errors = _attitude_errors(packets, folder)
    corrected = sum(1 for p in packets if p.get("name") == "ATTITUDE"
                    and p["values"]["flags"] & AttitudeFlag.OBSERVER_VELOCITY)
    latency = result.get("latency_ms", {})
    link = result.get("link", {})
    sent = {k.removeprefix("sent_"): v for k, v in link.items() if k.startswith("sent_")}
    print()
    print("demo summary")
    print(f"  frames processed     {result['processed']} of {args.frames}")
    print(f"  solve rate           {100 * result['solve_rate']:.1f} %")
    print("  latency (ms)         " + "  ".join(f"{k} {v:.1f}" for k, v in latency.items()))
    print(f"  packets sent         {json.dumps(sent)}")
    print(f"  packets decoded (FC) {json.dumps(decoded)}")
    if errors:
        rms = np.sqrt(np.mean(np.square(errors), axis=0))
        print(f"  attitude vs truth    RMS cross-boresight {rms[0]:.2f} arcsec, roll "
              f"{rms[1]:.1f} arcsec over {len(errors)} solutions (ICRS; aberration "
              f"corrected in {corrected})")
    queued, stale = link.get("queued_attitude", 0), link.get("dropped_stale_attitude", 0)
    print(f"  attitudes            {queued} queued, {sent.get('attitude', 0)} sent, {stale} "
          "dropped as stale (older than link.max_age_ms: a busy machine), "
          f"{link.get('over_rate_attitude', 0)} held back by link.attitude_rate_hz (a late "
          "frame followed at once by the next)")
    print(f"  faults               {json.dumps(result.get('faults', {}))}")
    problem = _shortfall(args.frames, result["processed"], link, decoded.get("ATTITUDE", 0),
                         len(errors))
    print(f"demo: {'OK' if problem is None else 'FAILED: ' + problem}")
    return 0 if problem is None else 1


def _shortfall(frames: int, processed: int, link: dict, decoded: int, valid: int) -> str | None:
    """Why the run falls short (None when it does not): see the module docstring."""
    sent = link.get("sent_attitude", 0)
    if processed < frames:
        return f"the service processed {processed} of {frames} frames"
    if decoded != sent:
        return f"the FC decoded {decoded} of the {sent} attitudes sent"
    if link.get("queued_attitude", 0) != sent + link.get("dropped_stale_attitude", 0):
        return "attitudes queued were neither sent nor dropped as stale"
    if decoded == 0 or valid < 0.9 * decoded:
        return f"{valid} of {decoded} attitudes the FC decoded were valid"
    return None
