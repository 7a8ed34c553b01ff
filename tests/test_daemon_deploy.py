"""Deployment files and on-device commands: unit file, firmware config, record, selftest."""

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from fake_rp1_cfe import FakeKernel

from tracker.capture import Frame, ReplaySource, v4l2_source
from tracker.cli import main
from tracker.commands import selftest
from tracker.config import load_config

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "startracker.service"
EXEC = "/opt/startracker/.venv/bin/tracker"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None,
                    reason="systemd-analyze absent (apt-get install systemd; .ci/run does)")
def test_unit_file_verifies_without_any_warning(tmp_path):
    """`systemd-analyze verify` must print nothing.

    Only ExecStart's program is swapped for an executable stub, since the
    venv exists only on the Pi; every other line is checked as shipped.
    """
    stub = tmp_path / "tracker"
    stub.write_text("#!/bin/sh\nexit 0\n")
    stub.chmod(0o755)
    text = UNIT.read_text()
    assert f"ExecStart={EXEC} run --config /etc/startracker/config.yaml" in text
    unit = tmp_path / "startracker.service"
    unit.write_text(text.replace(EXEC, str(stub)))
    out = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True,
                         text=True, timeout=60, cwd=tmp_path)
    assert (out.returncode, out.stdout + out.stderr) == (0, "")


def test_unit_file_has_the_required_settings():
    lines = set(UNIT.read_text().splitlines())
    for needed in ("Type=notify", "Restart=on-failure", "User=startracker",
                   "RestartPreventExitStatus=2",                 # item 13: exit 2 is final
                   "SupplementaryGroups=video dialout i2c", "DeviceAllow=char-i2c rw",
                   "RestrictNamespaces=user net",                # libcamera's IPA sandbox
                   "ProtectSystem=strict", "ProtectHome=yes", "PrivateTmp=yes",
                   "NoNewPrivileges=yes", "CapabilityBoundingSet=",
                   "DevicePolicy=closed", "DeviceAllow=char-video4linux rw",
                   "DeviceAllow=char-media rw", "DeviceAllow=char-dma_heap rw",
                   "DeviceAllow=char-ttyAMA rw", "StartLimitBurst=5", "WatchdogSec=5s",
                   "CPUAffinity=1-3"):
        assert needed in lines, needed
    assert any(line.startswith("MemoryMax=") for line in lines)
    assert not any(line.startswith(("PrivateDevices=", "RestrictNamespaces=yes"))
                   for line in lines)


def test_every_directive_of_the_unit_is_explained():
    """Each block of directives has a comment above it (item 13)."""
    previous = ""
    for number, line in enumerate(UNIT.read_text().splitlines(), 1):
        directive = "=" in line and not line.startswith("#")
        if directive and not (previous.startswith("#") or "=" in previous):
            raise AssertionError(f"line {number}: {line!r} has no comment above its block")
        previous = line


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze absent")
def test_unit_exposure_score_is_at_most_2_5(tmp_path):
    """`systemd-analyze security` scores the shipped unit 2.5 or less (item 13)."""
    unit = tmp_path / "startracker.service"
    unit.write_text(UNIT.read_text())
    out = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(unit)],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path).stdout
    score = float(out.split("Overall exposure level for startracker.service:")[1].split()[0])
    print(f"systemd-analyze security: {score}")
    assert score <= 2.5


def test_cmdline_notes_do_not_isolate_the_units_cores():
    """Item 14: isolcpus= would take the unit's CPUAffinity cores out of load balancing."""
    notes = (ROOT / "firmware_config" / "cmdline.txt.md").read_text()
    assert "isolcpus=2,3" not in notes.replace("`isolcpus=`", "")


def test_shipped_pi_config_loads():
    cfg = load_config(ROOT / "firmware_config" / "config.yaml")
    assert (cfg.capture.backend, cfg.link.port) == ("picamera2", "/dev/fcu")


def test_install_script_is_valid_bash():
    subprocess.run(["bash", "-n", str(ROOT / "tools" / "install_pi.sh")], check=True)


def frames_dir(tmp_path, n=3):
    rng = np.random.default_rng(9)
    folder = tmp_path / "in"
    folder.mkdir()
    images = [rng.integers(0, 1024, (1300, 1600), dtype=np.uint16) for _ in range(n)]
    for k, image in enumerate(images):
        np.save(folder / f"f{k}.npy", image)
    return folder, images


@pytest.mark.parametrize("fmt", ["npy", "png"])
def test_record_writes_frames_replay_reads_back_exactly(tmp_path, fmt):
    folder, images = frames_dir(tmp_path)
    out = tmp_path / "rec"
    assert main(["record", "--replay", str(folder), "--out", str(out), "--frames", "3",
                 "--format", fmt, "--min-free-mb", "1"]) == 0
    records = [json.loads(line) for line in (out / "frames.jsonl").read_text().splitlines()]
    assert [r["file"] for r in records] == [f"frame_{k:06d}.{fmt}" for k in range(3)]
    assert all(r["bit_depth"] == 10 and "t_ns" in r and "cpu_temp_c" in r for r in records)
    replayed = [f for f in ReplaySource([out]) if isinstance(f, Frame)]
    assert len(replayed) == 3
    for frame, image in zip(replayed, images, strict=True):
        np.testing.assert_array_equal(frame.image, image)
        assert frame.bit_depth == 10


