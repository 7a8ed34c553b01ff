"""Detection and centroiding: every method and two peers on simulated frames with truth.

``tracker bench detect [--frames N] [--quick] [--out DIR]`` renders the data
sets of tracker.bench.detect_data (the seed's four noise models across
-5..+3 dB; realistic 10-bit 16 mm and 8 mm frames with glare, hot pixels
and cosmic rays), runs every method of tracker.detect.METHODS and the peers
of tracker.bench.detect_peers (sep, tetra3) on the same frames in the same
process, one after the other per frame, and scores them
(tracker.bench.detect_score). It then runs the default detector over the
realistic frames for a long loop and reports resident memory.

Writes ``detect.md``, ``detect.json`` and ``detect.png`` into ``--out``,
headed by the machine. Times are medians of per-frame wall-clock times
(other work on the machine shows up as noise; medians keep it out).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from tracker.bench.detect_data import build_sets
from tracker.bench.detect_peers import PEERS, peer_available
from tracker.bench.detect_plot import plot_sets
from tracker.bench.detect_score import MAG_BINS, FrameTruth, Score
from tracker.bench.machine import describe_machine
from tracker.catalogue import load_catalogue
from tracker.detect import METHODS, make_detector

__all__ = ["add_arguments", "run"]

# Our methods may report this many stars per frame here (the seed sets hold up to ~400
# detectable stars; the shipped cap of detect.max_stars would cut recall, not quality).
BENCH_MAX_STARS = 4096
TARGETS = {"recall_realistic": 0.99, "fdr_realistic": 0.005, "crb_ratio": 1.5,
           "recall_seed": 0.95, "fdr_seed": 0.01}


def add_arguments(p) -> None:
    p.add_argument("--frames", type=int, default=3, metavar="N",
                   help="frames per seed-model data set (default 3)")
    p.add_argument("--realistic-frames", type=int, default=40, metavar="N",
                   help="frames per realistic data set (default 40: their stars at peak "
                        "SNR >= 20 are few, and the RMSE/CRB ratio needs dozens)")
    p.add_argument("--quick", action="store_true",
                   help="1 frame per set, 3 SNR levels, a short memory run")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed of the frames (default: sim.seed)")


def _rss_mib() -> float:
    try:
        with open("/proc/self/statm", encoding="ascii") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return float("nan")


def _run_method(name, detectors, cfg, frame, bit_depth, settings):
    """(x, y, ms, stages, rejected impulses) of one method on one frame.

    ``settings`` are detect.* keys for this data set (e.g. the centroid's
    noise model); peers take none.
    """
    image = frame.image
    if name in PEERS:
        t0 = time.perf_counter()
        x, y = PEERS[name](image)
        return x, y, (time.perf_counter() - t0) * 1e3, None, 0
    key = (name, image.shape, bit_depth, tuple(sorted(settings.items())))
    if key not in detectors:
        detectors[key] = make_detector(
            dataclasses.replace(cfg.detect, method=name, max_stars=BENCH_MAX_STARS, **settings),
            image.shape, bit_depth)
        detectors[key].detect(image)  # warm-up, untimed
    t0 = time.perf_counter()
    result = detectors[key].detect(image)
    ms = (time.perf_counter() - t0) * 1e3
    stars = result.stars
    rejected = result.counters.get("hot_pixels", 0) + result.counters.get("cosmic_rays", 0)
    return stars["x"].copy(), stars["y"].copy(), ms, dict(result.stages_ms), rejected


def _score_sets(sets, methods, cfg) -> dict:
    detectors: dict = {}
    scores = {s.name: {m: Score() for m in methods} for s in sets}
    for data in sets:
        for frame in data.frames:
            truth = FrameTruth.from_frame(frame, data.criterion, data.variance,
                                          data.flux_unit(frame), frame.truth["psf_sigma_px"],
                                          data.saturation)
            for m in methods:
                try:
                    x, y, ms, stages, rejected = _run_method(m, detectors, cfg, frame,
                                                             data.bit_depth,
                                                             data.detect_settings)
                except Exception:  # a peer failing on a frame is a result, not a crash
                    scores[data.name][m].failures += 1
                    continue
                scores[data.name][m].add(truth, np.asarray(x, float), np.asarray(y, float),
                                         ms, stages, rejected)
    return scores


def _memory_run(sets, cfg, loops: int) -> dict:
    """RSS of the default detector looping over the realistic frames."""
    frames = [f for s in sets if s.group == "realistic" for f in s.frames]
    det = make_detector(dataclasses.replace(cfg.detect, method="default"),
                        frames[0].image.shape, frames[0].bit_depth)
    for f in frames:
        det.detect(f.image)
    start = _rss_mib()
    peak = start
    for i in range(loops):
        det.detect(frames[i % len(frames)].image)
        if i % 50 == 0:
            peak = max(peak, _rss_mib())
    return {"frames": loops, "shape": list(frames[0].image.shape), "rss_start_mib": start,
            "rss_end_mib": _rss_mib(), "rss_peak_mib": max(peak, _rss_mib())}


def _pooled(sets, scores, methods, group) -> dict:
    out = {}
    for m in methods:
        total = Score()
        for s in sets:
            if s.group == group or (group == "seed" and s.group.startswith("seed/")):
                total = total.merged(scores[s.name][m])
        out[m] = total.summary()
    return out


def _fmt(v, spec=".3f", pct=False):
    if v is None:
        return "-"
    return f"{100 * v:.1f} %" if pct else format(v, spec)


def _targets(summary: dict) -> list[tuple[str, str, bool]]:
    rows = []
    for name in summary["realistic_sets"]:
        d = summary["sets"][name]["default"]
        rows.append((f"{name}: recall (peak SNR >= 5) >= 99 %", _fmt(d["recall"], pct=True),
                     (d["recall"] or 0) >= TARGETS["recall_realistic"]))
        rows.append((f"{name}: FDR <= 0.5 %", _fmt(d["fdr"], pct=True),
                     d["fdr"] <= TARGETS["fdr_realistic"]))
        ratio = d["rmse_over_crb_snr20"]
        rows.append((f"{name}: RMSE <= 1.5 x CRB at peak SNR >= 20 (n = {d['n_snr20']})",
                     _fmt(ratio, ".2f") + " x",
                     ratio is not None and ratio <= TARGETS["crb_ratio"]))
    for group, pooled in summary["seed_models"].items():
        d = pooled["default"]
        rows.append((f"{group}: recall (MF SNR >= 7) >= 95 %", _fmt(d["recall"], pct=True),
                     (d["recall"] or 0) >= TARGETS["recall_seed"]))
        rows.append((f"{group}: FDR <= 1 %", _fmt(d["fdr"], pct=True),
                     d["fdr"] <= TARGETS["fdr_seed"]))
        ratio = d["crb_px"] and d["rmse_px"] / d["crb_px"]
        rows.append((f"{group}: RMSE <= 1.5 x CRB (matched stars)", _fmt(ratio, ".2f") + " x",
                     ratio is not None and ratio <= TARGETS["crb_ratio"]))
    speed = summary["speed_full_frame_ms"]
    ours = speed.get("default")
    for peer, factor in (("sep", 1.0), ("tetra3", 0.5)):
        if speed.get(peer) is not None and ours is not None:
            rows.append((f"full-frame time <= {factor:g} x {peer} ({speed[peer]:.1f} ms)",
                         f"{ours:.1f} ms", ours <= factor * speed[peer]))
    return rows


def _markdown(summary: dict) -> str:
    m = summary["machine"]
    lines = ["# tracker bench detect", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in m.items()), "",
             f"Command: `{summary['command']}`; frames per seed-model set: "
             f"{summary['frames']}, per realistic set: {summary['realistic_frames']}; "
             f"match radius {summary['match_px']} px; times are medians per frame. "
             "The speckle sets run our detector with `detect.centroid_noise: "
             "multiplicative`, the setting for a camera whose noise scales with the light. "
             "CRB: the Cramer-Rao bound of the same stars. For speckle it is exact (the "
             "Fisher information of the rounded, clipped pixel); for the others each pixel's "
             "noise is taken as Gaussian of the model's variance, close for shot and read "
             "noise and only a reference for salt and pepper and glare, which an estimator "
             "can beat.",
             "",
             "## Targets (issue 3), default method", "", "| target | measured | met |",
             "|---|---|---|"]
    lines += [f"| {t} | {v} | {'yes' if ok else '**no**'} |" for t, v, ok in summary["targets"]]
    head = ("| method | recall | FDR | RMSE px | mean px | RMSE@SNR>=20 | CRB@SNR>=20 | "
            "ratio | median ms | impulses counted |")
    for name in summary["realistic_sets"]:
        lines += ["", f"## {name} (10-bit; recall of peak SNR >= 5)", "", head,
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for meth, d in summary["sets"][name].items():
            lines.append(f"| {meth} | {_fmt(d['recall'], pct=True)} | {_fmt(d['fdr'], pct=True)}"
                         f" | {_fmt(d['rmse_px'])} | {_fmt(d['mean_err_px'])} | "
                         f"{_fmt(d['rmse_snr20_px'])} | {_fmt(d['crb_snr20_px'])} | "
                         f"{_fmt(d['rmse_over_crb_snr20'], '.2f')} | {_fmt(d['median_ms'], '.1f')}"
                         f" | {d['rejected_impulses']} |")
    lines += ["", "## Seed noise models, pooled over SNR levels (recall of MF SNR >= 7)", "",
              "| model | method | recall | FDR | RMSE px | mean px | CRB px | RMSE/CRB | ms |",
              "|---|---|---|---|---|---|---|---|---|"]
    for group, pooled in summary["seed_models"].items():
        for meth, d in pooled.items():
            ratio = d["crb_px"] and d["rmse_px"] and d["rmse_px"] / d["crb_px"]
            lines.append(f"| {group[5:]} | {meth} | {_fmt(d['recall'], pct=True)} | "
                         f"{_fmt(d['fdr'], pct=True)} | {_fmt(d['rmse_px'])} | "
                         f"{_fmt(d['mean_err_px'])} | {_fmt(d['crb_px'])} | {_fmt(ratio, '.2f')}"
                         f" | {_fmt(d['median_ms'], '.1f')} |")
    lines += ["", "## The dissertation's comparison, all seed-model frames pooled", "",
              "| method | RMSE px | mean Euclidean px | FDR % | recall |", "|---|---|---|---|---|"]
    for meth, d in summary["seed_all"].items():
        lines.append(f"| {meth} | {_fmt(d['rmse_px'])} | {_fmt(d['mean_err_px'])} | "
                     f"{_fmt(d['fdr'], pct=True)} | {_fmt(d['recall'], pct=True)} |")
    bins = [f"{lo:g}..{hi:g}" for lo, hi in zip(MAG_BINS[:-1], MAG_BINS[1:], strict=True)]
    lines += ["", "## RMSE by magnitude bin, realistic frames pooled (px; n; CRB)", "",
              "| method | " + " | ".join(bins) + " |", "|---|" + "---|" * len(bins)]
    for meth, d in summary["realistic_all"].items():
        cells = [f"{_fmt(d['by_mag'][b]['rmse_px'])} (n {d['by_mag'][b]['n']}; "
                 f"{_fmt(d['by_mag'][b]['crb_px'])})" for b in bins]
        lines.append(f"| {meth} | " + " | ".join(cells) + " |")
    stages = summary["realistic_all"]["default"]["stages_median_ms"]
    lines += ["", "## Default detector per stage, full frames (median ms)", "",
              "| " + " | ".join(stages) + " |", "|" + "---|" * len(stages),
              "| " + " | ".join(f"{v:.2f}" for v in stages.values()) + " |"]
    mem = summary["memory"]
    lines += ["", "## Resident memory, default detector", "",
              f"{mem['frames']} frames of {mem['shape'][1]} x {mem['shape'][0]}: RSS "
              f"{mem['rss_start_mib']:.1f} MiB after warm-up, {mem['rss_end_mib']:.1f} MiB "
              f"at the end, peak {mem['rss_peak_mib']:.1f} MiB.", ""]
    if summary["missing_peers"]:
        lines += [f"Peers not installed: {', '.join(summary['missing_peers'])}.", ""]
    return "\n".join(lines)


def run(args, cfg) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = 1 if args.quick else max(1, int(args.frames))
    rng = np.random.default_rng(cfg.sim.seed if args.seed is None else args.seed)
    catalogue = load_catalogue(path=cfg.catalogue.path, mag_limit=None)
    realistic = 1 if args.quick else max(1, int(args.realistic_frames))
    sets = build_sets(cfg, catalogue, frames, realistic, args.quick, rng)
    peers = [p for p in PEERS if peer_available(p)]
    methods = list(METHODS) + peers
    scores = _score_sets(sets, methods, cfg)
    realistic = [s.name for s in sets if s.group == "realistic"]
    seed_groups = sorted({s.group for s in sets if s.group.startswith("seed/")})
    summary = {
        "machine": describe_machine(),
        "command": "tracker bench detect" + (" --quick" if args.quick else
                                             f" --frames {frames}"),
        "frames": frames, "realistic_frames": realistic, "match_px": 2.0, "methods": methods,
        "missing_peers": [p for p in PEERS if p not in peers],
        "sets": {s.name: {m: scores[s.name][m].summary() for m in methods} for s in sets},
        "realistic_sets": realistic,
        "seed_models": {g: _pooled(sets, scores, methods, g) for g in seed_groups},
        "seed_all": _pooled(sets, scores, methods, "seed"),
        "realistic_all": _pooled(sets, scores, methods, "realistic"),
    }
    summary["speed_full_frame_ms"] = {m: summary["realistic_all"][m]["median_ms"]
                                      for m in methods}
    summary["memory"] = _memory_run(sets, cfg, 100 if args.quick else 1000)
    summary["targets"] = _targets(summary)
    (out / "detect.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    (out / "detect.md").write_text(_markdown(summary))
    names = [s.name for s in sets]
    plot_sets(str(out / "detect.png"), names, methods,
              {m: [summary["sets"][n][m]["recall"] for n in names] for m in methods},
              {m: [summary["sets"][n][m]["mean_err_px"] for n in names] for m in methods},
              f"{summary['command']}: {summary['machine']['cores']} cores, "
              f"{summary['machine']['machine']}")
    print((out / "detect.md").read_text())
    return 0
