"""The FrameSource interface every capture backend implements.

A source yields, in order, either a :class:`Frame` (pixels plus metadata) or
a :class:`FrameError` (what could not be read, and why). An error never ends
the stream: the consumer counts it and asks for the next item. A live source
also yields :class:`Waiting` whenever it has waited a slice of time
(``tracker.capture.live.WAIT_SLICE_S``) without a frame, so its consumer
keeps control during long exposures or a silent camera; nothing is lost.
A source is a context manager; leaving the block releases the device or files.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from tracker.astrometry.observer import Observer, TimeSource

__all__ = ["Frame", "FrameError", "FrameSource", "Waiting"]


@dataclass
class Frame:
    """One image and what is known about it.

    ``image`` is 2-D, uint8 (8-bit) or uint16 holding ``bit_depth``-bit
    values. ``t_ns`` is the exposure mid-point on the monotonic clock (for
    replay: the record's ``t_ns``, else when the frame was read). Live
    backends hand out one of a ring of reused buffers: the image is
    overwritten when the source is asked for the frame ``frame_buffers``
    after it (a source without that attribute never reuses an image).

    ``t_tai_ns`` is the exposure mid-point as an absolute time (TAI ns since
    1970, tracker.astrometry.timescale) when the frame's own record gives
    one (a replay's ``utc``), and ``observer_velocity_km_s`` the observer's
    velocity relative to the Earth's centre (ICRS axes, km/s) at that time;
    None when unknown. Live frames carry neither: the daemon supplies them
    from TIME_SYNC and SET_VELOCITY (tracker.daemon.timebase).
    """

    index: int
    name: str
    image: np.ndarray
    bit_depth: int
    t_ns: int
    exposure_us: float | None = None
    gain: float | None = None
    meta: dict = field(default_factory=dict)
    t_tai_ns: int | None = None
    observer_velocity_km_s: tuple[float, float, float] | None = None

    def recorded_observer(self) -> Observer:
        """The observer context the frame's own record gives (empty without ``t_tai_ns``)."""
        if self.t_tai_ns is None:
            return Observer()
        return Observer(self.t_tai_ns, self.observer_velocity_km_s, TimeSource.RECORD)


@dataclass
class FrameError:
    """A frame that could not be delivered; ``reason`` is one line for people."""

    index: int
    name: str
    reason: str


@dataclass(frozen=True)
class Waiting:
    """No frame yet: the source has waited ``waited_s`` seconds for this one so far."""

    waited_s: float


class FrameSource(Protocol):
    """Anything that yields frames: replay files, picamera2, V4L2.

    Optional attributes: ``live`` (True: a running camera that does not wait
    for its consumer; default False) and ``frame_buffers`` (the ring of
    images a live source reuses; default: none reused).
    """

    def __iter__(self) -> Iterator[Frame | FrameError | Waiting]: ...

    def close(self) -> None: ...

    def __enter__(self) -> FrameSource: ...

    def __exit__(self, *exc: object) -> None: ...
