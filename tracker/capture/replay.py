"""Replay backend: frames from image files or folders, in name order.

Paths are expanded by the shared rule of :mod:`tracker.capture.input_paths`
(folders to the image files directly inside them, sorted by name; files named
explicitly in the order given; a missing path, a device or an empty folder is
a one-line error before anything is read). With ``loop`` the list starts
again after the last file; with ``fps`` > 0 frames are paced to that rate on
the monotonic clock, waiting in slices that yield
:class:`~tracker.capture.base.Waiting` (as a live camera does between
frames, so the daemon's watchdog stays fed). A file that cannot be read becomes a
:class:`~tracker.capture.base.FrameError` and replay goes on.

Metadata: a folder may hold ``frames.jsonl`` (written by ``tracker record``
and ``tracker simulate``), one JSON object per frame with ``file`` and any of
``t_ns`` (exposure mid-point, monotonic), ``exposure_us``, ``gain``, ``utc``
(the exposure mid-point as ISO 8601 UTC ending in ``Z``, e.g.
``2026-11-23T17:29:15.25Z``; a leap second's ``23:59:60`` is accepted) and
``observer_velocity_km_s`` ([x, y, z], the observer's velocity relative to
the Earth's centre at that time, ICRS axes). Replayed frames carry those
values, so tracking sees the recorded time base rather than the replay's,
and the solver the
recorded absolute time and velocity (tracker.astrometry.observer). A
``utc`` or ``observer_velocity_km_s`` that cannot be used is a
:class:`~tracker.errors.UserError` naming the file and line, before any
frame is read: a silently ignored time would cost 20 arcsec.

A frame without a recorded ``t_ns`` is stamped on a fixed time base: the
replay's start on the monotonic clock plus its index times the frame
interval (``1 / fps``, or ``interval_s`` when replaying as fast as possible).
Not the time it was read: tracking predicts the next frame's stars from the
time between frames, so a clock reading would make the answer depend on how
loaded the machine is.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from tracker.astrometry.observer import check_velocity
from tracker.astrometry.timescale import TimeError, check_tai_ns, tai_ns_from_utc_iso
from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.imagefile import IMAGE_SUFFIXES, ImageReadError, read_image
from tracker.capture.input_paths import expand_inputs
from tracker.capture.live import WAIT_SLICE_S
from tracker.errors import UserError

__all__ = ["ReplaySource", "expand_paths", "read_metadata", "METADATA_FILE"]

METADATA_FILE = "frames.jsonl"


def expand_paths(paths: Sequence[str | Path]) -> list[Path]:
    """The image files to replay, in order (tracker.capture.input_paths; UserError if none)."""
    return expand_inputs(paths, IMAGE_SUFFIXES)


def _absolute_time(record: dict, where: str) -> dict:
    """The record with ``utc`` as ``t_tai_ns`` and its velocity checked; UserError if unusable."""
    out = dict(record)
    try:
        if record.get("utc") is not None:
            out["t_tai_ns"] = check_tai_ns(tai_ns_from_utc_iso(record["utc"]))
        if record.get("observer_velocity_km_s") is not None:
            out["observer_velocity_km_s"] = check_velocity(record["observer_velocity_km_s"],
                                                           "observer_velocity_km_s")
    except (TimeError, ValueError) as exc:
        raise UserError(f"{where}: {exc}") from None
    return out


def read_metadata(paths: Sequence[str | Path]) -> dict[Path, dict]:
    """Per-file metadata from the ``frames.jsonl`` of each folder named (see module doc).

    Lines that are not JSON objects with a ``file`` key are skipped; a line
    whose ``utc`` or ``observer_velocity_km_s`` cannot be used raises
    :class:`~tracker.errors.UserError`. ``utc`` is also given as
    ``t_tai_ns`` (TAI ns since 1970).
    """
    meta: dict[Path, dict] = {}
    for folder in map(Path, paths):
        index = folder / METADATA_FILE
        if not (folder.is_dir() and index.is_file()):
            continue
        lines = index.read_text(encoding="utf-8", errors="replace").splitlines()
        for number, line in enumerate(lines, 1):
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if isinstance(record, dict) and isinstance(record.get("file"), str):
                meta[(folder / record["file"]).resolve()] = _absolute_time(
                    record, f"{index} line {number}")
    return meta


class ReplaySource:
    """A FrameSource over files; see the module docstring.

    ``expect_shape`` (height, width), when given, turns frames of another
    size into errors rather than passing them on. ``max_size`` (width,
    height; default: that of ``expect_shape``) is the largest image decoded
    (tracker.capture.imagefile); a larger one is an error read from its
    header alone. ``interval_s``: the time between frames without a recorded
    ``t_ns`` when ``fps`` is 0 (module docstring), s.
    """

    def __init__(self, paths: Sequence[str | Path], *, loop: bool = False, fps: float = 0.0,
                 bits16_depth: int = 10, expect_shape: tuple[int, int] | None = None,
                 max_size: tuple[int, int] | None = None, interval_s: float = 0.1):
        self.files = expand_paths(paths)
        self.metadata = read_metadata(paths)
        self.loop = loop
        self.period_ns = int(1e9 / fps) if fps > 0 else 0
        self.step_ns = self.period_ns or round(interval_s * 1e9)
        self.bits16_depth = bits16_depth
        self.expect_shape = expect_shape
        if max_size is None and expect_shape is not None:
            max_size = (expect_shape[1], expect_shape[0])
        self.max_size = max_size
        self._closed = False

    def __len__(self) -> int:
        return len(self.files)

    def _load(self, index: int, path: Path, t_nominal_ns: int) -> Frame | FrameError:
        try:
            image, depth = read_image(path, self.bits16_depth, self.max_size)
        except ImageReadError as exc:
            return FrameError(index, path.name, str(exc))
        if self.expect_shape is not None and image.shape != tuple(self.expect_shape):
            h, w = self.expect_shape
            return FrameError(index, path.name, f"{path.name}: frame is {image.shape[1]}x"
                              f"{image.shape[0]}, expected {w}x{h}")
        meta = self.metadata.get(path.resolve(), {})
        t_ns = meta.get("t_ns")
        return Frame(index, path.name, image, depth,
                     int(t_ns) if isinstance(t_ns, int) else t_nominal_ns,
                     exposure_us=meta.get("exposure_us"), gain=meta.get("gain"),
                     t_tai_ns=meta.get("t_tai_ns"),
                     observer_velocity_km_s=meta.get("observer_velocity_km_s"))

    def __iter__(self) -> Iterator[Frame | FrameError | Waiting]:
        index = 0
        start_ns = next_due = time.monotonic_ns()
        while not self._closed and self.files:
            for path in self.files:
                if self._closed:
                    return
                if self.period_ns:
                    yield from self._wait_until(next_due)
                    next_due += self.period_ns
                yield self._load(index, path, start_ns + index * self.step_ns)
                index += 1
            if not self.loop:
                return

    def _wait_until(self, due_ns: int) -> Iterator[Waiting]:
        """Sleep until ``due_ns`` in slices, yielding :class:`Waiting` after each one.

        A slow replay rate thus keeps the daemon's watchdog fed, as a live
        camera between frames does.
        """
        waited = 0.0
        while not self._closed:
            delay_s = (due_ns - time.monotonic_ns()) / 1e9
            if delay_s <= 0:
                return
            step = min(delay_s, WAIT_SLICE_S)
            time.sleep(step)
            waited += step
            if delay_s > step:
                yield Waiting(waited)

    def close(self) -> None:
        self._closed = True

    def __enter__(self) -> ReplaySource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
