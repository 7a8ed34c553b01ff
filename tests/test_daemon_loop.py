"""The frame loop with small fake stages: modes, faults survived and counted, stopping."""

import threading

import pytest
from daemon_fakes import (
    RAISE,
    SOLVED,
    UNSOLVED,
    FakeLink,
    FakePipeline,
    FakeSource,
    NotifyListener,
    VirtualClock,
    config,
    frame,
)

from tracker.capture.base import FrameError, Waiting
from tracker.capture.live import CameraError
from tracker.daemon import Daemon
from tracker.daemon.commands import Commands
from tracker.daemon.notify import Notifier
from tracker.protocol.messages import ErrorCode, Mode


def make_daemon(scripts, clock=None, **service_keys):
    """A daemon over fake stages; ``scripts`` is one list of items per source opened."""
    tags = {i.t_ns: i.name for script in scripts for i in script
            if hasattr(i, "t_ns")}
    sources = []

    def factory():
        if not scripts:
            raise CameraError("no camera")
        sources.append(FakeSource(scripts.pop(0)))
        return sources[-1]

    daemon = Daemon(config(**service_keys), source_factory=factory,
                    pipeline=FakePipeline(tags), link=FakeLink(clock),
                    notifier=Notifier(""), clock=clock)
    return daemon, sources


def test_lost_in_space_becomes_tracking_and_falls_back_when_lost():
    script = [frame(i, SOLVED) for i in range(3)] + [frame(i, UNSOLVED) for i in range(3, 6)]
    daemon, _ = make_daemon([script])
    modes = []
    daemon.on_frame = lambda report: modes.append(report.mode)
    assert daemon.run() == 0
    assert modes == [Mode.LOST_IN_SPACE, Mode.TRACKING, Mode.TRACKING, Mode.TRACKING,
                     Mode.TRACKING, Mode.LOST_IN_SPACE]
    assert (daemon.health.solved, daemon.health.solve_failures) == (3, 3)
    assert daemon.link.sent[1] == (1, Mode.TRACKING, True) and daemon.link.closed


def test_a_stage_that_raises_drops_only_that_frame():
    script = [frame(0), frame(1, RAISE), frame(2), frame(3, RAISE), frame(4)]
    daemon, _ = make_daemon([script])
    daemon.run()
    assert daemon.health.faults[ErrorCode.STAGE_ERROR] == 2
    assert daemon.health.processed == 3 and daemon.health.frames == 5
    assert [i for i, _, _ in daemon.link.sent] == [0, 2, 4]
    assert daemon.health.last_error == ErrorCode.STAGE_ERROR


def test_unreadable_frames_and_timeouts_are_counted_apart():
    script = [FrameError(0, "a.png", "a.png: truncated PNG (no IEND chunk)"), frame(1),
              FrameError(2, "picamera2", "no frame within 2 s"), frame(3)]
    daemon, _ = make_daemon([script])
    daemon.run()
    assert daemon.health.faults[ErrorCode.FRAME_UNREADABLE] == 1
    assert daemon.health.faults[ErrorCode.CAMERA_TIMEOUT] == 1
    assert daemon.health.capture_faults == 2 and daemon.health.processed == 2


def test_a_source_that_raises_is_reopened_and_the_loop_resumes():
    first = [frame(0), frame(1), OSError("camera unplugged")]
    daemon, sources = make_daemon([first, [CameraError("gone")], [frame(2), frame(3)]])
    daemon.run()     # the last source ends (as replay does), which ends the run
    assert daemon.health.faults[ErrorCode.CAMERA_LOST] == 2
    assert len(sources) == 3 and all(s.closed for s in sources)
    assert [i for i, _, _ in daemon.link.sent] == [0, 1, 2, 3]


def test_consecutive_failures_enter_fault_and_a_good_frame_leaves_it():
    script = [frame(i, RAISE) for i in range(3)] + [frame(3)]
    daemon, _ = make_daemon([script], fault_after=3)
    seen = []
    daemon.link.publish = lambda snapshot: seen.append(Mode(snapshot.mode))
    daemon.run()
    assert seen[-1] == Mode.FAULT                 # ticked before the good frame
    assert daemon.mode == Mode.LOST_IN_SPACE


