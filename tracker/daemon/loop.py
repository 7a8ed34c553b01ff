"""The frame loop: capture -> detect -> identify -> attitude -> link, at the camera's rate.

One thread runs :meth:`Daemon.run`; nothing else touches the stages. With a
live camera (``service.capture_ahead``) a second thread captures frame N+1
while the loop processes frame N (:mod:`tracker.daemon.capture_ahead`): the
loop starts each frame on the newest one captured, so a frame costs the
longer of its capture and its processing and waits for at most one frame's
processing before its own.

1. Publish a first STATUS (so an early REQUEST_STATUS is answered), open
   the link (a port that fails is retried by the link itself).
2. Open the frame source. While it fails, wait ``service.retry_initial_s``
   doubling up to ``service.retry_max_s`` between attempts, mode FAULT.
3. Take items from the source (or from the capture thread, which returns
   Waiting after every :data:`~tracker.capture.live.WAIT_SLICE_S` without
   one, even when the source is stuck in its own code). Every item (a
   frame, a lost frame, or :class:`~tracker.capture.base.Waiting` from a
   live source that has no frame yet) first runs a *tick*; a frame then
   runs the *processing step*. Backoff waits are cut into ticks of at most
   :data:`~tracker.capture.live.WAIT_SLICE_S` as well.
4. ``READY=1`` goes to systemd after the first frame, or after the first
   failed attempt to open the camera (the unit is then up, in FAULT,
   reporting STATUS and retrying: a camera missing at boot does not make
   systemd give up on the unit); ``STOPPING=1`` on the way out.

A tick: check the link's threads (one that ended stops the loop: exit
status 1, for systemd to restart a unit that would otherwise be deaf), send
``WATCHDOG=1`` when due (:class:`~tracker.daemon.notify.Watchdog`; only
ticks send it, so a stuck loop starves it), re-arm the in-process stall
watchdog, apply the FC's commands (taken as one value from the link),
mirror the link's counters, and publish a new STATUS snapshot (sent at
``link.status_rate_hz``; a systemd STATUS line every
``service.status_period_s``).

The processing step (:meth:`Daemon.process`): count the frame; give it its
observer context (absolute time and velocity: :mod:`tracker.daemon.timebase`,
which TIME_SYNC and SET_VELOCITY feed); in STANDBY send ATTITUDE with VALID
clear; otherwise run the pipeline, update the mode
(:mod:`tracker.daemon.modes`) and the exposure, and send ATTITUDE and
CENTROIDS (the link applies their output rates). Capture and processing are
separate steps, which is what lets them overlap without changing either.

Latency: ``FrameReport.latency_ms`` runs from the frame leaving the source
to its packets handed to the link; the link measures the whole of it, from
a live frame's exposure mid-point (a replayed frame's reading) to the last
byte of its ATTITUDE on the wire, and drops an ATTITUDE that would go out
more than ``link.max_age_ms`` after that (tracker.protocol.link), which
bounds it.

Faults survived, each counted in :class:`~tracker.daemon.health.Health`
under its ErrorCode and so in STATUS: an unreadable frame (skipped), a late
frame (skipped; the source raises after several), a source that raises
(closed, reopened with backoff), a stage that raises (that frame dropped,
loop goes on), link failures and FC garbage (handled and counted by the
link). A stalled loop is caught twice: systemd's watchdog and an in-process
one (``service.watchdog_s``: faulthandler dumps every thread's stack to
stderr and exits 1, so systemd restarts the unit).

SIGTERM and SIGINT set a flag checked on every tick, so the service stops
within one tick (plus the time to close a hung camera).

Memory: the loop's own state is fixed at start; per frame it makes short-
lived objects only (the pipeline's result, encoded packets, one STATUS
snapshot per tick), all released before the next frame; a test holds what
it keeps to a few bytes per frame over thousands of frames.
"""

from __future__ import annotations

import faulthandler
import gc
import logging
import signal
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass

