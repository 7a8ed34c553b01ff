"""``tracker replay FRAMES...``: run the pipeline over recorded or simulated frames.

Writes one JSON object per frame (DESIGN.md's contract) to ``--jsonl`` (or
standard output), shows a progress bar when standard error is a terminal,
and with ``--overlay DIR`` writes a PNG per frame with each detection
circled (green: identified, yellow: not identified) for people to look at.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tracker.capture import FrameError, ReplaySource
from tracker.commands.progress import Progress
from tracker.detect.psf import FWHM_PER_SIGMA
from tracker.overlay import write_overlay
from tracker.pipeline import FrameResult, Pipeline

__all__ = ["register", "frame_record"]


def register(sub, common) -> None:
    p = sub.add_parser("replay", parents=[common], help="detect and solve recorded frames, "
                       "one JSON line per frame")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="image files (PNG, TIFF, JPEG, .npy) or folders of them")
    p.add_argument("--jsonl", metavar="OUT", help="write the records here (default: stdout)")
    p.add_argument("--overlay", metavar="DIR", help="write PNGs with the detections marked")
    p.add_argument("--loop", action="store_true", help="start again after the last file")
    p.add_argument("--fps", type=float, default=0.0, help="pace frames at this rate (Hz)")
    p.set_defaults(func=run)


def frame_record(name: str, result: FrameResult) -> dict:
    """The per-frame JSON object of the replay contract."""
    det = result.detections
    sol = result.solution
    hips = getattr(sol, "hip", None)
    stars = []
    for i, s in enumerate(det.stars):
        star = {"x": round(float(s["x"]), 4), "y": round(float(s["y"]), 4),
                "flux": round(float(s["flux"]), 2), "snr": round(float(s["snr"]), 2),
                "flags": int(s["flags"])}
        if hips is not None and hips[i]:
            star["hip"] = int(hips[i])
        stars.append(star)
    record = {
        "frame": name,
        "stars": stars,
        "attitude": sol.to_json() if sol is not None else None,
        "time_ms": round(result.time_ms, 3),
        "stages_ms": {k: round(v, 3) for k, v in result.stages_ms.items()},
    }
    if det.reason:
        record["detect_reason"] = det.reason
    if sol is not None and not sol.ok:
        record["solve_reason"] = sol.reason
    elif result.solve_reason:
        record["solve_reason"] = result.solve_reason
    if det.counters:
        record["rejected"] = {k: int(v) for k, v in det.counters.items()}
    if det.psf_sigma_px is not None:
        record["psf"] = {"sigma_px": round(det.psf_sigma_px, 4),
                         "fwhm_px": round(det.psf_sigma_px * FWHM_PER_SIGMA, 4),
                         "ellipticity": round(det.psf_ellipticity, 4),
                         "angle_deg": round(det.psf_angle_deg, 2), "stars": det.psf_stars}
    return record


def run(args, cfg) -> int:
    source = ReplaySource(args.frames, loop=args.loop, fps=args.fps,
                          bits16_depth=cfg.camera.bit_depth)
    pipeline = Pipeline(cfg)
    if cfg.identify.enabled:
        pipeline.solver  # load catalogue and database now, not inside frame 1's time  # noqa: B018
    out = open(args.jsonl, "w", encoding="utf-8") if args.jsonl else sys.stdout
    overlay_dir = Path(args.overlay) if args.overlay else None
    if overlay_dir:
        overlay_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress(None if args.loop else len(source), "replay")
    errors = 0
    try:
        with source:
            for item in source:
                if isinstance(item, FrameError):
                    errors += 1
                    record = {"frame": item.name, "error": item.reason, "stars": [],
                              "attitude": None}
                    progress.note(f"skipped {item.reason}")
                else:
                    result = pipeline.process(item.image, item.bit_depth, item.t_ns)
                    record = frame_record(item.name, result)
                    if overlay_dir:
                        write_overlay(overlay_dir / (Path(item.name).stem + ".overlay.png"),
                                      item.image, item.bit_depth, result)
                out.write(json.dumps(record) + "\n")
                out.flush()
                progress.advance()
    finally:
        progress.close()
        if out is not sys.stdout:
            out.close()
    print(f"replay: {progress.count} frames, {errors} unreadable", file=sys.stderr)
    return 0