def test_standby_sends_attitude_without_solving_until_the_fc_asks():
    """Item 6: STANDBY takes frames and sends ATTITUDE (VALID clear), does not solve."""
    script = [frame(i) for i in range(4)]
    daemon, _ = make_daemon([script], start_state="standby")
    daemon.link.pending = [None, None, Commands(mode=Mode.TRACKING)]
    daemon.run()
    assert daemon.link.sent == [(0, Mode.STANDBY, None), (1, Mode.STANDBY, None),
                                (2, Mode.LOST_IN_SPACE, True), (3, Mode.TRACKING, True)]
    assert daemon.pipeline.seen == [2, 3]


def test_commands_apply_in_order_as_one_value():
    daemon, _ = make_daemon([[frame(i) for i in range(3)]])
    daemon.link.pending = [Commands(mode=Mode.STANDBY, reacquire=True, exposure_us=5.0,
                                    gain=99.0)]
    daemon.run()
    assert daemon.pipeline.resets == 1 and daemon.mode == Mode.STANDBY
    # clamped to the configured limits (item 9)
    cap = daemon.cfg.capture
    assert (daemon.exposure.exposure_us, daemon.exposure.gain) == (cap.exposure_min_us,
                                                                   cap.gain_max)


def test_frames_limit_and_request_stop():
    daemon, _ = make_daemon([[frame(i) for i in range(10)]], frames=4)
    daemon.run()
    assert daemon.health.frames == 4
    daemon, _ = make_daemon([[frame(i) for i in range(10)]])
    daemon.on_frame = lambda report: report.index == 2 and daemon.request_stop()
    daemon.run()
    assert daemon.health.processed == 3


def test_exposure_changes_reach_the_source():
    """Peaks at 0.5 full scale with target 0.25: the controller halves the light."""
    import dataclasses

    daemon, sources = make_daemon([[frame(i) for i in range(2)]])
    daemon.exposure.cfg = dataclasses.replace(daemon.cfg.capture, target_peak=0.25)
    daemon.run()
    gain0 = daemon.cfg.capture.gain
    assert sources[0].controls == [(daemon.cfg.capture.exposure_us, gain0 * 0.5)]


def test_a_link_thread_that_died_stops_the_loop_with_status_1():
    """Item 3: a deaf service must not run on (or exit 0, invisible to systemd)."""
    daemon, _ = make_daemon([[frame(i) for i in range(100)]])

    def on_frame(report):
        if report.index == 5:
            daemon.link.failure = "link-reader: RuntimeError: boom"

    daemon.on_frame = on_frame
    assert daemon.run() == 1
    assert daemon.health.processed == 6
    assert daemon.link_failure.startswith("link-reader")


def test_a_bug_outside_the_stages_is_not_swallowed():
    """Only sources and stages are guarded; anything else ends run() for systemd."""
    daemon, _ = make_daemon([[frame(0), frame(1)]])

    def broken(*args):
        raise KeyError("bug")

    daemon.link.send_frame = broken
    with pytest.raises(KeyError, match="bug"):
        daemon.run()
    assert daemon.link.closed


def test_early_status_is_complete_and_reports_the_fault():
    """A STATUS snapshot exists before the first frame (item 3's early REQUEST_STATUS)."""
    clock = VirtualClock()
    daemon, _ = make_daemon([], clock=clock)
    daemon.on_frame = None
    calls = []

    def factory():
        calls.append(1)
        if len(calls) >= 3:
            daemon.request_stop()
        raise CameraError("no camera 0")

    daemon.source_factory = factory
    assert daemon.run() == 0
    first = daemon.link.statuses()[0][1]
    assert first["frames"] == 0 and first["mode"] == Mode.LOST_IN_SPACE
    last = daemon.link.statuses()[-1][1]
    assert last["mode"] == Mode.FAULT and last["last_error"] == ErrorCode.CAMERA_LOST


