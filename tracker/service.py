"""The daemon: capture -> detect -> identify -> attitude -> link, at the camera's rate.

One thread runs the loop below; nothing else touches the stages.

1. Open the link (the serial port; a failure is retried by the link itself).
2. Open the frame source (retry with doubling backoff, ``service.retry_*``,
   while it fails; the state is ``fault`` meanwhile).
3. For each item from the source: count it, ping the watchdogs, apply FC
   commands, offer STATUS to the link (sent at ``link.status_rate_hz``; a
   systemd STATUS line every ``service.status_period_s``), then, unless in
   standby, run the pipeline, update the state and the exposure, and offer
   ATTITUDE and CENTROIDS (the link applies their output rates).
4. ``READY=1`` goes to systemd after the first frame, or after the first
   failed attempt to open the camera (the unit is then up, in ``fault``,
   reporting STATUS and retrying: a camera missing at boot does not make
   systemd give up on the unit); ``STOPPING=1`` on the way out.

States (:class:`State`): ``standby`` (frames taken, not processed, until
the FC asks for a mode), ``acquiring`` (lost-in-space solving),
``tracking`` (``service.track_after`` solved frames in a row; back to
acquiring after ``service.lost_after`` unsolved), ``fault`` (no camera, or
``service.fault_after`` failed frames in a row; left on the next good frame).

Faults survived, each counted in :class:`~tracker.health.Health` and so in
STATUS: an unreadable frame (skipped), a camera timeout (skipped; the source
raises after several), a source that raises (closed, reopened with
backoff), a stage that raises (that frame dropped, loop goes on), link
failures and FC garbage (handled and counted by the link). A stalled loop
is caught twice: systemd's watchdog (``WATCHDOG=1`` is sent only from this
loop) and an in-process one (``service.watchdog_s``: faulthandler dumps
every thread's stack to stderr and exits 1, so systemd restarts the unit).

SIGTERM and SIGINT set a flag checked between frames and wake any backoff
wait, so the service stops within one frame period (plus
``capture.timeout_s`` if the camera is hung).
"""

from __future__ import annotations

import enum
import faulthandler
import gc
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from tracker.capture.base import Frame, FrameError
from tracker.capture.live import TIMEOUT_REASON
from tracker.config import Config
from tracker.exposure import ExposureControl
from tracker.health import Health
from tracker.notify import Notifier, watchdog_interval_s

__all__ = ["Service", "State", "FrameReport"]

log = logging.getLogger(__name__)

# Log at most this many tracebacks of one fault kind; later ones only count.
_LOGGED_PER_FAULT = 5


class State(enum.StrEnum):
    """Service states; see the module docstring."""

    STANDBY = "standby"
    ACQUIRING = "acquiring"
    TRACKING = "tracking"
    FAULT = "fault"


@dataclass
class FrameReport:
    """What one processed frame cost, for benchmarks: ms per stage and end to end.

    ``latency_ms`` runs from the frame leaving the source to its packets
    handed to the link; ``stages_ms`` splits it (``capture`` is the wait
    inside the source before that and is not part of the latency).
    """

    index: int
    state: State
    solved: bool
    latency_ms: float
    stages_ms: dict


