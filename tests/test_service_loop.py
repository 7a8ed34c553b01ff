"""The service loop with small fake stages: states, faults survived and counted, stopping."""

import dataclasses
import socket
from types import SimpleNamespace

import numpy as np
import pytest

from tracker.capture.base import Frame, FrameError
from tracker.capture.live import CameraError
from tracker.config import Config, ServiceConfig
from tracker.detect import STAR_DTYPE, Detections
from tracker.health import FAULTS
from tracker.notify import Notifier
from tracker.pipeline import FrameResult
from tracker.service import Service, State

SOLVED, UNSOLVED, RAISE = "solved", "unsolved", "raise"


def frame(i, tag=SOLVED):
    return Frame(i, tag, np.zeros((4, 4), np.uint16), 10, i)


class FakeSource:
    """Yields a script; an exception instance in it is raised from the iterator."""

    def __init__(self, script):
        self.script = script
        self.closed = False
        self.controls = []

    def __iter__(self):
        for item in self.script:
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


class FakePipeline:
    """Solves frames tagged 'solved', fails 'unsolved', raises on 'raise'.

    The pipeline sees only pixels and time, so ``tags`` maps t_ns -> tag.
    """

    def __init__(self, tags):
        self.tags = tags

    def process(self, image, bit_depth, t_ns):
        tag = self.tags[t_ns]
        if tag == RAISE:
            raise ValueError("boom")
        stars = np.zeros(5, STAR_DTYPE)
        stars["peak"] = 0.5 * 1023
        sol = SimpleNamespace(ok=tag == SOLVED)
        return FrameResult(Detections(stars), sol, 1.0, {"detect.x": 0.5})


class FakeLink:
    def __init__(self):
        self.is_open = False
        self.sent = []
        self.status = 0
        self.closed = False

    def open(self):
        self.is_open = True

    def close(self):
        self.closed = True

    def poll(self, service):
        pass

    def send_frame(self, frame, result, state):
        self.sent.append((frame.index, state))

    def send_status(self, service):
        self.status += 1


def make_service(scripts, **service_keys):
    """A service over fake stages; ``scripts`` is one list of items per source opened."""
    keys = {"retry_initial_s": 0.001, "retry_max_s": 0.002, "watchdog_s": 0.0,
            **service_keys}
    cfg = dataclasses.replace(Config(), service=dataclasses.replace(ServiceConfig(), **keys))
    tags = {i.t_ns: i.name for script in scripts for i in script if isinstance(i, Frame)}
    sources = []

    def factory():
        if not scripts:
            raise CameraError("no camera")
        sources.append(FakeSource(scripts.pop(0)))
        return sources[-1]

    svc = Service(cfg, source_factory=factory, pipeline=FakePipeline(tags), link=FakeLink(),
                  notifier=Notifier(""))
    return svc, sources


def test_acquiring_becomes_tracking_and_falls_back_when_lost():
    script = [frame(i, SOLVED) for i in range(3)] + [frame(i, UNSOLVED) for i in range(3, 6)]
    svc, _ = make_service([script])
    states = []
    svc.on_frame = lambda report: states.append(report.state)
    assert svc.run() == 0
    assert states == [State.ACQUIRING, State.TRACKING, State.TRACKING, State.TRACKING,
                      State.TRACKING, State.ACQUIRING]
    assert (svc.health.solved, svc.health.solve_failures) == (3, 3)
    assert svc.link.sent[1] == (1, State.TRACKING) and svc.link.closed


def test_a_stage_that_raises_drops_only_that_frame():
    script = [frame(0), frame(1, RAISE), frame(2), frame(3, RAISE), frame(4)]
    svc, _ = make_service([script])
    svc.run()
    assert svc.health.faults["stage_error"] == 2
    assert svc.health.processed == 3 and svc.health.frames == 5
    assert [i for i, _ in svc.link.sent] == [0, 2, 4]
    assert svc.health.last_error == FAULTS["stage_error"]


def test_unreadable_frames_and_timeouts_are_counted_apart():
    script = [FrameError(0, "a.png", "a.png: truncated PNG (no IEND chunk)"), frame(1),
              FrameError(2, "picamera2", "no frame within 2 s"), frame(3)]
    svc, _ = make_service([script])
    svc.run()
    assert svc.health.faults["frame_unreadable"] == 1
    assert svc.health.faults["camera_timeout"] == 1
    assert svc.health.capture_faults == 2 and svc.health.processed == 2


def test_a_source_that_raises_is_reopened_and_the_loop_resumes():
    first = [frame(0), frame(1), OSError("camera unplugged")]
    svc, sources = make_service([first, [CameraError("gone")], [frame(2), frame(3)]])
    svc.run()     # the last source ends (as replay does), which ends the run
    assert svc.health.faults["camera_lost"] == 2
    assert len(sources) == 3 and all(s.closed for s in sources)
    assert [i for i, _ in svc.link.sent] == [0, 1, 2, 3]