from tracker.astrometry.observer import Observer, TimeSource
from tracker.board import cpu_temperature_c
from tracker.capture.base import Frame, FrameError, Waiting
from tracker.capture.live import TIMEOUT_REASON, WAIT_SLICE_S
from tracker.config import Config, config_checksum
from tracker.daemon.capture_ahead import CaptureAhead
from tracker.daemon.clock import Clock
from tracker.daemon.commands import Commands
from tracker.daemon.exposure import ExposureControl
from tracker.daemon.health import Health
from tracker.daemon.modes import ModeMachine
from tracker.daemon.notify import Notifier, Watchdog, watchdog_interval_s
from tracker.daemon.status import StatusSnapshot
from tracker.daemon.timebase import TimeBase
from tracker.detect.psf import FWHM_PER_SIGMA
from tracker.protocol.messages import ErrorCode, Mode

__all__ = ["Daemon", "FrameReport", "EXIT_LINK_FAILED"]

log = logging.getLogger(__name__)

# run()'s exit status when a link thread ended: systemd restarts the unit.
EXIT_LINK_FAILED = 1
# Log at most this many tracebacks of one fault kind; later ones only count.
_LOGGED_PER_FAULT = 5
# Longest wait, when a source closes, for the capture thread to leave the source's code.
_CAPTURE_JOIN_S = 2.0
_SECOND_NS = 1_000_000_000


@dataclass
class FrameReport:
    """What one processed frame cost, for benchmarks: ms per stage and end to end.

    ``latency_ms`` runs from the frame leaving the source to its packets
    handed to the link; ``stages_ms`` splits it (``capture`` is the wait
    inside the source before that and is not part of the latency).
    """

    index: int
    mode: Mode
    solved: bool
    latency_ms: float
    stages_ms: dict


