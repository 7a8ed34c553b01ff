"""tracker bench track: its cost ratios read from its own rows (tracker.bench.track)."""

import argparse

import numpy as np

from tracker.bench.machine import describe_machine
from tracker.bench.track import _markdown, run_scenario
from tracker.catalogue import load_catalogue
from tracker.config import Config


def test_a_scenario_reports_its_wall_paired_and_cpu_ratios():
    """The ratio of medians (wall), the median of each frame's windowed time over its own
    full-frame detection, and the ratio of the CPU medians, each from the rows it
    reports, and all three in the table."""
    cfg = Config()
    cat = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    r = run_scenario(cfg, cat, 16.0, 1.0, 1.0, 10.0, 20.0, 0, np.random.default_rng(4))
    full = [row for row in r["rows"]["full"] if row["i"] >= 3]
    windowed = [row for row in r["rows"]["windows"]
                if row["i"] >= 3 and row["mode"] == "tracking"]
    assert len(windowed) >= 5 and all(row["windows"] > 0 for row in windowed)
    assert all(row["detect_cpu_ms"] is None for row in windowed)
    assert all(0 < row["detect_cpu_ms"] <= row["cpu_ms"] for row in full)
    by_frame = {row["i"]: row for row in full}
    paired = [row["ms"] / by_frame[row["i"]]["detect_ms"] for row in windowed]
    assert r["paired_ratio_median"] == np.median(paired)
    assert r["cost_ratio"] == (np.median([row["ms"] for row in windowed])
                               / np.median([row["detect_ms"] for row in full]))
    assert r["cpu_ratio"] == (np.median([row["cpu_ms"] for row in windowed])
                              / np.median([row["detect_cpu_ms"] for row in full]))
    args = argparse.Namespace(fps=10.0, exposure_ms=20.0, seed=4)
    table = _markdown(describe_machine(), args, [r], None)
    assert f"1/{1 / r['paired_ratio_median']:.1f}" in table
    assert f"1/{1 / r['cpu_ratio']:.1f}" in table