class Service:
    """The loop of the module docstring, with every stage injected.

    ``source_factory()`` returns a new FrameSource (called again after the
    source fails); ``pipeline.process(image, bit_depth, t_ns)`` returns a
    :class:`~tracker.pipeline.FrameResult`; ``link`` is a
    :class:`~tracker.service_link.ServiceLink` or anything with its methods.
    ``on_frame(report)`` is called after each processed frame (benchmarks).
    """

    def __init__(self, cfg: Config, *, source_factory: Callable, pipeline, link,
                 notifier: Notifier | None = None, health: Health | None = None,
                 on_frame: Callable[[FrameReport], None] | None = None):
        self.cfg = cfg
        self.scfg = cfg.service
        self.source_factory = source_factory
        self.pipeline = pipeline
        self.link = link
        self.notifier = notifier or Notifier()
        self.health = health or Health()
        self.on_frame = on_frame
        self.exposure = ExposureControl(cfg.capture)
        self.state = State(self.scfg.start_state)
        self._wanted = State.ACQUIRING if self.state == State.STANDBY else self.state
        self._stop = threading.Event()
        self._finished = False
        self._source = None
        self._ready = False
        self._solved_run = 0
        self._missed_run = 0
        self._failed_run = 0
        self._logged: dict[str, int] = {}
        self._wd_period_ns = int(1e9 * (watchdog_interval_s() or 1.0))
        self._wd_next = 0
        self._wd_rearm_next = 0
        self._status_next = 0

    # -- control from outside ------------------------------------------------

    def request_stop(self, *_args) -> None:
        """Stop after the current frame; safe from a signal handler."""
        self._stop.set()

    def install_signal_handlers(self) -> None:
        """SIGTERM/SIGINT stop the loop (main thread only)."""
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)

    def set_mode(self, state: State, reacquire: bool = False) -> None:
        """A mode asked for by the FC: standby, or acquiring (tracking follows by itself).

        ``reacquire`` drops the solver's tracking state, so the next frame is
        solved lost in space.
        """
        if reacquire:
            self.pipeline.reset()
        self._wanted = State.STANDBY if state == State.STANDBY else State.ACQUIRING
        if self.state != State.FAULT or state == State.STANDBY:
            self._enter(self._wanted)

    def set_exposure(self, exposure_us: float | None = None, gain: float | None = None) -> None:
        """FC override of exposure and/or gain; automatic control stops."""
        self.exposure.set_manual(exposure_us, gain)
        self._apply_exposure()

    # -- the loop --------------------------------------------------------------

    def run(self) -> int:
        """Run until stopped, the source ends or ``service.frames`` are taken; 0 on a clean stop."""
        if self.scfg.watchdog_s > 0:
            faulthandler.enable()
        gc.collect()
        gc.freeze()     # start-up objects (catalogue, database) are never rescanned
        self.link.open()
        delay = self.scfg.retry_initial_s
        try:
            while not self._stop.is_set() and not self._finished:
                if self._run_source():
                    delay = self.scfg.retry_initial_s
                if self._finished or self._stop.is_set():
                    break
                self._enter(State.FAULT)
                if not self._ready:
                    self._mark_ready("no camera yet, retrying")
                self._tick()
                log.info("reopening the camera in %.2f s", delay)
                if self.scfg.watchdog_s > 0:
                    faulthandler.dump_traceback_later(self.scfg.watchdog_s + delay, exit=True)
                self._stop.wait(delay)
                delay = min(2 * delay, self.scfg.retry_max_s)
        finally:
            self.notifier.notify("STOPPING=1", "STATUS=" + self.health.summary("stopping"))
            if self.scfg.watchdog_s > 0:
                faulthandler.cancel_dump_traceback_later()
            self.link.close()
            self.link.poll(self)        # the link's final counters into health
            log.info("stopped: %s", self.health.summary(self.state.value))
        return 0

    def _run_source(self) -> bool:
        """Consume one source until it ends or fails; True if it delivered a frame.

        Only the source's own calls are guarded here (a source failing in any
        way is closed and reopened); an exception from the service's own code
        is a bug and ends the process, for systemd to restart it.
        """
        try:
            source = self.source_factory()
            iterator = iter(source)
        except Exception as exc:
            self._fault("camera_lost", f"{type(exc).__name__}: {exc}", exc)
            return False
        self._source = source
        got_frame = False
        try:
            while not self._stop.is_set():
                t0 = time.monotonic_ns()
                try:
                    item = next(iterator, None)
                except Exception as exc:
                    self._fault("camera_lost", f"{type(exc).__name__}: {exc}", exc)
                    break
                if item is None:
                    self._finished = True
                    break
                got_frame = got_frame or isinstance(item, Frame)
                self._handle(item, t0)
                if self.scfg.frames and self.health.frames >= self.scfg.frames:
                    self._finished = True
                    break
        finally:
            self._source = None
            try:
                source.close()
            except Exception as exc:    # a half-dead camera may fail to close; it is dropped
                log.warning("closing the source failed: %s", exc)
        return got_frame

    def _handle(self, item: Frame | FrameError, t0: int) -> None:
        t_avail = time.monotonic_ns()
        self.health.frames += 1
        self._tick()
        if isinstance(item, FrameError):
            kind = "camera_timeout" if item.reason.startswith(TIMEOUT_REASON) else \
                "frame_unreadable"
            self._fault(kind, item.reason)
            self._failed()
            return
        if not self._ready:
            self._mark_ready(f"first frame {item.name}")
        if self.state == State.STANDBY:
            return
        self._process(item, t_avail, (t_avail - t0) / 1e6)

    def _process(self, frame: Frame, t_avail: int, capture_ms: float) -> None:
        try:
            result = self.pipeline.process(frame.image, frame.bit_depth, frame.t_ns)
        except Exception as exc:    # a stage that raises loses this frame only
            self._fault("stage_error", f"{frame.name}: {type(exc).__name__}: {exc}", exc)
            self._failed()
            return
        t_done = time.monotonic_ns()
        self._failed_run = 0
        if self.state == State.FAULT:
            self._enter(self._wanted)
        solution = result.solution
        solved = bool(solution is not None and getattr(solution, "ok", False))
        self._update_state(solved, result.detections.count)
        if self.exposure.update(result.detections, frame.bit_depth):
            self._apply_exposure()
        t_ctl = time.monotonic_ns()
        self.link.send_frame(frame, result, self.state)
        t_end = time.monotonic_ns()
        latency = (t_end - t_avail) / 1e6
        self.health.processed += 1
        self.health.frame_done(latency)
        if self.on_frame is not None:
            stages = {"capture": capture_ms, **result.stages_ms,
                      "pipeline": (t_done - t_avail) / 1e6, "control": (t_ctl - t_done) / 1e6,
                      "link": (t_end - t_ctl) / 1e6}
            self.on_frame(FrameReport(frame.index, self.state, solved, latency, stages))

    # -- state ---------------------------------------------------------------

    def _enter(self, state: State) -> None:
        if state != self.state:
            log.info("state %s -> %s", self.state.value, state.value)
            self.state = state
            self._solved_run = self._missed_run = 0

    def _mark_ready(self, why: str) -> None:
        link = "link open" if self.link.is_open else "link not open yet"
        self.notifier.notify("READY=1", "STATUS=" + self.health.summary(self.state.value))
        self._ready = True
        log.info("ready: %s, %s", why, link)

    def _update_state(self, solved: bool, n_stars: int) -> None:
        if solved:
            self.health.solved += 1
            self._solved_run += 1
            self._missed_run = 0
            if self.state == State.ACQUIRING and self._solved_run >= self.scfg.track_after:
                self._enter(State.TRACKING)
        else:
            if n_stars:
                self.health.solve_failures += 1
            self._missed_run += 1
            self._solved_run = 0
            if self.state == State.TRACKING and self._missed_run >= self.scfg.lost_after:
                self._enter(State.ACQUIRING)

    def _failed(self) -> None:
        self._failed_run += 1
        if self._failed_run >= self.scfg.fault_after and self.state != State.STANDBY:
            self._enter(State.FAULT)

    def _fault(self, kind: str, text: str, exc: BaseException | None = None) -> None:
        self.health.fault(kind, text)
        n = self._logged[kind] = self._logged.get(kind, 0) + 1
        if n <= _LOGGED_PER_FAULT:
            log.warning("%s: %s", kind, text, exc_info=exc if n == 1 else None)
            if n == _LOGGED_PER_FAULT:
                log.warning("%s: further ones are only counted (STATUS)", kind)

    def _apply_exposure(self) -> None:
        setter = getattr(self._source, "set_controls", None)
        if setter is None or not setter(self.exposure.exposure_us, self.exposure.gain):
            self.exposure.auto = False      # this source cannot change them: stop trying

    # -- periodic work -------------------------------------------------------

    def _tick(self) -> None:
        """Watchdogs, link I/O and STATUS; called once per frame and while backing off."""
        now = time.monotonic_ns()
        if now >= self._wd_next:
            self.notifier.notify("WATCHDOG=1")
            self._wd_next = now + self._wd_period_ns
        if self.scfg.watchdog_s > 0 and now >= self._wd_rearm_next:
            faulthandler.dump_traceback_later(self.scfg.watchdog_s, exit=True)
            self._wd_rearm_next = now + 1_000_000_000
        self.link.poll(self)
        if now >= self._status_next:
            self._status_next = now + int(self.scfg.status_period_s * 1e9)
            self.link.send_status(self)
            self.notifier.notify("STATUS=" + self.health.summary(self.state.value))
