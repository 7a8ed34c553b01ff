"""``tracker run``: the star-tracker service (what systemd starts).

Reads frames from ``capture.backend`` (replay, picamera2 or v4l2), runs
them through the pipeline and talks to the flight computer on
``link.port``; see :mod:`tracker.daemon`. Logs go to stderr (journald
under systemd). Options override the configuration for a run, e.g. the
demo's::

    tracker run --replay FRAMES/ --loop --frames 300 --port /dev/pts/5 --summary -

With ``--summary FILE`` (``-`` = stdout) a JSON object is written at the end:
frames, solved, faults, latency percentiles (ms: the frame out of the source to its
packets queued), ``wire_latency_ms`` (a live frame's exposure mid-point, a replayed
one's reading, to the last byte of its ATTITUDE on the wire), frames superseded
(tracker.daemon.capture_ahead) and the link's counters.

Exit status: 0 after SIGTERM/SIGINT or the last replayed frame; 1 when the
serial link's threads died (systemd restarts the unit); 2 for a
configuration the user must fix (systemd does not restart: the unit's
``RestartPreventExitStatus=2``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys

from tracker.capture.backends import make_source
from tracker.commands.argtypes import count, non_negative
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.pipeline import Pipeline

__all__ = ["register", "run", "build_daemon", "summary"]


def register(sub, common) -> None:
    p = sub.add_parser("run", parents=[common], help="run the service: camera -> attitude "
                       "-> serial link (what systemd starts)")
    p.add_argument("--frames", type=count, metavar="N",
                   help="stop after N frames (service.frames; default: run until stopped)")
    p.add_argument("--port", metavar="DEVICE", help="serial device or pyserial URL "
                   "(link.port), e.g. a pseudo-terminal")
    p.add_argument("--replay", nargs="+", metavar="PATH",
                   help="use the replay backend on these files or folders")
    p.add_argument("--loop", action="store_true", help="replay: start again after the last file")
    p.add_argument("--fps", type=non_negative,
                   help="capture.fps (replay pacing; live frame rate)")
    p.add_argument("--summary", metavar="FILE", help="write a JSON summary at the end "
                   "('-' = stdout)")
    p.set_defaults(func=run)


def _override(cfg: Config, args) -> Config:
    capture, service, link = cfg.capture, cfg.service, cfg.link
    if args.replay:
        capture = dataclasses.replace(capture, backend="replay")
    if args.loop:
        capture = dataclasses.replace(capture, loop=True)
    if args.fps is not None:
        capture = dataclasses.replace(capture, fps=args.fps)
    if args.frames is not None:
        service = dataclasses.replace(service, frames=max(args.frames, 0))
    if args.port:
        link = dataclasses.replace(link, port=args.port)
    return dataclasses.replace(cfg, capture=capture, service=service, link=link)


def build_daemon(cfg: Config, replay: list[str] | None = None, **kwargs) -> Daemon:
    """The daemon with the real stages; ``kwargs`` go to :class:`~tracker.daemon.Daemon`.

    Raises FileNotFoundError at once if replay frames are missing, and the
    database's ConfigError if no pattern database fits the camera.
    """
    if cfg.capture.backend == "replay":
        make_source(cfg, replay)     # missing frames: said now, not retried forever
    pipeline = kwargs.pop("pipeline", None) or Pipeline(cfg)
    if cfg.identify.enabled and isinstance(pipeline, Pipeline):
        # load the catalogue and pattern database now (a wrong database is a
        # clear error at start-up), not inside the first frame's latency
        pipeline.solver  # noqa: B018
    return Daemon(cfg, source_factory=lambda: make_source(cfg, replay),
                  pipeline=pipeline,
                  link=kwargs.pop("link", None) or DaemonLink(cfg), **kwargs)


def summary(daemon: Daemon) -> dict:
    """The end-of-run JSON summary of a daemon."""
    h = daemon.health
    link = getattr(daemon.link, "link", None)
    return {
        "mode": daemon.mode.name,
        "frames": h.frames, "processed": h.processed, "solved": h.solved,
        "solve_rate": round(h.solved / h.processed, 4) if h.processed else 0.0,
        "faults": h.fault_counts(),
        "latency_ms": {k: round(v, 3) for k, v in h.latency_percentiles().items()},
        "wire_latency_ms": ({k: round(v, 3) for k, v in link.latency.percentiles().items()}
                            if link is not None else {}),
        "superseded": h.superseded,
        "link": link.stats() if link is not None else {},
    }


def run(args, cfg: Config) -> int:
    cfg = _override(cfg, args)
    if not args.verbose:
        logging.getLogger().setLevel(cfg.service.log_level)
    daemon = build_daemon(cfg, args.replay)
    daemon.install_signal_handlers()
    code = daemon.run()
    if args.summary:
        text = json.dumps(summary(daemon), indent=2) + "\n"
        if args.summary == "-":
            sys.stdout.write(text)
        else:
            with open(args.summary, "w", encoding="utf-8") as fh:
                fh.write(text)
    return code
