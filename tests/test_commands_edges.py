"""Commands at their edges: a full disk under record, the monitor's arguments, a hung
monitor in the demo, the shared file rule in calibrate and validate."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tracker.cli import main
from tracker.commands import demo
from tracker.commands.calibrate import expand_frames
from tracker.commands.monitor import build_command, split_port
from tracker.errors import UserError
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.messages import Direction, Mode, MsgId

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = Path(sys.executable).parent / "tracker"


# --- record on a disk that fills up --------------------------------------------------------


def _in_small_filesystem(script: str, size_kb: int) -> subprocess.CompletedProcess:
    """Run a shell script with $FS a fresh tmpfs of size_kb, in a private mount namespace.

    The namespace (and the mount) die with the script, so it copies out what the test
    reads. Root may mount in its own namespace; others need a user namespace too.
    """
    for prefix in (["unshare", "-m"], ["unshare", "-rm"]):
        if shutil.which(prefix[0]) is None:
            break
        wrapped = (f'FS=$(mktemp -d) && mount -t tmpfs -o size={size_kb}k tmpfs "$FS" && '
                   f"{script}")
        proc = subprocess.run([*prefix, "sh", "-c", wrapped], capture_output=True, text=True,
                              timeout=300)
        if "mount" not in proc.stderr or proc.returncode == 0 or "tracker" in proc.stderr:
            return proc
    pytest.skip("cannot mount a small tmpfs here: unshare -m and -rm both refused (the "
                "test needs root or user namespaces)")


@pytest.fixture(name="small_frames")
def fixture_small_frames(tmp_path):
    """Five 240x128 10-bit frames, 61,440 bytes each (15 pages of 4 KiB), and their camera."""
    folder = tmp_path / "in"
    folder.mkdir()
    rng = np.random.default_rng(2)
    for k in range(5):
        np.save(folder / f"f{k:02d}.npy", rng.integers(0, 1024, (128, 240), dtype=np.uint16))
    cfg = tmp_path / "cam.yaml"
    cfg.write_text("camera: {width: 240, height: 128}\n")
    return folder, cfg


@pytest.mark.parametrize("min_free_mb, stopped_by", [(0, "bytes free there)"),
                                                     (0.01, "disk-space guard")])
def test_record_on_a_full_disk_stops_in_one_line_and_keeps_a_complete_index(
        tmp_path, small_frames, min_free_mb, stopped_by):
    """31 pages free: the first frame file (15 pages + the .npy header: 16) fits, the
    second does not though the guard, counting 15 pages of pixels, lets it start; with a
    margin of 10 KB the guard itself stops at the second. frames.jsonl holds a line of an
    earlier session, so the new lines need no new page."""
    folder, cfg = small_frames
    out = tmp_path / "copied"
    out.mkdir()
    proc = _in_small_filesystem(
        f'mkdir "$FS/rec" && echo \'{{"note": "an earlier session"}}\' > "$FS/rec/frames.jsonl"'
        f' && FREE=$(stat -f -c %a "$FS") && head -c $(( (FREE - 31) * 4096 )) /dev/zero > '
        f'"$FS/filler" && "{SCRIPT}" record --replay "{folder}" --out "$FS/rec" --frames 5 '
        f'--config "{cfg}" --min-free-mb {min_free_mb}; echo "exit $?" > "{out}/exit"; '
        f'cp "$FS/rec/frames.jsonl" "{out}/"; ls "$FS/rec" > "{out}/files"', 256)
    assert "Traceback" not in proc.stderr, proc.stderr
    assert (out / "exit").read_text().strip() == "exit 1", proc.stderr
    errors = [line for line in proc.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and stopped_by in errors[0], proc.stderr
    assert "stopped after 1 frames" in errors[0]
    records = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert records[0] == {"note": "an earlier session"}
    assert [r["file"] for r in records[1:]] == ["frame_000000.npy"]
    # every frame listed is there whole, and no partial file is left
    assert sorted((out / "files").read_text().split()) == ["frame_000000.npy", "frames.jsonl"]


# --- monitor arguments -----------------------------------------------------------------------


@pytest.mark.parametrize("port, sends, expected", [
    ("/dev/ttyUSB0", [["ping"]], ("/dev/ttyUSB0", [["ping"]])),
    (None, [["ping", "/dev/ttyUSB0"]], ("/dev/ttyUSB0", [["ping"]])),
    (None, [["ping"], ["set-mode", "tracking", "loop://"]],
     ("loop://", [["ping"], ["set-mode", "tracking"]])),
])
def test_the_port_may_follow_the_last_send(port, sends, expected):
    assert split_port(port, sends) == expected


def test_no_port_at_all_is_one_line():
    with pytest.raises(UserError, match="no serial port given"):
        split_port(None, [["set-mode", "tracking"]])


@pytest.mark.parametrize("words, message", [
    (["set-mode", "flying"], "--send set-mode flying: found 'flying', expected standby, "
                             "lost-in-space, tracking or a mode number"),
    (["set-exposure", "1e3"], "found '1e3', expected a whole number of microseconds"),
    (["set-gain", "inf"], "found 'inf', expected a number"),
    (["set-output", "attitude"], "found 1 argument(s), expected set-output MESSAGE HZ"),
    (["set-output", "pictures", "1"], "found 'pictures', expected attitude, centroids or "
                                      "status"),
    (["set-exposure", "-5"], "SET_EXPOSURE: a value does not fit"),
    (["launch"], "--send launch: unknown command"),
])
def test_bad_commands_say_what_was_expected(words, message):
    with pytest.raises(UserError) as info:
        build_command(Encoder(Direction.TC), words)
    assert message in str(info.value) and "int()" not in str(info.value)


def test_good_commands_decode_as_sent():
    frames = b"".join(build_command(Encoder(Direction.TC), w) for w in (
        ["set-mode", "tracking"], ["SET-MODE", "7"], ["set-output", "status", "0.5"]))
    packets = list(StreamDecoder(Direction.TC, validate=False).feed(frames))
    assert [p.id for p in packets] == [MsgId.SET_MODE, MsgId.SET_MODE, MsgId.SET_OUTPUT]
    assert packets[0].values["mode"] == Mode.TRACKING and packets[1].values["mode"] == 7
    assert packets[2].values == {"msg_id": MsgId.STATUS, "rate_hz": 0.5}


# --- the demo never waits forever on its monitor ---------------------------------------------


def test_demo_kills_a_monitor_that_ignores_ctrl_c(monkeypatch, capsys):
    monkeypatch.setattr(demo, "_MONITOR_STOP_S", 0.5)
    stubborn = subprocess.Popen([sys.executable, "-c", "import signal, time; "
                                 "signal.signal(signal.SIGINT, signal.SIG_IGN); "
                                 "print('ready', flush=True); time.sleep(60)"],
                                stdout=subprocess.PIPE, text=True)
    assert stubborn.stdout.readline().strip() == "ready"
    demo._stop(stubborn)
    assert stubborn.returncode == -signal.SIGKILL
    assert "did not stop within 0.5 s of Ctrl-C; killed it" in capsys.readouterr().err


def test_demo_reads_a_log_cut_mid_line(tmp_path):
    log = tmp_path / "fc.jsonl"
    log.write_text('{"name": "STATUS", "seq": 0, "values": {}}\n{"name": "ATTI')
    assert [p["name"] for p in demo._fc_packets(log)] == ["STATUS"]
    assert demo._fc_packets(tmp_path / "missing.jsonl") == []


# --- one rule for files and folders ------------------------------------------------------------


def test_calibrate_counts_an_image_and_its_centroid_list_once(tmp_path):
    real = ROOT / "tests" / "data" / "real" / "cedar-solve"
    for name in ("orion_belt.jpg", "orion_belt.jpg.centroids.json",
                 "hale_bopp.jpg.centroids.json"):
        shutil.copyfile(real / name, tmp_path / name)
    assert [p.name for p in expand_frames([str(tmp_path)])] == [
        "hale_bopp.jpg.centroids.json", "orion_belt.jpg.centroids.json"]


@pytest.mark.parametrize("command", [["replay"], ["validate"], ["calibrate", "--out", "o.yaml"],
                                     ["record", "--out", "rec", "--replay"]])
def test_an_empty_folder_is_the_same_one_line_everywhere(tmp_path, capsys, command,
                                                         monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "empty").mkdir()
    assert main([*command, "empty"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"tracker {command[0]}: empty: no ") and "in this folder" in last
