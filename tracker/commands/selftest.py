"""``tracker selftest``: on-device checks before (or instead of) starting the service.

Each check prints one line, ``PASS``, ``WARN``, ``FAIL`` or ``SKIP``, its
name and what it found; the exit status is 1 if any check failed.

- ``service``: whether the startracker service is running. It holds the
  camera and the UART, so while it runs the camera and UART checks fail
  with that reason (stop it first: ``sudo systemctl stop startracker``).
- ``picamera2``: the installed picamera2 and libcamera work together
  (picamera2 0.3.20 .. 0.3.25 with a libcamera that lacks ExposureTimeMode,
  as Arducam's 0.3.x build; see tracker.capture.picamera2_source).
- ``camera``: opens the live backend (``--backend``, default the configured
  one, or picamera2 when that is replay) and captures a few frames with
  ``raw_shift`` 0. picamera2: the granted raw format and size; v4l2: the
  rp1-cfe graph it set up (links, pad formats, video node) and whether the
  sensor's exposure and gain controls exist. Then the frame rate (from the
  frames' timestamps), exposure, gain, and the raw shift the data needs: a
  16-bit word above the sensor's full scale (1023 at 10 bits) means the data
  sits in the high bits (``capture.raw_shift`` = 16 - bit depth), else in the
  low bits (0); a configured value that disagrees fails.
- ``uart``: with ``--loopback`` (TX wired to RX), writes 256 random bytes to
  ``link.port`` and reads them back, holding the port's lock as the service
  does (another holder is named); otherwise only checks that the device exists
  and is readable and writable by this user.
- ``data``: every ``*.npz`` in the package's data folder matches its ``.sha256`` file,
  and the configured catalogue loads.
- ``clock``: the system clock's UTC and whether the kernel says NTP or PTP
  keeps it synchronised (tracker.system_clock), against
  ``time.system_clock``: warns when the configuration trusts a clock the
  kernel calls unsynchronised, or trusts it ``always`` (on the Pi's own
  word alone); absolute time then comes from TIME_SYNC only.
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

from tracker.astrometry.timescale import utc_iso_from_tai_ns
from tracker.board import THROTTLE_BITS, cpu_temperature_c, throttled
from tracker.capture.backends import make_source
from tracker.capture.base import Frame, FrameError
from tracker.capture.picamera2_source import compatibility_problem, installed_versions
from tracker.catalogue import CatalogueError, default_catalogue_path, load_catalogue
from tracker.config import Config
from tracker.system_clock import kernel_synchronised, tai_minus_monotonic_ns

__all__ = ["register", "run", "CHECKS", "raw_shift_advice"]

_FRAMES = 5
_UNIT = "startracker.service"
_BUSY = (f"the {_UNIT} is running and holds the camera and the UART; stop it first: "
         "sudo systemctl stop startracker")


def register(sub, common) -> None:
    p = sub.add_parser("selftest", parents=[common], help="on-device checks: camera, UART, "
                       "data checksums, temperature, throttling")
    p.add_argument("--backend", choices=("picamera2", "v4l2"),
                   help="camera backend to probe (default: the configured live one)")
    p.add_argument("--loopback", action="store_true",
                   help="UART loopback test (connect TX to RX first)")
    p.add_argument("--skip", nargs="+", default=(), metavar="CHECK",
                   help="checks to skip: " + ", ".join(CHECKS))
    p.set_defaults(func=run)


def service_running() -> bool:
    """Whether systemd reports the startracker service active (False without systemd)."""
    tool = shutil.which("systemctl")
    if tool is None:
        return False
    try:
        return subprocess.run([tool, "is-active", "--quiet", _UNIT], timeout=10).returncode == 0
    except (subprocess.SubprocessError, OSError):
        return False


def raw_shift_advice(image: np.ndarray, bit_depth: int, configured: int) -> tuple[bool, str]:
    """(configured shift is right, why) for a frame captured with raw_shift 0.

    A word above the sensor's full scale (2^bit_depth - 1) can only come from
    data in the high bits: the shift is then 16 - bit_depth, else 0. The
    black level keeps even a dark frame's words above zero.
    """
    if image.dtype != np.uint16:
        return True, "8-bit data, no shift"
    full = (1 << bit_depth) - 1
    top = int(image.max())
    need = 16 - bit_depth if top > full else 0
    where = "high" if need else "low"
    text = (f"largest word {top} {'>' if need else '<='} {full}: {bit_depth}-bit data in the "
            f"{where} bits, capture.raw_shift {need}")
    if need != configured:
        return False, f"{text}, but it is {configured}: set capture.raw_shift: {need}"
    return True, text


def _backend(cfg: Config, args) -> str:
    return args.backend or (cfg.capture.backend if cfg.capture.backend != "replay"
                            else "picamera2")


def check_service(cfg: Config, args) -> tuple[str, str]:
    if args.service_running:
        return "WARN", _BUSY
    return "PASS", "not running (the camera and the UART are free)"


def check_picamera2(cfg: Config, args) -> tuple[str, str]:
    if _backend(cfg, args) != "picamera2":
        return "SKIP", "the camera backend is v4l2"
    version, exposure_mode = installed_versions()
    if version is None:
        return "FAIL", "picamera2 is not installed (apt install python3-picamera2)"
    problem = compatibility_problem(version, exposure_mode)
    libcamera = {None: "libcamera not importable", True: "libcamera has ExposureTimeMode",
                 False: "libcamera without ExposureTimeMode (0.3.x)"}[exposure_mode]
    if problem:
        return "FAIL", problem
    return "PASS", f"picamera2 {version}, {libcamera}"


def check_camera(cfg: Config, args) -> tuple[str, str]:
    backend = _backend(cfg, args)
    if args.service_running:
        return "FAIL", f"{backend}: {_BUSY}"
    probe = dataclasses.replace(cfg, capture=dataclasses.replace(cfg.capture, backend=backend,
                                                                 raw_shift=0))
    frames, errors = [], []
    try:
        with make_source(probe) as source:
            for item in source:     # the source itself gives up after three late frames
                if isinstance(item, Frame):
                    frames.append((item.t_ns, item.exposure_us, item.gain, item.image.copy()))
                elif isinstance(item, FrameError):
                    errors.append(item.reason)
                if len(frames) >= _FRAMES or len(errors) >= _FRAMES:
                    break
            granted = getattr(source, "granted", "")
            controls = getattr(source, "controls", None)
    except Exception as exc:    # any failure to reach the camera is this check's result
        return "FAIL", f"no camera ({backend}): {exc}"
    if not frames:
        return "FAIL", (f"{backend}: camera opened ({granted}) but delivered no frame: "
                        f"{'; '.join(errors[:2])}")
    times = [t for t, *_ in frames]
    span_s = (times[-1] - times[0]) / 1e9
    fps = (len(times) - 1) / span_s if span_s > 0 else float("nan")
    _, exposure, gain, image = frames[-1]
    ok, shift = raw_shift_advice(image, cfg.camera.bit_depth, cfg.capture.raw_shift)
    text = (f"{backend}: {granted}; {image.shape[1]}x{image.shape[0]}, {len(frames)} frames "
            f"at {fps:.1f} fps (buffer times), exposure {exposure} us, gain {gain}; {shift}")
    if controls is not None and not controls.available:
        return "FAIL", text + "; the sensor has no EXPOSURE/ANALOGUE_GAIN/PIXEL_RATE controls"
    return ("PASS" if ok and not errors else "WARN" if ok else "FAIL"), \
        text + (f"; {len(errors)} frame(s) lost: {errors[0]}" if errors else "")


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
    if args.service_running:
        return "FAIL", f"{port}: {_BUSY}"
    import serial

    data = os.urandom(256)
    try:
        with serial.serial_for_url(port, baudrate=cfg.link.baudrate, timeout=1.0,
                                   exclusive=True) as ser:
            ser.reset_input_buffer()
            ser.write(data)
            back = ser.read(len(data))
    except (serial.SerialException, OSError, ValueError) as exc:
        busy = " (another process holds it: the service?)" if "lock" in str(exc) else ""
        return "FAIL", f"{port}: {exc}{busy}"
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


def check_clock(cfg: Config, args) -> tuple[str, str]:
    policy = cfg.time.system_clock
    synced = kernel_synchronised()
    now = utc_iso_from_tai_ns(tai_minus_monotonic_ns() + time.monotonic_ns())[:19] + "Z"
    state = {True: "synchronised (NTP/PTP, adjtimex)", False: "not synchronised (adjtimex)",
             None: "synchronisation unknown (no adjtimex)"}[synced]
    text = f"system clock {now}, {state}; time.system_clock: {policy}"
    if policy == "never":
        return "PASS", text + " (absolute time from TIME_SYNC only)"
    if policy == "always" or not synced:
        return "WARN", text + (" (trusted without the kernel's word)" if policy == "always"
                               else " (not used until it is)")
    return "PASS", text + " (used until TIME_SYNC)"


def check_cpu_temp(cfg: Config, args) -> tuple[str, str]:
    temp = cpu_temperature_c()
    if temp is None:
        return "SKIP", "no /sys/class/thermal/thermal_zone0/temp here"
    status = "FAIL" if temp >= 85 else "WARN" if temp >= 75 else "PASS"
    return status, f"SoC at {temp:.1f} C"


def check_throttle(cfg: Config, args) -> tuple[str, str]:
    try:
        value = throttled()
    except (OSError, ValueError) as exc:
        return "WARN", f"vcgencmd get_throttled failed: {exc}"
    if value is None:
        return "SKIP", "vcgencmd not found (not a Raspberry Pi)"
    found = [text for bit, text in THROTTLE_BITS.items() if value >> bit & 1]
    if value & 0xF:
        return "FAIL", f"0x{value:x}: " + ", ".join(found)
    if found:
        return "WARN", f"0x{value:x}: " + ", ".join(found)
    return "PASS", "0x0: no under-voltage or throttling since boot"


CHECKS = {"service": check_service, "picamera2": check_picamera2, "camera": check_camera,
          "uart": check_uart, "data": check_data, "clock": check_clock,
          "cpu_temp": check_cpu_temp,
          "throttle": check_throttle}


def run(args, cfg: Config) -> int:
    args.service_running = "service" not in args.skip and service_running()
    failed = False
    for name, check in CHECKS.items():
        status, text = ("SKIP", "skipped (--skip)") if name in args.skip else check(cfg, args)
        failed = failed or status == "FAIL"
        print(f"{status:4} {name:9} {text}", flush=True)
    return 1 if failed else 0
