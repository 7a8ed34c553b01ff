"""Absolute time at the commands' edges (issue 14): record, simulate, monitor, the library."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest

from tracker.astrometry.observer import TimeSource
from tracker.astrometry.timescale import tai_ns_from_utc_iso
from tracker.cli import main
from tracker.commands.monitor import build_command, host_tai_ns
from tracker.errors import UserError
from tracker.protocol.decoder import StreamDecoder
from tracker.protocol.encoder import Encoder
from tracker.protocol.messages import Direction, MsgId


def _frames(folder, n=3):
    folder.mkdir()
    for k in range(n):
        cv2.imwrite(str(folder / f"f{k}.png"), np.full((1300, 1600), 9, np.uint8))
    return folder


def _config(tmp_path, system_clock, replay_path):
    path = tmp_path / f"{system_clock}.yaml"
    path.write_text(f"time: {{system_clock: {system_clock}}}\n"
                    f"capture: {{backend: replay, replay_path: '{replay_path}'}}\n")
    return str(path)


@pytest.mark.parametrize("system_clock", ["never", "always"])
def test_record_writes_utc_only_when_the_clock_is_trusted(tmp_path, system_clock):
    """`always` trusts the system clock: the exposure mid-point's utc is the frame's
    monotonic stamp moved onto UTC; `never` (the default) writes none."""
    source = _frames(tmp_path / "src")
    out = tmp_path / system_clock
    before = time.time()
    assert main(["record", "--out", str(out), "--frames", "3",
                 "--config", _config(tmp_path, system_clock, source)]) == 0
    after = time.time()
    records = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert len(records) == 3
    if system_clock == "never":
        assert not any("utc" in r for r in records)
        return
    posix = np.array([tai_ns_from_utc_iso(r["utc"]) / 1e9 - 37 for r in records])
    # replayed files are stamped from the replay's start, capture.replay_interval_s apart
    assert before - 0.01 <= posix[0] <= after + 0.01
    assert np.diff(posix) == pytest.approx([0.1, 0.1], abs=1e-6)


def test_record_from_files_keeps_their_own_utc_and_velocity(tmp_path):
    source = _frames(tmp_path / "src", 2)
    (source / "frames.jsonl").write_text(json.dumps(
        {"file": "f1.png", "utc": "2025-06-30T12:00:00.5Z",
         "observer_velocity_km_s": [1.0, 2.0, 3.0]}) + "\n")
    out = tmp_path / "rec"
    assert main(["record", "--out", str(out), "--replay", str(source), "--frames", "2",
                 "--config", _config(tmp_path, "always", source)]) == 0
    first, second = [json.loads(line) for line in (out / "frames.jsonl").read_text()
                     .splitlines()]
    assert "utc" not in first                   # a file with no time of its own: none
    assert second["utc"] == "2025-06-30T12:00:00.500000000Z"
    assert second["observer_velocity_km_s"] == [1.0, 2.0, 3.0]


def test_simulate_utc_puts_time_and_velocity_in_the_index_and_truth(tmp_path):
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--frames", "2", "--ra", "10", "--dec", "20",
                 "--roll", "30", "--noise", "none", "--fps", "4",
                 "--utc", "2031-07-04T05:06:07.25Z",
                 "--observer-velocity-km-s", "-1.5", "7", "0.5"]) == 0
    index = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert [r["utc"] for r in index] == ["2031-07-04T05:06:07.250000000Z",
                                         "2031-07-04T05:06:07.500000000Z"]
    assert index[1]["observer_velocity_km_s"] == [-1.5, 7.0, 0.5]
    truth = json.loads((out / "f0001.png.truth.json").read_text())
    assert truth["utc"] == index[1]["utc"] and truth["observer_velocity_km_s"] == [-1.5, 7, 0.5]
    assert truth["epoch_year"] == pytest.approx(2031.50366, abs=1e-5)   # the frames' epoch


@pytest.mark.parametrize("argv, match", [
    (["--observer-velocity-km-s", "1", "2", "3"], "needs --utc"),
    (["--utc", "2031-07-04T05:06:07"], "expected ISO 8601 UTC"),
    (["--utc", "1969-07-20T20:17:40Z"], "before 1972"),
    (["--utc", "2030-01-01T00:00:00Z", "--observer-velocity-km-s", "1", "inf", "3"],
     "three numbers")])
def test_simulate_refuses_unusable_times_in_one_line(tmp_path, capsys, argv, match):
    assert main(["simulate", "--out", str(tmp_path / "x"), *argv]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1


def test_monitor_sends_the_hosts_tai_and_a_velocity():
    encoder = Encoder(Direction.TC)
    now = host_tai_ns()
    sync, velocity = (StreamDecoder(Direction.TC).feed(build_command(encoder, words))[0]
                      for words in (["time-sync"], ["set-velocity", "-7.5", "0", "1.25"]))
    assert abs(sync.values["fc_time_ns"] - now) < 10**9
    assert abs(now - (time.time_ns() + 37 * 10**9)) < 10**9      # TAI = UTC + 37 s (2017-)
    assert (sync.id, velocity.id) == (MsgId.TIME_SYNC, MsgId.SET_VELOCITY)
    assert (velocity.values["vx_km_s"], velocity.values["vz_km_s"]) == (-7.5, 1.25)
    with pytest.raises(UserError, match="a velocity in km/s"):
        build_command(encoder, ["set-velocity", "1", "fast", "2"])
    with pytest.raises(UserError, match="expected set-velocity VX VY VZ"):
        build_command(encoder, ["set-velocity", "1"])


def test_library_calls_take_utc_and_say_what_was_corrected():
    import tracker
    from tracker.api import _observer

    assert _observer("2026-03-20T21:00:00Z", (1, 2, 3)).time_source == TimeSource.RECORD
    with pytest.raises(tracker.UserError, match="needs utc"):
        tracker.solve_centroids([(0, 0)] * 5, observer_velocity_km_s=(1, 2, 3))
    with pytest.raises(tracker.UserError, match="expected ISO 8601"):
        tracker.solve_centroids([(0, 0)] * 5, utc="yesterday")


@pytest.mark.parametrize("policy, synced, status, says", [
    ("never", False, "PASS", "TIME_SYNC only"), ("synchronised", True, "PASS", "until TIME_SYNC"),
    ("synchronised", False, "WARN", "not used until it is"),
    ("synchronised", None, "WARN", "synchronisation unknown"),
    ("always", True, "WARN", "without the kernel's word")])
def test_selftest_says_whether_the_clock_is_used(monkeypatch, policy, synced, status, says):
    from tracker.commands import selftest
    from tracker.config import Config, TimeConfig

    monkeypatch.setattr(selftest, "kernel_synchronised", lambda: synced)
    got, text = selftest.check_clock(Config(time=TimeConfig(system_clock=policy)), None)
    assert got == status and says in text
    assert f"time.system_clock: {policy}" in text
