"""``tracker record --out DIR``: save camera frames with their metadata for replay.

Frames come from ``capture.backend`` (normally picamera2 or v4l2) and are
written as ``DIR/frame_NNNNNN.npy`` (default: exact, fast) or ``.png``
(16-bit for 10-bit data, lossless, smaller, slower), which ``tracker replay
DIR`` reads in name order. ``DIR/frames.jsonl`` gets one JSON object per
frame: ``file``, ``index``, ``t_ns`` (exposure mid-point, monotonic),
``wall_time`` (when it was saved, UTC, ISO 8601), ``exposure_us``, ``gain``,
``bit_depth``, ``cpu_temp_c`` and the backend's ``meta`` (sensor
timestamp...); a frame the source could not deliver gets ``{"index",
"error"}``.

``utc``, the exposure mid-point as ISO 8601 UTC (what replay needs to
correct aberration), is written only when it is known: from the camera's
monotonic stamp and the Pi's own clock when ``time.system_clock`` trusts
that clock (``always``, or ``synchronised`` while the kernel says NTP keeps
it: tracker.system_clock), and for frames recorded from files (``--replay``)
when their own record has one; the same goes for
``observer_velocity_km_s``.

Disk-space guard: before each frame the free space of DIR's file system is
checked, and recording stops (exit status 1, after closing the files
cleanly) when writing the frame would leave less than ``--min-free-mb``. A
write that fails all the same (the disk filled up faster, a quota) stops it
the same way: the partial frame file is removed, one line says why, and
``frames.jsonl`` (written a line at a time) lists every frame kept.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import signal
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from tracker.astrometry.observer import Observer
from tracker.astrometry.timescale import utc_iso_from_tai_ns
from tracker.board import cpu_temperature_c
from tracker.capture.backends import make_source
from tracker.capture.base import FrameError, Waiting
from tracker.capture.live import CameraError
from tracker.commands.argtypes import count, non_negative, positive_count
from tracker.commands.outputs import output_folder
from tracker.config import Config
from tracker.daemon.timebase import TimeBase
from tracker.errors import UserError

__all__ = ["register", "run", "DiskGuard"]

log = logging.getLogger(__name__)


class DiskGuard:
    """Says whether ``nbytes`` more may be written under ``folder`` keeping ``min_free`` bytes."""

    def __init__(self, folder: Path, min_free_bytes: int):
        self.folder = folder
        self.min_free = min_free_bytes

    def allows(self, nbytes: int) -> bool:
        return shutil.disk_usage(self.folder).free - nbytes >= self.min_free


def register(sub, common) -> None:
    p = sub.add_parser("record", parents=[common], help="save camera frames and metadata "
                       "(exposure, gain, time, temperature) for `tracker replay`")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for frames + frames.jsonl")
    p.add_argument("--frames", type=count, default=100, metavar="N",
                   help="frames to save (default 100; 0 = until stopped)")
    p.add_argument("--every", type=positive_count, default=1, metavar="K",
                   help="keep every K-th frame")
    p.add_argument("--format", choices=("npy", "png"), default="npy", help="file format")
    p.add_argument("--min-free-mb", type=non_negative, default=500.0, metavar="MB",
                   help="stop when less than this would remain free (default 500)")
    p.add_argument("--replay", nargs="+", metavar="PATH",
                   help="record from these files instead of the camera (tests, re-encoding)")
    p.set_defaults(func=run)


def _save(path: Path, image: np.ndarray) -> None:
    """Write one frame; on any failure remove what was written and raise OSError."""
    try:
        if path.suffix == ".npy":
            np.save(path, image, allow_pickle=False)
        elif not cv2.imwrite(str(path), image):
            raise OSError("the PNG encoder failed")
    except OSError:
        path.unlink(missing_ok=True)
        raise


def _absolute_time(observer: Observer) -> dict:
    """A frame record's ``utc`` and ``observer_velocity_km_s``, where known (module doc)."""
    out = {}
    if observer.t_tai_ns is not None:
        out["utc"] = utc_iso_from_tai_ns(observer.t_tai_ns)
        if observer.velocity_km_s is not None:
            out["observer_velocity_km_s"] = list(observer.velocity_km_s)
    return out


def run(args, cfg: Config) -> int:
    out = output_folder(args.out, "--out")
    guard = DiskGuard(out, int(args.min_free_mb * 2**20))
    if args.replay:
        cfg = dataclasses.replace(cfg, capture=dataclasses.replace(cfg.capture,
                                                                   backend="replay"))
    timebase = TimeBase(cfg.time)
    stop = []
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    saved = seen = 0
    code = 0
    try:
        # one line at a time (line buffering): whatever stops the recording, the
        # index lists every frame that was kept
        with make_source(cfg, args.replay) as source, \
                open(out / "frames.jsonl", "a", encoding="utf-8", buffering=1) as meta:
            for item in source:
                if stop or (args.frames and saved >= args.frames):
                    break
                if isinstance(item, Waiting):     # a live camera between frames
                    continue
                seen += 1
                if (seen - 1) % args.every:
                    continue
                if isinstance(item, FrameError):
                    meta.write(json.dumps({"index": item.index, "error": item.reason}) + "\n")
                    continue
                if not guard.allows(item.image.nbytes):
                    log.error("disk-space guard: less than %.0f MB would remain free in %s; "
                              "stopped after %d frames", args.min_free_mb, out, saved)
                    code = 1
                    break
                name = f"frame_{saved:06d}.{args.format}"
                try:
                    _save(out / name, item.image)
                    record = {"file": name, "index": item.index, "t_ns": item.t_ns,
                              "wall_time": datetime.now(UTC).isoformat(timespec="milliseconds"),
                              "exposure_us": item.exposure_us, "gain": item.gain,
                              "bit_depth": item.bit_depth, "cpu_temp_c": cpu_temperature_c(),
                              "source": item.name, "meta": item.meta,
                              **_absolute_time(item.recorded_observer() if args.replay
                                               else timebase.observer_for(item))}
                    meta.write(json.dumps(record) + "\n")
                except OSError as exc:
                    (out / name).unlink(missing_ok=True)
                    log.error("cannot write %s (%s; %s bytes free there); stopped after %d "
                              "frames", out / name, exc.strerror or exc,
                              f"{shutil.disk_usage(out).free:,}", saved)
                    code = 1
                    break
                saved += 1
    except KeyboardInterrupt:
        pass
    except CameraError as exc:
        raise UserError(f"camera: {exc} ({saved} frames saved)") from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    log.info("recorded %d frames to %s", saved, out)
    return code