class Daemon:
    """The loop of the module docstring, with every stage injected.

    ``source_factory()`` returns a new FrameSource (called again after the
    source fails); ``pipeline.process(image, bit_depth, t_ns, observer,
    exposure_s)`` returns a :class:`~tracker.pipeline.FrameResult` and ``pipeline.reset()``
    forgets the tracking lock; ``link`` is a
    :class:`~tracker.daemon.link.DaemonLink` or anything with its methods.
    ``clock`` (tests: a virtual one) times every wait; ``timebase`` (tests)
    replaces the :class:`~tracker.daemon.timebase.TimeBase` of ``cfg.time``.
    ``on_frame(report)`` is called after each processed frame (benchmarks).
    """

    def __init__(self, cfg: Config, *, source_factory: Callable, pipeline, link,
                 notifier: Notifier | None = None, clock: Clock | None = None,
                 timebase: TimeBase | None = None,
                 on_frame: Callable[[FrameReport], None] | None = None):
        self.cfg = cfg
        self.scfg = cfg.service
        self.source_factory = source_factory
        self.pipeline = pipeline
        self.link = link
        self.clock = clock or Clock()
        self.notifier = notifier or Notifier()
        self.watchdog = Watchdog(self.notifier, watchdog_interval_s())
        self.health = Health(self.clock.now_ns)
        self.modes = ModeMachine(cfg.service)
        self.exposure = ExposureControl(cfg.capture)
        self.timebase = timebase or TimeBase(cfg.time)
        self.on_frame = on_frame
        self.link_failure: str | None = None
        self._config_crc = config_checksum(cfg)
        self._stop = threading.Event()
        self._finished = False
        self._source = None
        self._live = False
        self._ready = False
        self._sensor: tuple[float | None, float | None] = (None, None)   # exposure, gain
        self._observer: Observer | None = None      # the latest frame's
        self._temp_c = float("nan")
        self._psf_fwhm_px = float("nan")           # the latest frame's that measured one
        self._logged: dict[ErrorCode, int] = {}
        self._next = {"stall": 0, "systemd_status": 0, "temperature": 0}

    @property
    def mode(self) -> Mode:
        return self.modes.mode

    # -- control from outside ------------------------------------------------

    def request_stop(self, *_args) -> None:
        """Stop at the next tick; safe from a signal handler."""
        self._stop.set()

    def install_signal_handlers(self) -> None:
        """SIGTERM/SIGINT stop the loop (main thread only)."""
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)

    # -- the loop --------------------------------------------------------------

    def run(self) -> int:
        """Run until stopped, the source ends or ``service.frames`` are taken.

        Returns 0 on a clean stop, :data:`EXIT_LINK_FAILED` when a link thread ended.
        """
        if self.scfg.watchdog_s > 0:
            faulthandler.enable()
        gc.collect()
        gc.freeze()     # start-up objects (catalogue, database) are never rescanned
        self.link.publish(self._snapshot())
        self.link.open()
        delay = self.scfg.retry_initial_s
        try:
            while not self._done():
                if self._run_source():
                    delay = self.scfg.retry_initial_s
                if self._done():
                    break
                self.modes.camera_lost()
                if not self._ready:
                    self._mark_ready("no camera yet, retrying")
                log.debug("reopening the camera in %.2f s", delay)
                self._wait(delay)
                delay = min(2 * delay, self.scfg.retry_max_s)
        finally:
            self.notifier.notify("STOPPING=1", "STATUS=" + self.health.summary("stopping"))
            if self.scfg.watchdog_s > 0:
                faulthandler.cancel_dump_traceback_later()
            self.link.close()
            self._mirror_link()        # the link's final counters into health
            log.info("stopped: %s", self.health.summary(self.mode.name))
        if self.link_failure:
            log.critical("the serial link failed (%s); exiting for systemd to restart",
                         self.link_failure)
            return EXIT_LINK_FAILED
        return 0

    def _done(self) -> bool:
        return self._stop.is_set() or self._finished

    def _wait(self, seconds: float) -> None:
        """Wait, ticking at least every WAIT_SLICE_S, until seconds pass or a stop."""
        end = self.clock.now_ns() + int(seconds * 1e9)
        while not self._done():
            self._tick()
            left = (end - self.clock.now_ns()) / 1e9
            if left <= 0 or self.clock.wait(self._stop, min(left, WAIT_SLICE_S)):
                break

    def _run_source(self) -> bool:
        """Consume one source until it ends or fails; True if it delivered a frame.

        Only the source's own calls are guarded here (a source failing in any
        way is closed and reopened); an exception from the daemon's own code
        is a bug and ends the process, for systemd to restart it.
        """
        try:
            source = self.source_factory()
            items = iter(source)
        except Exception as exc:
            self._fault(ErrorCode.CAMERA_LOST, f"{type(exc).__name__}: {exc}", exc)
            return False
        self._source = source
        self._live = bool(getattr(source, "live", False))
        ahead = self._capture_ahead(source, items)
        take = (lambda: next(items, None)) if ahead is None else ahead.take
        got_frame = False
        try:
            while not self._done():
                t0 = self.clock.now_ns()
                item = self.capture(take)
                if item is None:
                    break
                got_frame = got_frame or isinstance(item, Frame)
                self._tick()
                if self._stop.is_set():
                    break
                if not isinstance(item, Waiting):
                    try:
                        self.process(item, t0)
                    finally:
                        if ahead is not None:
                            ahead.release()
                            self.health.superseded = ahead.superseded
                if self.scfg.frames and self.health.frames >= self.scfg.frames:
                    self._finished = True
        finally:
            if ahead is not None:
                self._stop_capture(ahead)
            self._source = None
            try:
                source.close()
            except Exception as exc:    # a half-dead camera may fail to close; it is dropped
                log.warning("closing the source failed: %s", exc)
        return got_frame

    def _capture_ahead(self, source, items: Iterator) -> CaptureAhead | None:
        """The capture thread for this source, or None (``service.capture_ahead``)."""
        policy = self.scfg.capture_ahead
        if policy == "never" or (policy == "live" and not self._live):
            return None
        return CaptureAhead(items, live=self._live, frame_buffers=getattr(source, "frame_buffers",
                                                                     None),
                            wait=self.clock.wait, slice_s=WAIT_SLICE_S).start()

    def _stop_capture(self, ahead: CaptureAhead) -> None:
        """End the capture thread, ticking meanwhile; a source hung in its own code is
        left behind after :data:`_CAPTURE_JOIN_S` (closing it usually frees it)."""
        ahead.stop()
        waited = 0.0
        while not ahead.join(WAIT_SLICE_S) and waited < _CAPTURE_JOIN_S:
            waited += WAIT_SLICE_S
            self._tick()
        if waited >= _CAPTURE_JOIN_S:
            log.warning("the capture thread did not stop within %g s; closing the source "
                        "under it", _CAPTURE_JOIN_S)

    def capture(self, take: Callable[[], object]) -> Frame | FrameError | Waiting | None:
        """The capture step: the source's next item; None when it ended or failed."""
        try:
            item = take()
        except Exception as exc:
            self._fault(ErrorCode.CAMERA_LOST, f"{type(exc).__name__}: {exc}", exc)
            return None
        if item is None:
            self._finished = True
        return item

    def process(self, item: Frame | FrameError, t0_ns: int) -> None:
        """The processing step for one item from the source (taken at t0_ns)."""
        t_avail = self.clock.now_ns()
        self.health.frames += 1
        if isinstance(item, FrameError):
            code = ErrorCode.CAMERA_TIMEOUT if item.reason.startswith(TIMEOUT_REASON) else \
                ErrorCode.FRAME_UNREADABLE
            self._fault(code, item.reason)
            self.modes.frame_failed()
            return
        if not self._ready:
            self._mark_ready(f"first frame {item.name}")
        self._sensor = (item.exposure_us, item.gain)
        observer = self._observer = self.timebase.observer_for(item)
        # a live frame's latency runs from its exposure; a replayed one's from its reading
        t_ref = item.t_ns if self._live else t_avail
        if not self.modes.processing:
            self.modes.frame_ok()
            self.link.send_frame(item, None, self.mode, observer, t_ref)
            return
        self._solve(item, observer, t_avail, (t_avail - t0_ns) / 1e6, t_ref)

    def _solve(self, frame: Frame, observer: Observer, t_avail: int, capture_ms: float,
               t_ref: int) -> None:
        try:
            exposure_s = None if frame.exposure_us is None else frame.exposure_us / 1e6
            result = self.pipeline.process(frame.image, frame.bit_depth, frame.t_ns, observer,
                                           exposure_s)
        except Exception as exc:    # a stage that raises loses this frame only
            self._fault(ErrorCode.STAGE_ERROR, f"{frame.name}: {type(exc).__name__}: {exc}",
                        exc)
            self.modes.frame_failed()
            return
        t_done = self.clock.now_ns()
        self.modes.frame_ok()
        solution = result.solution
        solved = bool(solution is not None and solution.ok)
        if solved:
            self.health.solved += 1
        elif len(result.detections.stars):
            self.health.solve_failures += 1
        self.modes.solved(solved)
        if result.detections.psf_sigma_px is not None:
            self._psf_fwhm_px = result.detections.psf_sigma_px * FWHM_PER_SIGMA
        if self.exposure.update(result.detections, frame.bit_depth):
            self._apply_exposure()
        t_ctl = self.clock.now_ns()
        self.link.send_frame(frame, result, self.mode, observer, t_ref)
        t_end = self.clock.now_ns()
        latency = (t_end - t_avail) / 1e6
        self.health.processed += 1
        self.health.frame_done(latency)
        if self.on_frame is not None:
            stages = {"capture": capture_ms, **result.stages_ms,
                      "pipeline": (t_done - t_avail) / 1e6, "control": (t_ctl - t_done) / 1e6,
                      "link": (t_end - t_ctl) / 1e6}
            self.on_frame(FrameReport(frame.index, self.mode, solved, latency, stages))

    # -- the tick --------------------------------------------------------------

    def _tick(self) -> None:
        """Link check, watchdogs, FC commands, counters and STATUS; see the module docstring."""
        failure = self.link.failure
        if failure is not None:
            self.link_failure = failure
            self._stop.set()
            return
        now = self.clock.now_ns()
        self.watchdog.kick(now)
        if self.scfg.watchdog_s > 0 and now >= self._next["stall"]:
            faulthandler.dump_traceback_later(self.scfg.watchdog_s, exit=True)
            self._next["stall"] = now + _SECOND_NS
        self._apply(self.link.take_commands())
        self._mirror_link()
        self.health.tick()
        if now >= self._next["temperature"]:       # a sysfs read at most once a second
            temp = cpu_temperature_c()
            self._temp_c = float("nan") if temp is None else temp
            self._next["temperature"] = now + _SECOND_NS
        self.link.publish(self._snapshot())
        if now >= self._next["systemd_status"]:
            self._next["systemd_status"] = now + int(self.scfg.status_period_s * 1e9)
            self.notifier.notify("STATUS=" + self.health.summary(self.mode.name))

    def _apply(self, cmds: Commands | None) -> None:
        if cmds is None:
            return
        if cmds.reacquire:
            self.pipeline.reset()
        if cmds.mode is not None:
            self.modes.command(cmds.mode)
        if cmds.exposure_us is not None or cmds.gain is not None:
            self.exposure.set_manual(cmds.exposure_us, cmds.gain)
            self._apply_exposure()
        if cmds.time_offset_ns is not None:
            self.timebase.time_sync(cmds.time_offset_ns)
        if cmds.velocity is not None:
            self.timebase.set_velocity(*cmds.velocity)

    def _status_observer(self) -> Observer:
        """STATUS's context: a frame's taken now (a replayed record's: the latest frame's)."""
        last = self._observer
        if last is not None and last.time_source == TimeSource.RECORD:
            return last
        return self.timebase.observer_at(self.clock.now_ns())

    def _snapshot(self) -> StatusSnapshot:
        h = self.health
        observer = self._status_observer()
        exposure_us, gain = self._sensor
        return StatusSnapshot(
            uptime_s=int(h.uptime_s), frame_rate_hz=h.frame_rate_hz,
            exposure_us=round(self.exposure.exposure_us if exposure_us is None else exposure_us),
            gain=float(self.exposure.gain if gain is None else gain),
            cpu_temp_c=self._temp_c, mode=int(self.mode), frames=h.frames,
            capture_faults=h.capture_faults, solve_failures=h.solve_failures,
            last_error=int(h.last_error), config_crc=self._config_crc,
            time_source=int(observer.time_source), corrections=int(observer.corrections),
            psf_fwhm_px=self._psf_fwhm_px)

    def _mirror_link(self) -> None:
        counts = self.link.counts()
        for code, total in ((ErrorCode.LINK_ERROR, counts.link_error),
                            (ErrorCode.RX_REJECT, counts.rx_reject),
                            (ErrorCode.TX_DROP, counts.tx_drop),
                            (ErrorCode.LINK_INTERNAL, counts.link_internal)):
            if total > self.health.faults[code]:
                self.health.fault(code, count=total - self.health.faults[code])

    # -- helpers -------------------------------------------------------------

    def _mark_ready(self, why: str) -> None:
        link = "link open" if self.link.is_open else "link not open yet"
        self.notifier.notify("READY=1", "STATUS=" + self.health.summary(self.mode.name))
        self._ready = True
        log.info("ready: %s, %s", why, link)

    def _fault(self, code: ErrorCode, text: str, exc: BaseException | None = None) -> None:
        self.health.fault(code, text)
        n = self._logged[code] = self._logged.get(code, 0) + 1
        if n <= _LOGGED_PER_FAULT:
            log.warning("%s: %s", code.name.lower(), text, exc_info=exc if n == 1 else None)
            if n == _LOGGED_PER_FAULT:
                log.warning("%s: further ones are only counted (STATUS)", code.name.lower())

    def _apply_exposure(self) -> None:
        setter = getattr(self._source, "set_controls", None)
        if setter is None or not setter(self.exposure.exposure_us, self.exposure.gain):
            self.exposure.auto = False      # this source cannot change them: stop trying
