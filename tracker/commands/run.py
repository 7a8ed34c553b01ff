"""``tracker run``: the star-tracker service (what systemd starts).

Reads frames from ``capture.backend`` (replay, picamera2 or v4l2), runs
them through the pipeline and talks to the flight computer on
``link.port``; see :mod:`tracker.service`. Logs go to stderr (journald
under systemd). Options override the configuration for a run, e.g. the
demo's::

    tracker run --replay FRAMES/ --loop --frames 300 --port /dev/pts/5 --summary -

With ``--summary FILE`` (``-`` = stdout) a JSON object is written at the end:
frames, solved, faults, latency percentiles (ms) and the link's counters.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import sys

from tracker.capture.live import make_source
from tracker.commands.argtypes import count, non_negative
from tracker.config import Config
from tracker.pipeline import Pipeline
from tracker.service import Service
from tracker.service_link import ServiceLink

__all__ = ["register", "run", "build_service", "summary"]


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


def build_service(cfg: Config, replay: list[str] | None = None, **kwargs) -> Service:
    """The service with the real stages; ``kwargs`` go to :class:`Service`.

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
    return Service(cfg, source_factory=lambda: make_source(cfg, replay),
                   pipeline=pipeline,
                   link=kwargs.pop("link", None) or ServiceLink(cfg), **kwargs)


def summary(service: Service) -> dict:
    """The end-of-run JSON summary of a service."""
    h = service.health
    link = getattr(service.link, "link", None)
    return {
        "state": service.state.value,
        "frames": h.frames, "processed": h.processed, "solved": h.solved,
        "solve_rate": round(h.solved / h.processed, 4) if h.processed else 0.0,
        "faults": {k: v for k, v in h.faults.items() if v},
        "latency_ms": {k: round(v, 3) for k, v in h.latency_percentiles().items()},
        "link": link.stats() if link is not None else {},
    }


def run(args, cfg: Config) -> int:
    cfg = _override(cfg, args)
    if not args.verbose:
        logging.getLogger().setLevel(cfg.service.log_level)
    service = build_service(cfg, args.replay)
    service.install_signal_handlers()
    code = service.run()
    if args.summary:
        text = json.dumps(summary(service), indent=2) + "\n"
        if args.summary == "-":
            sys.stdout.write(text)
        else:
            with open(args.summary, "w", encoding="utf-8") as fh:
                fh.write(text)
    return code
