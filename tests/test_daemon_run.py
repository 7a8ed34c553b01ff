"""`tracker run` as a process: replay backend, summary, SIGTERM."""

import json
import signal
import subprocess
import sys
import time

import numpy as np

from tracker.cli import main


def frames(tmp_path, n=3):
    rng = np.random.default_rng(4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(n):
        image = rng.normal(60, 3, (1300, 1600)).clip(0, 1023).astype(np.uint16)
        for x, y in rng.integers(20, 1280, (25, 2)):
            image[y - 1:y + 2, x - 1:x + 2] += 500
        np.save(folder / f"f{k}.npy", image)
    return folder


def test_run_a_fixed_number_of_frames_with_a_summary(tmp_path):
    out = tmp_path / "summary.json"
    code = main(["run", "--replay", str(frames(tmp_path)), "--loop", "--frames", "7",
                 "--port", "loop://", "--summary", str(out)])
    summary = json.loads(out.read_text())
    assert code == 0
    assert summary["frames"] == 7 and summary["processed"] == 7
    assert set(summary["latency_ms"]) == {"p50", "p90", "p99", "max"}
    assert summary["link"]["queued_attitude"] >= 1
    sent = summary["link"]["sent_attitude"]
    # every ATTITUDE written has its latency: the frame read to its last byte on the wire
    assert sent >= 1 and set(summary["wire_latency_ms"]) == {"p50", "p90", "p99", "max"}
    assert 0 < summary["wire_latency_ms"]["p50"] <= summary["wire_latency_ms"]["max"]


def test_missing_replay_frames_is_a_user_error(tmp_path, capsys):
    assert main(["run", "--replay", str(tmp_path / "nope")]) == 2
    assert "nope: no such file or folder" in capsys.readouterr().err


def test_sigterm_stops_the_service_cleanly(tmp_path):
    """Exit status 0 and the stop logged; the time taken is printed (-s shows it)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "tracker.cli", "run", "--replay", str(frames(tmp_path)),
         "--loop", "--port", "loop://"], stderr=subprocess.PIPE, text=True)
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if "ready:" in line:
            break
    t0 = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    rest = proc.communicate(timeout=10)[1]
    elapsed = time.monotonic() - t0
    print(f"stopped {elapsed:.3f} s after SIGTERM")
    assert proc.returncode == 0, "".join(lines) + rest
    assert "stopped: " in rest


STALLING = """
import sys, time, dataclasses
from tracker.commands.run import build_daemon
from tracker.config import Config

class Stall:
    def process(self, image, bit_depth, t_ns, observer, exposure_s=None):
        time.sleep(120)

cfg = Config()
cfg = dataclasses.replace(cfg, service=dataclasses.replace(cfg.service, watchdog_s=1.0),
                          link=dataclasses.replace(cfg.link, port="loop://"))
sys.exit(build_daemon(cfg, [sys.argv[1]], pipeline=Stall()).run())
"""


def test_a_stalled_loop_dumps_its_stacks_and_exits_for_systemd(tmp_path):
    """The in-process watchdog (service.watchdog_s = 1 s) ends a loop stuck in a stage."""
    proc = subprocess.run([sys.executable, "-c", STALLING, str(frames(tmp_path, 1))],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert "Timeout (0:00:01)!" in proc.stderr
    assert "in process" in proc.stderr           # the stalled frame of Stall.process
