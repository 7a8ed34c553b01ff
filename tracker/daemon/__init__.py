"""The daemon: what ``tracker run`` (and systemd) runs on the Pi.

One frame loop (:mod:`~tracker.daemon.loop`) takes frames from the camera,
runs them through the pipeline (:mod:`tracker.pipeline`, shared with
``tracker replay``) and hands the results to the serial link. Around it:

- :mod:`~tracker.daemon.modes`: the operating mode (the ICD's Mode:
  STANDBY, LOST_IN_SPACE, TRACKING, FAULT) and the rules that move it;
- :mod:`~tracker.daemon.link`: the daemon's side of the serial link. FC
  commands reach the loop as values (:mod:`~tracker.daemon.commands`);
  STATUS leaves it as an immutable snapshot (:mod:`~tracker.daemon.status`);
  the link never holds the loop;
- :mod:`~tracker.daemon.exposure`: automatic exposure and gain;
- :mod:`~tracker.daemon.health`: fault counters (by ErrorCode), rates and
  latency percentiles for STATUS and systemd;
- :mod:`~tracker.daemon.notify`: sd_notify (READY, STATUS, WATCHDOG) and
  the watchdog's pace;
- :mod:`~tracker.daemon.clock`: the loop's clock and waits, injectable so
  tests run minutes of camera outage on a virtual clock.

Typical use (what ``tracker run`` does)::

    daemon = Daemon(cfg, source_factory=lambda: make_source(cfg),
                    pipeline=Pipeline(cfg), link=DaemonLink(cfg))
    daemon.install_signal_handlers()
    sys.exit(daemon.run())       # 0 on SIGTERM; 1 if the serial link's threads died
"""

from tracker.daemon.link import DaemonLink
from tracker.daemon.loop import EXIT_LINK_FAILED, Daemon, FrameReport

__all__ = ["Daemon", "DaemonLink", "FrameReport", "EXIT_LINK_FAILED"]
