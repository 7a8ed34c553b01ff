"""Capture running ahead of processing (tracker.daemon.capture_ahead): order, buffers, ends."""

import threading

import numpy as np
import pytest
from daemon_fakes import SOLVED, UNSOLVED, FakeLink, FakePipeline, FakeSource, config, frame

from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.live import CameraError
from tracker.daemon import Daemon
from tracker.daemon.capture_ahead import CaptureAhead
from tracker.daemon.notify import Notifier

SLICE_S = 0.05


def real_wait(event, seconds):
    return event.wait(seconds)


def take_all(ahead):
    """Every item up to the end (None), skipping Waiting; releases each frame."""
    out = []
    while True:
        item = ahead.take()
        if item is None:
            return out
        if not isinstance(item, Waiting):
            out.append(item)
            ahead.release()


def test_a_replay_source_gives_every_item_in_order_then_ends():
    items = [frame(0), FrameError(1, "b.png", "truncated"), Waiting(0.25), frame(2), frame(3)]
    ahead = CaptureAhead(iter(items), live=False, frame_buffers=None, wait=real_wait,
                         slice_s=SLICE_S).start()
    got = take_all(ahead)
    assert [(type(i).__name__, i.index) for i in got] == [
        ("Frame", 0), ("FrameError", 1), ("Frame", 2), ("Frame", 3)]
    assert ahead.take() is None and ahead.superseded == 0    # the end is sticky
    assert ahead.join(5.0)


def test_the_source_error_reaches_the_loop_after_the_items_before_it():
    def source():
        yield frame(0)
        yield frame(1)
        raise CameraError("camera unplugged")

    ahead = CaptureAhead(source(), live=True, frame_buffers=3, wait=real_wait,
                         slice_s=SLICE_S).start()
    with pytest.raises(CameraError, match="unplugged"):
        while True:
            if not isinstance(ahead.take(), Waiting):
                ahead.release()
    assert ahead.join(5.0)


class RingCamera:
    """A live source writing frame k (every pixel = k) into a ring of three images.

    ``asked`` counts the frames requested; frame k is delivered only once
    ``allow`` permits k + 1 frames, so the test decides how far it runs ahead.
    """

    live = True
    frame_buffers = 3

    def __init__(self, frames):
        self.ring = [np.zeros((4, 4), np.uint16) for _ in range(self.frame_buffers)]
        self.frames = frames
        self.asked = 0
        self.allowed = threading.Semaphore(0)

    def __iter__(self):
        for k in range(self.frames):
            self.asked += 1
            self.allowed.acquire()
            image = self.ring[k % self.frame_buffers]
            image.fill(k)
            yield Frame(k, f"f{k}", image, 10, k)


def test_live_frames_newest_wins_and_no_image_is_overwritten_while_processed():
    cam = RingCamera(8)
    ahead = CaptureAhead(iter(cam), live=True, frame_buffers=cam.frame_buffers,
                         wait=real_wait, slice_s=SLICE_S).start()
    cam.allowed.release()
    first = ahead.take()
    while isinstance(first, Waiting):
        first = ahead.take()
    assert first.index == 0
    for _ in range(7):
        cam.allowed.release()      # the camera would run on; only two buffers are free
    while ahead.superseded < 1:    # frame 2 replaced frame 1 in the slot
        threading.Event().wait(0.01)
    assert cam.asked == 3          # frame 3 would reuse frame 0's image: not asked for
    assert np.all(first.image == 0)
    ahead.release()                # frame 0 processed: its image may be reused
    later = take_all(ahead)
    assert later[0].index == 2     # the newest, not the superseded frame 1
    indices = [f.index for f in later]
    assert indices == sorted(indices) and indices[-1] == 7
    assert len(later) + ahead.superseded == 7


def test_stop_ends_the_thread_when_the_loop_takes_nothing_more():
    cam = RingCamera(100)
    cam.allowed.release()
    ahead = CaptureAhead(iter(cam), live=True, frame_buffers=3, wait=real_wait,
                         slice_s=SLICE_S).start()
    item = ahead.take()
    while isinstance(item, Waiting):
        item = ahead.take()
    for _ in range(99):
        cam.allowed.release()
    ahead.stop()                   # frame 0 never released: the thread waits for a buffer
    assert ahead.join(5.0)
    assert cam.asked <= 3


@pytest.mark.parametrize("policy", ["always", "never"])
def test_the_loop_solves_the_same_frames_with_capture_ahead_or_without(policy):
    """Replay is never superseded: the loop sees the same frames, in the same order."""
    script = ([frame(i, SOLVED) for i in range(4)] + [FrameError(4, "x.png", "truncated")]
              + [frame(i, UNSOLVED) for i in range(5, 9)] + [frame(i) for i in range(9, 12)])
    tags = {i.t_ns: i.name for i in script if hasattr(i, "t_ns")}
    daemon = Daemon(config(capture_ahead=policy), source_factory=lambda: FakeSource(script),
                    pipeline=FakePipeline(tags), link=FakeLink(), notifier=Notifier(""))
    modes = []
    daemon.on_frame = lambda report: modes.append((report.index, report.mode, report.solved))
    assert daemon.run() == 0
    assert daemon.pipeline.seen == [i.t_ns for i in script if hasattr(i, "t_ns")]
    assert daemon.health.frames == 12 and daemon.health.capture_faults == 1
    assert daemon.health.superseded == 0
    assert [m for _, m, _ in modes][-1] == daemon.mode
    assert sum(solved for _, _, solved in modes) == 7
