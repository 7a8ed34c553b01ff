"""``tracker replay FRAMES...``: run the pipeline over recorded or simulated frames.

For people, on standard output: one line per frame (its stars, and the
attitude or why there is none, and the time) and at the end a summary with
the counts per outcome and reason. A frame of another size than the
configured camera is found but not identified; that is said once on
standard error, with both sizes.

For programs: ``--jsonl FILE`` (``-``: standard output, instead of the
lines) gets one JSON object per frame (the contract in docs/conventions.md,
:func:`frame_record`). ``--overlay DIR`` writes a picture per frame
(tracker.overlay) and ``--report DIR`` an HTML page with a sky chart and a
table of the frames (tracker.report). Output names are the frames' names,
made unique when two folders hold the same ones (:func:`unique_keys`).
"""

from __future__ import annotations

import json
import statistics
import sys
from collections import Counter, deque
from pathlib import Path

from tracker.capture import FrameError, ReplaySource, Waiting
from tracker.commands.argtypes import non_negative
from tracker.commands.outputs import close_output, open_output, output_folder
from tracker.commands.progress import Progress
from tracker.detect.psf import FWHM_PER_SIGMA
from tracker.errors import UserError
from tracker.overlay import render_overlay, write_overlay
from tracker.pipeline import FrameResult, Pipeline
from tracker.report import ReplayReport
from tracker.truth import read_truth

__all__ = ["register", "frame_record", "frame_line", "unique_keys", "Tally"]

_TIMES_KEPT = 100_000      # frame times kept for the median (a --loop run is endless)


def register(sub, common) -> None:
    p = sub.add_parser("replay", parents=[common], help="detect and solve recorded frames: a "
                       "line per frame, JSON with --jsonl, pictures, an HTML report")
    p.add_argument("frames", nargs="+", metavar="FRAMES",
                   help="image files (PNG, TIFF, JPEG, .npy) or folders of them")
    p.add_argument("--jsonl", metavar="OUT", help="write one JSON record per frame to OUT "
                   "('-' = standard output, instead of the lines for people)")
    p.add_argument("--overlay", metavar="DIR", help="write a PNG per frame with its stars "
                   "marked and its result")
    p.add_argument("--report", metavar="DIR", help="write DIR/index.html: a sky chart of the "
                   "boresights and a table of the frames")
    p.add_argument("--quiet", action="store_true", help="no line per frame, only the summary")
    p.add_argument("--loop", action="store_true", help="start again after the last file")
    p.add_argument("--fps", type=non_negative, default=0.0,
                   help="pace frames at this rate (Hz; 0 = as fast as possible); frames "
                   "without a recorded t_ns are stamped 1/fps apart (at 0: "
                   "capture.replay_interval_s)")
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
    if result.observer.t_tai_ns is not None:
        record["observer"] = result.observer.to_json()
    return record


def frame_line(name: str, record: dict, width: int = 0) -> str:
    """The line for people about one frame's record (or error record)."""
    head = f"{name:<{width}}"
    if "error" in record:
        return f"{head}  unreadable: {record['error'].removeprefix(name + ': ')}"
    n = len(record["stars"])
    att = record["attitude"]
    if att is not None:
        return (f"{head}  {n:4d} stars  solved      RA {att['ra_deg']:9.4f}  Dec "
                f"{att['dec_deg']:+8.4f}  roll {att['roll_deg']:8.3f} deg  {att['matched']:3d} "
                f"matched  {record['time_ms']:7.1f} ms")
    reason = record.get("solve_reason") or record.get("detect_reason") or "unknown"
    return f"{head}  {n:4d} stars  not solved: {reason}  {record['time_ms']:.1f} ms"


def unique_keys(paths: list[Path]) -> dict[Path, str]:
    """A distinct output name per file: its stem, else ``folder-name``, else numbered."""
    def clashes(names: dict[Path, str]) -> set[str]:
        seen = Counter(names.values())
        return {k for k, n in seen.items() if n > 1}

    keys = {p: p.stem for p in paths}
    dup = clashes(keys)
    keys = {p: (f"{p.parent.name}-{p.name}" if k in dup else k) for p, k in keys.items()}
    dup = clashes(keys)
    return {p: (f"{i:04d}-{k}" if k in dup else k) for i, (p, k) in enumerate(keys.items())}


