"""``tracker selftest``: on-device checks before (or instead of) starting the service.

Each check prints one line, ``PASS``, ``WARN``, ``FAIL`` or ``SKIP``, its
name and what it found; the exit status is 1 if any check failed.

- ``camera``: opens the live backend (``--backend``, default the configured
  one, or picamera2 when that is replay), checks the granted raw format and
  size, captures a few frames and reports exposure, gain, the frame rate and
  which bits of the 16-bit words vary (all low bits zero means MSB-aligned
  data: ``capture.raw_shift`` should then be 16 - bit depth). On a machine
  without a camera it fails with the reason ("no camera: ...").
- ``uart``: with ``--loopback`` (TX wired to RX), writes 256 random bytes to
  ``link.port`` and reads them back; otherwise only checks that the device
  exists and is readable and writable by this user.
- ``data``: every ``*.npz`` under catalogue/ matches its ``.sha256`` file,
  and the configured catalogue loads.
- ``cpu_temp``: SoC temperature (warn at 75 C, fail at 85 C).
- ``throttle``: ``vcgencmd get_throttled`` (under-voltage, throttling now or
  since boot).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np

from tracker.board import cpu_temperature_c
from tracker.capture.backends import make_source
from tracker.capture.base import Frame
from tracker.catalogue import CatalogueError, default_catalogue_path, load_catalogue
from tracker.config import Config

__all__ = ["register", "run", "CHECKS"]

_FRAMES = 5
# get_throttled bits: now (0-3) and since boot (16-19).
_THROTTLE_BITS = {0: "under-voltage", 1: "ARM frequency capped", 2: "throttled",
                  3: "soft temperature limit", 16: "under-voltage occurred",
                  17: "frequency capping occurred", 18: "throttling occurred",
                  19: "soft temperature limit occurred"}


def register(sub, common) -> None:
    p = sub.add_parser("selftest", parents=[common], help="on-device checks: camera, UART, "
                       "data checksums, temperature, throttling")
    p.add_argument("--backend", choices=("picamera2", "v4l2"),
                   help="camera backend to probe (default: the configured live one)")
    p.add_argument("--loopback", action="store_true",
                   help="UART loopback test (connect TX to RX first)")
    p.add_argument("--skip", nargs="+", default=(), metavar="CHECK",
                   help="checks to skip: camera, uart, data, cpu_temp, throttle")
    p.set_defaults(func=run)


def _bits_report(image: np.ndarray) -> str:
    if image.dtype != np.uint16:
        return "8-bit data"
    used = int(np.bitwise_or.reduce(image, axis=None))
    low_zero = (used & -used).bit_length() - 1 if used else 16
    return f"bits used 0x{used:04x} (lowest {low_zero} bits always 0)"


def check_camera(cfg: Config, args) -> tuple[str, str]:
    backend = args.backend or (cfg.capture.backend if cfg.capture.backend != "replay"
                               else "picamera2")
    cfg = dataclasses.replace(cfg, capture=dataclasses.replace(cfg.capture, backend=backend,
                                                               raw_shift=0))
    frames = []
    t0 = time.monotonic()
    try:
        with make_source(cfg) as source:
            for item in source:
                if isinstance(item, Frame):
                    frames.append((item.exposure_us, item.gain, item.image.copy()))
                if len(frames) >= _FRAMES or time.monotonic() - t0 > 10 * cfg.capture.timeout_s:
                    break
            granted = getattr(source, "granted", "")
    except Exception as exc:    # any failure to reach the camera is this check's result
        return "FAIL", f"no camera ({backend}): {exc}"
    if not frames:
        return "FAIL", f"{backend}: camera opened (granted {granted}) but delivered no frame"
    fps = len(frames) / max(time.monotonic() - t0, 1e-9)
    exposure, gain, image = frames[-1]
    return "PASS", (f"{backend}: granted {granted}, {image.shape[1]}x{image.shape[0]}, "
                    f"{len(frames)} frames at ~{fps:.1f} fps, exposure {exposure} us, "
                    f"gain {gain}; {_bits_report(image)}")


def check_uart(cfg: Config, args) -> tuple[str, str]:
    port = cfg.link.port
    if not args.loopback:
        if "://" in port:
            return "SKIP", f"{port} is a URL; nothing to check without --loopback"
        if not os.path.exists(port):
            return "FAIL", f"{port}: no such device (firmware_config/ enables UART0)"
        if not os.access(port, os.R_OK | os.W_OK):
            return "FAIL", f"{port}: not readable and writable by this user (group dialout?)"
        return "PASS", f"{port} present and accessible (use --loopback to test the wire)"
    import serial

    data = os.urandom(256)
    try:
        with serial.serial_for_url(port, baudrate=cfg.link.baudrate, timeout=1.0) as ser:
            ser.reset_input_buffer()
            ser.write(data)
            back = ser.read(len(data))
    except (serial.SerialException, OSError, ValueError) as exc:
        return "FAIL", f"{port}: {exc}"
    if back != data:
        differ = sum(a != b for a, b in zip(back, data, strict=False))
        return "FAIL", (f"{port} at {cfg.link.baudrate} baud: {len(back)} of {len(data)} "
                        f"bytes came back, {differ} differ")
    return "PASS", f"{port} loopback at {cfg.link.baudrate} baud: 256 bytes intact"


def _sidecar_ok(path: Path) -> str | None:
    """None if ``path`` matches ``path.sha256``, else why not."""
    try:
        expected = Path(f"{path}.sha256").read_text(encoding="ascii").split()[0].lower()
    except (OSError, IndexError, UnicodeDecodeError):
        return f"{path.name}: no readable .sha256 file"
    if hashlib.sha256(path.read_bytes()).hexdigest() != expected:
        return f"{path.name}: SHA-256 mismatch"
    return None


def check_data(cfg: Config, args) -> tuple[str, str]:
    folder = default_catalogue_path().parent
    files = sorted(folder.glob("*.npz"))
    problems = [p for p in map(_sidecar_ok, files) if p]
    try:
        cat = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year,
                             cfg.catalogue.mag_limit)
    except CatalogueError as exc:
        problems.append(str(exc))
        cat = None
    if problems:
        return "FAIL", "; ".join(problems)
    return "PASS", (f"{len(files)} files in {folder} match their checksums; catalogue "
                    f"{len(cat)} stars")


def check_cpu_temp(cfg: Config, args) -> tuple[str, str]:
    temp = cpu_temperature_c()
    if temp is None:
        return "SKIP", "no /sys/class/thermal/thermal_zone0/temp here"
    status = "FAIL" if temp >= 85 else "WARN" if temp >= 75 else "PASS"
    return status, f"SoC at {temp:.1f} C"


def check_throttle(cfg: Config, args) -> tuple[str, str]:
    tool = shutil.which("vcgencmd")
    if tool is None:
        return "SKIP", "vcgencmd not found (not a Raspberry Pi)"
    try:
        out = subprocess.run([tool, "get_throttled"], capture_output=True, text=True,
                             timeout=5, check=True).stdout
        value = int(out.strip().split("=")[-1], 16)
    except (subprocess.SubprocessError, OSError, ValueError) as exc:
        return "WARN", f"vcgencmd get_throttled failed: {exc}"
    found = [text for bit, text in _THROTTLE_BITS.items() if value >> bit & 1]
    if value & 0xF:
        return "FAIL", f"0x{value:x}: " + ", ".join(found)
    if found:
        return "WARN", f"0x{value:x}: " + ", ".join(found)
    return "PASS", "0x0: no under-voltage or throttling since boot"


CHECKS = {"camera": check_camera, "uart": check_uart, "data": check_data,
          "cpu_temp": check_cpu_temp, "throttle": check_throttle}


def run(args, cfg: Config) -> int:
    failed = False
    for name, check in CHECKS.items():
        status, text = ("SKIP", "skipped (--skip)") if name in args.skip else check(cfg, args)
        failed = failed or status == "FAIL"
        print(f"{status:4} {name:9} {text}", flush=True)
    return 1 if failed else 0
