"""``tracker focus``: the PSF's FWHM across the field, live, for focusing the lens.

Frames come from ``capture.backend`` (the camera on the Pi; picamera2 and
V4L2 are imported only when chosen) or, with ``--replay``, from files. For
each frame the detector finds the stars, the most significant few of every
cell of a grid across the field have their PSF measured one by one (frame
by frame, nothing smoothed across frames, so a turn of the lens shows at
once), and tracker.focus bins them into the grid:

* ``--png FILE`` (default ``focus.png``) is rewritten each frame with the
  frame and the map over it (green at the frame's best FWHM, red at twice
  it); an image viewer that reloads files shows it live;
* on a terminal the grid of FWHM values is redrawn in place; otherwise one
  block per frame is printed.

Stop with Ctrl-C, or after ``--frames N``.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from tracker.capture.backends import make_source
from tracker.capture.base import FrameError, Waiting
from tracker.capture.live import CameraError
from tracker.commands.argtypes import count
from tracker.config import Config
from tracker.detect import make_detector
from tracker.errors import UserError
from tracker.focus import draw_map, focus_map, spread_over, terminal_lines, write_png

__all__ = ["register", "run"]


def _grid(text: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--grid {text!r}: expected COLSxROWS, e.g. 4x3") from None
    if not (1 <= cols <= 32 and 1 <= rows <= 32):
        raise UserError(f"--grid {text!r}: 1 to 32 cells each way")
    return rows, cols


def register(sub, common) -> None:
    p = sub.add_parser("focus", parents=[common], help="the PSF's FWHM across the field, "
                       "live, as a picture and a terminal map (for focusing the lens)")
    p.add_argument("--replay", nargs="+", metavar="PATH",
                   help="files or folders instead of the camera")
    p.add_argument("--png", default="focus.png", metavar="FILE",
                   help="picture rewritten each frame (default focus.png)")
    p.add_argument("--grid", default="4x3", metavar="COLSxROWS",
                   help="cells across the field (default 4x3)")
    p.add_argument("--frames", type=count, default=0, metavar="N",
                   help="stop after N frames (default 0: until Ctrl-C)")
    p.set_defaults(func=run)


def run(args, cfg: Config) -> int:
    grid = _grid(args.grid)
    if args.replay:
        cfg = dataclasses.replace(cfg, capture=dataclasses.replace(cfg.capture,
                                                                   backend="replay"))
    # every star counts, however much wider than the frame's typical one (a corner of a
    # lens out of focus): nothing is masked as a bright body
    detect = dataclasses.replace(cfg.detect, method="default", psf_measure=True,
                                 psf_memory_frames=1, min_sky_sectors=0, body_ratio=1000.0)
    live = sys.stdout.isatty()
    detectors = {}
    shown = 0
    drawn = 0
    try:
        with make_source(cfg, args.replay) as source:
            for item in source:
                if isinstance(item, Waiting):     # a live camera between frames
                    continue
                if args.frames and shown >= args.frames:
                    break
                shown += 1
                if isinstance(item, FrameError):
                    print(f"{item.name}: {item.reason}", file=sys.stderr)
                    continue
                key = (item.image.shape, item.bit_depth)
                if key not in detectors:
                    detectors[key] = make_detector(detect, item.image.shape, item.bit_depth)
                det = detectors[key]
                result = det.detect(item.image)
                cells = spread_over(result.stars, item.image.shape, grid)
                fm = focus_map(np.concatenate([det.psf_of(x, y) for x, y in cells]),
                               item.image.shape, grid)
                try:
                    write_png(Path(args.png), draw_map(item.image, item.bit_depth, fm))
                except OSError as exc:
                    raise UserError(f"--png: {exc}") from None
                lines = [f"{item.name}: " + terminal_lines(fm)[0], *terminal_lines(fm)[1:]]
                if live and drawn:
                    sys.stdout.write(f"\x1b[{drawn}F\x1b[J")   # back over the last map
                sys.stdout.write("\n".join(lines) + "\n")
                sys.stdout.flush()
                drawn = len(lines)
    except KeyboardInterrupt:
        pass
    except CameraError as exc:
        raise UserError(f"camera: {exc}") from None
    return 0