class Tally:
    """Counts of a replay's outcomes, and its summary lines."""

    def __init__(self) -> None:
        self.frames = 0
        self.solved = 0
        self.not_solved: Counter[str] = Counter()
        self.unreadable = 0
        self.first_error = ""
        self.times_ms: deque[float] = deque(maxlen=_TIMES_KEPT)

    def add(self, record: dict) -> None:
        self.frames += 1
        if "error" in record:
            self.unreadable += 1
            self.first_error = self.first_error or record["error"]
            return
        self.times_ms.append(record["time_ms"])
        if record["attitude"] is not None:
            self.solved += 1
        else:
            self.not_solved[record.get("solve_reason") or record.get("detect_reason")
                            or "unknown"] += 1

    def lines(self) -> list[str]:
        n = self.frames
        share = f" ({100 * self.solved / n:.1f} %)" if n else ""
        reasons = ", ".join(f"{k} {v}" for k, v in self.not_solved.most_common())
        text = (f"replay: {n} frames: {self.solved} solved{share}, "
                f"{sum(self.not_solved.values())} not solved"
                + (f" ({reasons})" if reasons else "") + f", {self.unreadable} unreadable")
        out = [text]
        if self.first_error:
            out.append(f"replay: first unreadable: {self.first_error}")
        if self.times_ms:
            out.append(f"replay: time per frame (decoding excluded): median "
                       f"{statistics.median(self.times_ms):.1f} ms, max "
                       f"{max(self.times_ms):.1f} ms")
        return out


def _size_warning(name: str, shape: tuple[int, int], cfg) -> str:
    cam = cfg.camera
    return (f"tracker replay: {name} is {shape[1]}x{shape[0]} px, the camera configuration "
            f"says {cam.width}x{cam.height}: its stars are found but not identified "
            "(give the configuration of the camera that took it: camera.width, height, "
            "pixel_size_um, focal_length_mm); said once")


def run(args, cfg) -> int:
    if args.report and args.loop:
        raise UserError("--report needs a replay that ends: leave out --loop")
    cam = cfg.camera
    source = ReplaySource(args.frames, loop=args.loop, fps=args.fps,
                          bits16_depth=cam.bit_depth, max_size=(cam.width, cam.height),
                          interval_s=cfg.capture.replay_interval_s)
    pipeline = Pipeline(cfg)
    if cfg.identify.enabled:
        pipeline.solver  # load catalogue and database now, not inside frame 1's time  # noqa: B018
    overlay_dir = output_folder(args.overlay, "--overlay") if args.overlay else None
    report = None
    if args.report:
        report = ReplayReport(output_folder(args.report, "--report"), pipeline.camera,
                              pipeline.catalogue)
    json_out = open_output(args.jsonl, "--jsonl") if args.jsonl else None
    lines = not args.quiet and json_out is not sys.stdout
    keys = unique_keys(source.files)
    width = min(max(len(p.name) for p in source.files), 40)
    progress = Progress(None if args.loop else len(source), "replay",
                        enabled=not lines)
    tally = Tally()
    warned = False
    try:
        with source:
            for item in source:
                if isinstance(item, Waiting):    # paced by --fps: nothing to do yet
                    continue
                path = source.files[item.index % len(source.files)]
                if isinstance(item, FrameError):
                    record = {"frame": item.name, "error": item.reason, "stars": [],
                              "attitude": None}
                    if report is not None:
                        report.add_error(item.name, record["error"])
                else:
                    result = pipeline.process(item.image, item.bit_depth, item.t_ns,
                                              item.recorded_observer())
                    record = frame_record(item.name, result)
                    if result.solve_reason == "frame_size" and not warned:
                        warned = True
                        progress.note(_size_warning(item.name, item.image.shape, cfg))
                    if overlay_dir is not None or report is not None:
                        truth = read_truth(path)
                        if overlay_dir is not None:
                            overlay_path = overlay_dir / f"{keys[path]}.overlay.png"
                            picture = write_overlay(overlay_path, item.image, result,
                                                    item.name, truth)
                        else:
                            overlay_path = None
                            picture = render_overlay(item.image, result, item.name, truth)
                        if report is not None:
                            report.add_frame(keys[path], item.name, result, picture,
                                             overlay_path, truth)
                tally.add(record)
                if json_out is not None:
                    json_out.write(json.dumps(record) + "\n")
                    json_out.flush()
                if lines:
                    print(frame_line(item.name, record, width), flush=True)
                progress.advance()
    finally:
        progress.close()
        close_output(json_out)
        summary = tally.lines()
        if report is not None:
            summary.append(f"replay: report {report.write(summary)}")
        print("\n".join(summary), file=sys.stdout if lines else sys.stderr)
    return 0