def test_record_skips_a_live_sources_waiting_items(tmp_path, monkeypatch):
    from daemon_fakes import FakeSource

    from tracker.capture.base import Waiting
    from tracker.commands import record

    image = np.full((1300, 1600), 100, np.uint16)
    script = [Waiting(0.25), Frame(0, "a", image, 10, 5), Waiting(0.25), Waiting(0.5),
              Frame(1, "b", image, 10, 6)]
    monkeypatch.setattr(record, "make_source", lambda cfg, paths: FakeSource(script))
    out = tmp_path / "rec"
    assert main(["record", "--out", str(out), "--frames", "2", "--min-free-mb", "1"]) == 0
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert [json.loads(line)["t_ns"] for line in lines] == [5, 6]


def test_record_disk_space_guard_stops_cleanly(tmp_path, caplog):
    folder, _ = frames_dir(tmp_path, 1)
    free_mb = shutil.disk_usage(tmp_path).free / 2**20
    out = tmp_path / "rec"
    assert main(["record", "--replay", str(folder), "--out", str(out),
                 "--min-free-mb", str(free_mb + 1)]) == 1
    assert "disk-space guard" in caplog.text
    assert not list(out.glob("frame_*")) and (out / "frames.jsonl").exists()


def test_selftest_here_reports_no_camera_and_checks_data(capsys, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "picamera2", None)
    code = main(["selftest", "--backend", "picamera2", "--skip", "uart", "service"])
    out = capsys.readouterr().out
    assert code == 1
    assert "FAIL camera    no camera (picamera2): picamera2 is not importable" in out
    assert "PASS data" in out and "match their checksums" in out
    assert "SKIP uart      skipped (--skip)" in out


def test_selftest_says_the_running_service_holds_the_camera_and_uart(tmp_path, capsys,
                                                                     monkeypatch):
    """Item 14: selftest and a running service contend for the camera and the UART."""
    monkeypatch.setattr(selftest, "service_running", lambda: True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("link: {port: 'loop://'}\n")
    code = main(["selftest", "--config", str(cfg), "--backend", "v4l2", "--loopback",
                 "--skip", "data", "picamera2"])
    out = capsys.readouterr().out
    assert code == 1
    assert "WARN service   the startracker.service is running and holds the camera" in out
    assert "FAIL camera    v4l2: the startracker.service is running" in out
    assert "FAIL uart      loop://: the startracker.service is running" in out


def test_selftest_v4l2_reports_the_pipeline_and_the_raw_shift(capsys, monkeypatch):
    """Item 11: the V4L2 set-up is part of selftest (here on the simulated rp1-cfe)."""
    image = np.full((1300, 1600), 64, np.uint16)
    frames = [(image, 10**12 + k * 10**8) for k in range(6)]
    monkeypatch.setattr(v4l2_source, "DeviceIO",
                        lambda: FakeKernel(frames, ["frame"] * 6, libcamera_links=True))
    monkeypatch.setattr(selftest, "service_running", lambda: False)
    main(["selftest", "--backend", "v4l2", "--skip", "uart", "data", "cpu_temp", "throttle"])
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x[5:11] == "camera")
    assert line.startswith("PASS camera    v4l2: /dev/media2: arducam-pivariety 10-000c -> csi2"
                           " -> rp1-cfe-csi2_ch0 (/dev/video0), 1600x1300 Y16")
    assert "at 10.0 fps (buffer times)" in line
    # the fake CFE writes Y16 words high-aligned (<< 6): 64 << 6 = 4096 > 1023
    assert "largest word 4096 > 1023: 10-bit data in the high bits, capture.raw_shift 6" in line
    assert "but it is" not in line and "frame(s) lost" not in line
    assert "no EXPOSURE/ANALOGUE_GAIN" not in line


@pytest.mark.parametrize("top, configured, ok, need", [(1023, 0, True, 0), (1024, 0, False, 6),
                                                       (4096, 6, True, 6), (900, 6, False, 0)])
def test_raw_shift_rule_is_the_sensor_full_scale(top, configured, ok, need):
    """Item 14: a word above 1023 (10-bit sensor) means high-aligned data."""
    image = np.zeros((4, 4), np.uint16)
    image[1, 2] = top
    got_ok, text = selftest.raw_shift_advice(image, 10, configured)
    assert got_ok == ok and f"capture.raw_shift {need}" in text


def test_selftest_uart_loopback_over_a_loop_url(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("link: {port: 'loop://'}\n")
    main(["selftest", "--config", str(cfg), "--loopback", "--skip", "camera", "data",
          "service", "picamera2"])
    assert "PASS uart      loop:// loopback at 921600 baud: 256 bytes intact" in \
        capsys.readouterr().out


@pytest.mark.hardware
def test_selftest_passes_on_the_pi():
    assert main(["selftest", "--config", os.environ.get("TRACKER_CONFIG",
                                                        "/etc/startracker/config.yaml")]) == 0
