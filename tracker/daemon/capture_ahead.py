"""Capture running ahead of processing: frame N+1 is taken while frame N is processed.

A thread iterates the frame source and hands its items to the frame loop
through a small slot (:meth:`CaptureAhead.take`); the loop processes one
frame while the thread waits for the next, so the time a frame costs is the
longer of its capture and its processing, not their sum.

- **Live sources** (a running camera, ``source.live``): the newest frame
  wins. A frame still waiting in the slot when a newer one arrives is
  *superseded*: never processed, counted (:attr:`CaptureAhead.superseded`),
  its buffer free again. A frame therefore waits at most for the frame
  being processed before its own processing starts, which bounds the
  latency. FrameError items are never superseded (each is a fault to count);
  the slot holds at most :data:`SLOT_ITEMS` items and the thread waits when
  it is full.
- **Other sources** (replay): nothing is superseded; the thread waits until
  the loop has taken the item before reading the next file. The loop sees
  the same items in the same order as without the thread.

Buffers: a live source writes its frames into a ring of
``source.frame_buffers`` images (tracker.capture.live). Before asking the
source for a frame, the thread waits until the frame that used the same
buffer, ``frame_buffers`` frames back, has been *released*: processed
(the loop calls :meth:`CaptureAhead.release` after the frame it took) or superseded. No image is
overwritten while the loop reads it.

Waits: the loop's :meth:`~CaptureAhead.take` waits through the daemon's
clock in slices of at most ``slice_s`` and returns
:class:`~tracker.capture.base.Waiting` after each empty one, so the loop
ticks (and feeds the watchdog) even when the source blocks inside its own
code. The source's own Waiting items are not passed on (the loop makes its
own); they let the thread notice a stop request.

Ends: when the source ends, :meth:`take` returns None once the slot is
empty; an exception from the source ends the thread and :meth:`take` raises
it in the loop's thread, after the items before it. :meth:`stop` asks the
thread to end at the source's next item (a live source yields one at least
every tracker.capture.live.WAIT_SLICE_S); the caller closes the source after
:meth:`join`.

Thread safety: the source is iterated by the thread alone; the loop may call
the source's ``set_controls`` (picamera2 serialises controls under its own
lock; V4L2 controls go to the sensor's subdevice, not to the streaming
video node).
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable, Iterator

from tracker.capture.base import Frame, FrameError, Waiting

__all__ = ["CaptureAhead", "SLOT_ITEMS"]

# Items the slot holds for the loop: a frame, or errors before it.
SLOT_ITEMS = 4
_END = object()


class CaptureAhead:
    """The capture thread and its slot; see the module docstring.

    ``items`` is the source's iterator; ``live`` and ``frame_buffers`` come
    from the source (tracker.capture.base.FrameSource). ``wait(event,
    seconds)`` is the daemon's interruptible wait (tracker.daemon.clock).
    """

    def __init__(self, items: Iterator, *, live: bool, frame_buffers: int | None,
                 wait: Callable[[threading.Event, float], bool], slice_s: float) -> None:
        self._items = items
        self._live = bool(live)
        self._buffers = int(frame_buffers) if live and frame_buffers else None
        self._wait = wait
        self._slice_s = float(slice_s)
        self._slot: collections.deque = collections.deque()
        self._cond = threading.Condition()
        self._ready = threading.Event()      # the slot holds something for the loop
        self._stop = threading.Event()
        self._captured = 0                   # frames the source has delivered
        self._released: set[int] = set()     # their numbers, until no longer needed
        self._oldest_held = 0                # every frame before this one is released
        self._in_use: int | None = None      # the frame the loop took last
        self._error: BaseException | None = None
        self.superseded = 0
        self._thread = threading.Thread(target=self._run, name="capture", daemon=True)

    def start(self) -> CaptureAhead:
        self._thread.start()
        return self

    # -- the loop's side -----------------------------------------------------------

    def take(self) -> Frame | FrameError | Waiting | None:
        """The next item; Waiting after ``slice_s`` without one; None when the source ended.

        Raises the exception the source raised, after the items before it.
        A frame taken must be given back with :meth:`release` once processed.
        """
        if not self._ready.is_set():
            self._wait(self._ready, self._slice_s)
        with self._cond:
            if not self._slot:
                self._ready.clear()
                return Waiting(self._slice_s)
            number, item = self._slot[0]
            if item is _END:                     # stays: every later take says the same
                if self._error is not None:
                    raise self._error
                return None
            self._slot.popleft()
            if not self._slot:
                self._ready.clear()
            self._in_use = number
            self._cond.notify_all()
        return item

    def release(self) -> None:
        """The loop is done with the frame it took last: its buffer may be reused."""
        with self._cond:
            if self._in_use is not None:
                self._free(self._in_use)
                self._in_use = None

    def stop(self) -> None:
        """Ask the thread to end at the source's next item."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def join(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the thread; True if it ended."""
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    # -- the thread ----------------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                if not self._buffer_free():
                    return
                item = next(self._items, _END)
                if item is _END:
                    break
                if isinstance(item, Waiting):
                    continue
                if not self._post(item):
                    return
        except BaseException as exc:       # handed to the loop, which reopens the source
            self._error = exc
        with self._cond:
            self._slot.append((None, _END))
            self._ready.set()

    def _buffer_free(self) -> bool:
        """Wait until the next frame's buffer is free; False on a stop."""
        if self._buffers is None:
            return True
        with self._cond:
            while self._captured - self._oldest_held >= self._buffers:
                if self._stop.is_set():
                    return False
                self._cond.wait(self._slice_s)
        return True

    def _post(self, item) -> bool:
        """Put an item in the slot (superseding or waiting as the policy says); False on a stop."""
        with self._cond:
            number = None
            if isinstance(item, Frame):
                number = self._captured
                self._captured += 1
                if self._live:
                    self._supersede()
            room = SLOT_ITEMS if self._live else 1
            while len(self._slot) >= room:
                if self._stop.is_set():
                    return False
                self._cond.wait(self._slice_s)
            self._slot.append((number, item))
            self._ready.set()
        return True

    def _supersede(self) -> None:
        """Drop the frames waiting in the slot (a newer one came); errors stay."""
        kept = collections.deque()
        for number, waiting in self._slot:
            if number is None:
                kept.append((number, waiting))
            else:
                self.superseded += 1
                self._free(number)
        self._slot = kept

    def _free(self, number: int) -> None:
        """Mark a frame released; advance past every released frame (under the lock)."""
        self._released.add(number)
        while self._oldest_held in self._released:
            self._released.discard(self._oldest_held)
            self._oldest_held += 1
        self._cond.notify_all()