# ---- the watchdog: item 1 and the "camera absent for 60 s" acceptance -----------------


@pytest.fixture(name="systemd")
def fixture_systemd(tmp_path, monkeypatch):
    """NOTIFY_SOCKET, WATCHDOG_USEC = 5 s (WatchdogSec=5) and a virtual clock."""
    import os

    clock = VirtualClock()
    listener = NotifyListener(tmp_path / "notify", clock)
    monkeypatch.setenv("NOTIFY_SOCKET", listener.path)
    monkeypatch.setenv("WATCHDOG_USEC", "5000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    yield clock, listener
    listener.close()


def _gaps_s(times):
    return [(b - a) / 1e9 for a, b in zip(times, times[1:], strict=False)]


def test_camera_absent_60_s_then_present_under_a_5_s_watchdog(systemd):
    """No watchdog miss, FAULT and CAMERA_LOST in STATUS, solving within 2 s of its return."""
    clock, listener = systemd
    t_start = clock.now_ns()
    t_back = t_start + 60 * 10**9
    opens = []

    def next_frame(k):
        def step():
            clock.advance(0.1)                 # 10 fps
            return frame(k, SOLVED, t_ns=clock.now_ns())
        return step

    def factory():
        opens.append(clock.now_ns())
        clock.advance(0.05)                    # an open attempt takes a little time
        if clock.now_ns() < t_back:
            raise CameraError("no camera 0 (absent)")
        return FakeSource([next_frame(k) for k in range(30)])

    daemon = Daemon(config(retry_initial_s=0.5, retry_max_s=1.0), source_factory=factory,
                    pipeline=FakePipeline(), link=FakeLink(clock), clock=clock)
    solved_at = []
    daemon.on_frame = lambda r: r.solved and solved_at.append(clock.now_ns())
    assert daemon.run() == 0
    pings = listener.times_of("WATCHDOG=1")
    assert pings[0] - t_start < 10**9 and clock.now_ns() - pings[-1] < 3 * 10**9
    assert max(_gaps_s(pings)) <= 2.5 + 0.3      # WatchdogSec/2 + one tick; systemd's is 5
    assert len(opens) >= 55                        # retried about every second
    assert listener.times_of("READY=1")[0] - t_start < 10**9   # READY although no camera
    during = [s for t, s in daemon.link.statuses() if t_start + 2 * 10**9 < t < t_back]
    assert during and all(s["mode"] == Mode.FAULT for s in during)
    assert all(s["last_error"] == ErrorCode.CAMERA_LOST for s in during)
    assert (solved_at[0] - t_back) / 1e9 < 2.0
    assert daemon.link.statuses()[-1][1]["mode"] == Mode.TRACKING
    print(f"camera absent 60 s: {len(pings)} WATCHDOG=1, largest gap {max(_gaps_s(pings)):.2f} s"
          f", first solve {(solved_at[0] - t_back) / 1e9:.2f} s after the camera came back")


def test_slow_frames_keep_the_watchdog_fed(systemd):
    """Item 1: at capture.fps 0.15 (a frame every 6.7 s) pings stay under 2.8 s apart."""
    clock, listener = systemd
    period = 1 / 0.15

    def waiting_then_frame(k):
        script = []
        for _ in range(int(period / 0.25)):
            script.append(lambda: (clock.advance(0.25), Waiting(0.25))[1])
        script.append(lambda k=k: frame(k, SOLVED, t_ns=clock.now_ns()))
        return script

    script = [item for k in range(6) for item in waiting_then_frame(k)]
    daemon = Daemon(config(), source_factory=lambda: FakeSource(script),
                    pipeline=FakePipeline(), link=FakeLink(clock), clock=clock)
    assert daemon.run() == 0
    pings = listener.times_of("WATCHDOG=1")
    assert daemon.health.processed == 6 and len(pings) > 12
    assert max(_gaps_s(pings)) <= 2.5 + 0.3
    print(f"frames every 6.7 s: largest WATCHDOG=1 gap {max(_gaps_s(pings)):.2f} s")


def test_a_camera_stuck_in_its_own_code_keeps_the_watchdog_fed(systemd):
    """Capture ahead: the loop ticks while the source blocks 60 s without yielding Waiting."""
    clock, listener = systemd
    t_start = clock.now_ns()
    released = threading.Event()
    clock.before_advance.append(
        lambda: clock.now_ns() - t_start >= 60 * 10**9 and released.set())

    class StuckCamera(FakeSource):
        live = True

    def frames():
        yield frame(0, SOLVED, t_ns=clock.now_ns())
        released.wait()                       # a driver call that does not return for 60 s
        for k in range(1, 4):
            yield frame(k, SOLVED, t_ns=clock.now_ns())

    daemon = Daemon(config(), source_factory=lambda: StuckCamera(frames()),
                    pipeline=FakePipeline(), link=FakeLink(clock), clock=clock)
    assert daemon.run() == 0
    pings = listener.times_of("WATCHDOG=1")
    assert clock.now_ns() - t_start >= 60 * 10**9
    assert max(_gaps_s(pings)) <= 2.5 + 0.3 and len(pings) >= 24
    assert daemon.health.processed >= 2       # frames after it came back (the newest wins)
    print(f"camera stuck 60 s in its own code: {len(pings)} WATCHDOG=1, largest gap "
          f"{max(_gaps_s(pings)):.2f} s")


def test_no_watchdog_ping_once_the_link_is_dead(systemd):
    """WATCHDOG=1 flows only while the loop is healthy."""
    clock, listener = systemd

    def tick_frames():
        for k in range(40):
            clock.advance(0.5)
            yield frame(k, SOLVED, t_ns=clock.now_ns())

    daemon = Daemon(config(), source_factory=lambda: FakeSource(list(tick_frames())),
                    pipeline=FakePipeline(), link=FakeLink(clock), clock=clock)
    dead_at = []

    def on_frame(report):
        if report.index == 10:
            daemon.link.failure = "link-writer ended"
            dead_at.append(clock.now_ns())

    daemon.on_frame = on_frame
    assert daemon.run() == 1
    assert all(t <= dead_at[0] for t in listener.times_of("WATCHDOG=1"))


def test_the_loop_does_not_accumulate_memory():
    """Python allocations still held after 3000 frames vs after 300: under 64 KiB.

    The fakes allocate per frame too (a FrameResult), so this bounds what the
    loop keeps, not what it touches; 64 KiB is ~20 bytes per frame, far below
    any per-frame leak of a dict or a list entry (>= 56 bytes each).
    """
    import tracemalloc

    daemon, _ = make_daemon([[frame(i) for i in range(3300)]])
    daemon.link.send_frame = lambda *a: None
    daemon.link.publish = lambda snapshot: None
    marks = {}

    def on_frame(report):
        if report.index in (300, 3299):
            marks[report.index] = tracemalloc.get_traced_memory()[0]

    daemon.on_frame = on_frame
    tracemalloc.start()
    try:
        daemon.run()
    finally:
        tracemalloc.stop()
    assert marks[3299] - marks[300] < 64 * 1024


def test_watchdog_interval_is_half_of_systemds_for_this_process(monkeypatch):
    import os

    from tracker.daemon.notify import watchdog_interval_s

    monkeypatch.setenv("WATCHDOG_USEC", "5000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert watchdog_interval_s() == 2.5
    monkeypatch.setenv("WATCHDOG_PID", "1")           # meant for another process
    assert watchdog_interval_s() is None


@pytest.mark.parametrize("address, expected", [("@tracker-test", "\0tracker-test"),
                                               ("/run/x", "/run/x"), ("", None)])
def test_notifier_address_forms(address, expected):
    n = Notifier(address)
    assert n.enabled == (expected is not None)
    if expected is not None:
        assert n._addr == expected
    n.notify("READY=1")      # nobody listening: logged once, never raises
    n.close()
