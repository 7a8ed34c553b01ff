"""Stand-ins for the daemon's tests: a virtual clock, a systemd notify socket, fake stages.

The virtual clock makes the daemon's waits take no real time: ``wait``
advances it. :class:`NotifyListener` is a real AF_UNIX datagram socket, as
systemd's NOTIFY_SOCKET is; it stamps each datagram with the virtual time at
which it was sent (datagrams are queued synchronously by ``sendto``, and the
clock drains the socket before every advance, so the stamp is exact).
"""

import dataclasses
import socket
import time
from types import SimpleNamespace

import numpy as np

from tracker.capture.base import Frame
from tracker.config import Config
from tracker.daemon.link import LinkCounts
from tracker.daemon.status import status_values
from tracker.detect import STAR_DTYPE, Detections
from tracker.pipeline import FrameResult

SOLVED, UNSOLVED, RAISE = "solved", "unsolved", "raise"


class VirtualClock:
    """now_ns() and wait() of tracker.daemon.clock.Clock, on virtual time."""

    def __init__(self, start_s: float = 1000.0):
        self.t = int(start_s * 1e9)
        self.before_advance = []          # callables run before time moves on

    def now_ns(self) -> int:
        return self.t

    def advance(self, seconds: float) -> None:
        for hook in self.before_advance:
            hook()
        self.t += int(round(seconds * 1e9))

    def wait(self, event, seconds: float) -> bool:
        if event.is_set():
            return True
        self.advance(seconds)
        return event.is_set()


class NotifyListener:
    """A systemd-like NOTIFY_SOCKET; ``messages`` holds (virtual ns, text) per datagram."""

    def __init__(self, path, clock: VirtualClock):
        self.path = str(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.setblocking(False)
        self.clock = clock
        self.messages: list[tuple[int, str]] = []
        clock.before_advance.append(self.drain)

    def drain(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return
            self.messages.append((self.clock.now_ns(), data.decode()))

    def times_of(self, text: str) -> list[int]:
        self.drain()
        return [t for t, m in self.messages if text in m.split("\n")]

    def close(self) -> None:
        self.sock.close()


def frame(i, tag=SOLVED, t_ns=None):
    """A tiny frame; the fake pipeline keys its answer on t_ns (default i)."""
    return Frame(i, tag, np.zeros((4, 4), np.uint16), 10, i if t_ns is None else t_ns)


class FakeSource:
    """Yields a script; an exception instance in it is raised from the iterator.

    A callable in the script is called (e.g. to advance a virtual clock) and
    what it returns is yielded unless it is None.
    """

    def __init__(self, script):
        self.script = script
        self.closed = False
        self.controls = []

    def __iter__(self):
        for item in self.script:
            if callable(item):
                item = item()
                if item is None:
                    continue
            if isinstance(item, BaseException):
                raise item
            yield item

    def set_controls(self, exposure_us, gain):
        self.controls.append((exposure_us, gain))
        return True

    def close(self):
        self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def paced_frames(period_s: float = 0.005) -> FakeSource:
    """An endless source of tiny frames, one every period_s of real time (link tests)."""
    def frames():
        i = 0
        while True:
            time.sleep(period_s)
            yield Frame(i, f"f{i}", np.zeros((8, 8), np.uint16), 10, 1000 + i)
            i += 1
    return FakeSource(frames())


class FakePipeline:
    """Solves frames tagged 'solved', fails 'unsolved', raises on 'raise'.

    The pipeline sees only pixels and time, so ``tags`` maps t_ns -> tag
    (a t_ns not in it is solved).
    """

    def __init__(self, tags=None):
        self.tags = tags or {}
        self.resets = 0
        self.seen = []
        self.observer = None           # the latest frame's context

    def reset(self):
        self.resets += 1

    def process(self, image, bit_depth, t_ns, observer=None, exposure_s=None):
        self.seen.append(t_ns)
        self.observer = observer
        tag = self.tags.get(t_ns, SOLVED)
        if tag == RAISE:
            raise ValueError("boom")
        stars = np.zeros(5, STAR_DTYPE)
        stars["peak"] = 0.5 * 1023
        sol = SimpleNamespace(ok=tag == SOLVED, q=np.array([1.0, 0, 0, 0]),
                              sigma_cross_arcsec=2.0, sigma_roll_arcsec=20.0, matched=12,
                              rate_rad_s=None, hip=np.zeros(5, np.int32))
        return FrameResult(Detections(stars), sol, 1.0, {"detect.x": 0.5}, None, observer)


class FakeLink:
    """The loop-side face of DaemonLink, recording what the loop hands it."""

    def __init__(self, clock=None):
        self.is_open = False
        self.closed = False
        self.failure = None
        self.sent = []                 # (frame index, mode, solved or None for STANDBY)
        self.snapshots = []            # (clock ns or None, StatusSnapshot)
        self.pending = []              # Commands values handed out one per take
        self.observers = []            # the observer context of each frame sent
        self.t_refs = []               # the time each frame's latency runs from
        self.clock = clock

    def open(self):
        self.is_open = True

    def close(self):
        self.closed = True

    def take_commands(self):
        return self.pending.pop(0) if self.pending else None

    def publish(self, snapshot):
        self.snapshots.append((self.clock.now_ns() if self.clock else None, snapshot))

    def counts(self):
        return LinkCounts({}, 0, 0)

    def send_frame(self, frame, result, mode, observer, t_ref_ns=None):
        solved = None if result is None else bool(result.solution.ok)
        self.sent.append((frame.index, mode, solved))
        self.observers.append(observer)
        self.t_refs.append(t_ref_ns)

    def statuses(self):
        return [(t, status_values(s)) for t, s in self.snapshots]


def config(**service_keys) -> Config:
    keys = {"retry_initial_s": 0.001, "retry_max_s": 0.002, "watchdog_s": 0.0,
            **service_keys}
    return dataclasses.replace(Config(), service=dataclasses.replace(Config().service, **keys))