def test_camera_absent_at_start_is_retried_until_stopped():
    svc, _ = make_service([])
    calls = []
    svc.source_factory = lambda: (calls.append(1), len(calls) < 5 or svc.request_stop(),
                                  (_ for _ in ()).throw(CameraError("no camera 0")))[2]
    assert svc.run() == 0
    assert svc.health.faults["camera_lost"] == 5 and svc.state == State.FAULT


def test_consecutive_failures_enter_fault_and_a_good_frame_leaves_it():
    script = [frame(i, RAISE) for i in range(3)] + [frame(3)]
    svc, _ = make_service([script], fault_after=3)
    states = []
    original = svc._enter
    svc._enter = lambda s: (states.append(s), original(s))
    svc.run()
    assert states[:2] == [State.FAULT, State.ACQUIRING]


def test_standby_takes_frames_without_processing_until_the_fc_asks():
    script = [frame(i) for i in range(4)]
    svc, _ = make_service([script], start_state="standby")
    seen = []

    def poll(service):
        seen.append(service.health.frames)
        if service.health.frames == 2:
            service.set_mode(State.ACQUIRING)

    svc.link.poll = poll
    svc.run()
    assert [i for i, _ in svc.link.sent] == [1, 2, 3]   # applied before frame 1 is processed


def test_frames_limit_and_request_stop():
    svc, _ = make_service([[frame(i) for i in range(10)]], frames=4)
    svc.run()
    assert svc.health.frames == 4
    svc, _ = make_service([[frame(i) for i in range(10)]])
    svc.on_frame = lambda report: report.index == 2 and svc.request_stop()
    svc.run()
    assert svc.health.processed == 3


def test_exposure_changes_reach_the_source():
    """Peaks at 0.5 full scale with target 0.25: the controller halves the light."""
    svc, sources = make_service([[frame(i) for i in range(2)]])
    svc.cfg = dataclasses.replace(svc.cfg, capture=dataclasses.replace(svc.cfg.capture,
                                                                       target_peak=0.25))
    svc.exposure.cfg = svc.cfg.capture
    svc.run()
    gain0 = svc.cfg.capture.gain
    assert sources[0].controls == [(svc.cfg.capture.exposure_us, gain0 * 0.5)]


def test_systemd_notifications(tmp_path):
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(1.0)
    svc, _ = make_service([[frame(0), frame(1)]])
    svc.notifier = Notifier(str(tmp_path / "notify"))
    svc.run()
    messages = []
    listener.setblocking(False)
    while True:
        try:
            messages.append(listener.recv(4096).decode())
        except BlockingIOError:
            break
    assert messages[0] == "WATCHDOG=1"
    assert messages[1].startswith("STATUS=acquiring: 0 frames")
    assert messages[2].startswith("READY=1\nSTATUS=")
    assert messages[-1].startswith("STOPPING=1\nSTATUS=stopping: 2 frames, 2 solved")


@pytest.mark.parametrize("address, expected", [("@tracker-test", "\0tracker-test"),
                                               ("/run/x", "/run/x"), ("", None)])
def test_notifier_address_forms(address, expected):
    n = Notifier(address)
    assert n.enabled == (expected is not None)
    if expected is not None:
        assert n._addr == expected
    n.notify("READY=1")      # nobody listening: logged once, never raises
    n.close()


def test_the_loop_does_not_accumulate_memory():
    """Python allocations still held after 3000 frames vs after 300: under 64 KiB.

    The fakes allocate per frame too (a FrameResult), so this bounds what the
    loop keeps, not what it touches; 64 KiB is ~20 bytes per frame, far below
    any per-frame leak of a dict or a list entry (>= 56 bytes each).
    """
    import tracemalloc

    svc, _ = make_service([[frame(i) for i in range(3300)]])
    svc.link.send_frame = lambda *a: None
    marks = {}

    def on_frame(report):
        if report.index in (300, 3299):
            marks[report.index] = tracemalloc.get_traced_memory()[0]

    svc.on_frame = on_frame
    tracemalloc.start()
    try:
        svc.run()
    finally:
        tracemalloc.stop()
    assert marks[3299] - marks[300] < 64 * 1024


def test_a_bug_outside_the_stages_is_not_swallowed():
    """Only sources and stages are guarded; anything else ends run() for systemd."""
    svc, _ = make_service([[frame(0), frame(1)]])

    def broken(*args):
        raise KeyError("bug")

    svc.link.send_frame = broken
    with pytest.raises(KeyError, match="bug"):
        svc.run()
    assert svc.link.closed


def test_watchdog_interval_is_half_of_systemds_for_this_process(monkeypatch):
    import os

    from tracker.notify import watchdog_interval_s

    monkeypatch.setenv("WATCHDOG_USEC", "5000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert watchdog_interval_s() == 2.5
    monkeypatch.setenv("WATCHDOG_PID", "1")           # meant for another process
    assert watchdog_interval_s() is None
