"""tracker bench track: its cost ratios and pooled draws read from its own rows
(tracker.bench.track), and its scenario syntax."""

import argparse

import numpy as np
import pytest

from tracker.bench.machine import describe_machine
from tracker.bench.track import _markdown, parse_scenarios, run_scenario
from tracker.catalogue import load_catalogue
from tracker.cli import main
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


def test_draws_are_pooled_over_their_own_frames_and_each_is_reported():
    """Two draws of a still scenario: different fields (truth per draw), every frame's row
    tagged with its draw, the pooled RMS the root mean square over both draws' tracked
    frames, each draw's windowed/full ratio from its own frames, and a scenario's first draw
    identical to the same scenario run with one draw."""
    cfg = Config()
    cat = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year)
    two = run_scenario(cfg, cat, 16.0, 0.0, 0.9, 10.0, 20.0, 0, np.random.default_rng(8), 2)
    one = run_scenario(cfg, cat, 16.0, 0.0, 0.9, 10.0, 20.0, 0, np.random.default_rng(8))
    assert two["frames"] == 2 * one["frames"] == 18
    assert two["draws"][0]["psf_sigma_px"] == one["draws"][0]["psf_sigma_px"]
    assert two["draws"][1]["psf_sigma_px"] != two["draws"][0]["psf_sigma_px"]
    # the same frames: the same answers to the last bits BLAS's alignment-dependent sums leave
    assert [r["cross_arcsec"] for r in one["rows"]["full"] if r["ok"]] == pytest.approx([
        r["cross_arcsec"] for r in two["rows"]["full"] if r["ok"] and r["draw"] == 0], abs=1e-6)
    for arm in ("full", "windows"):
        tracked = [r for r in two["rows"][arm] if r["mode"] == "tracking" and r["i"] >= 3]
        assert {r["draw"] for r in tracked} == {0, 1}
        pooled = np.sqrt(np.mean([r["cross_arcsec"] ** 2 for r in tracked]))
        assert two["stats"][arm]["cross_rms_arcsec"] == pytest.approx(pooled, rel=1e-12)
    for d, draw in enumerate(two["draws"]):
        rms = {arm: np.sqrt(np.mean([r["roll_arcsec"] ** 2 for r in two["rows"][arm]
                                     if r["draw"] == d and r["mode"] == "tracking"
                                     and r["i"] >= 3])) for arm in ("full", "windows")}
        assert draw["roll_ratio"] == pytest.approx(rms["windows"] / rms["full"], rel=1e-12)
    args = argparse.Namespace(fps=10.0, exposure_ms=20.0, seed=8)
    assert f"{two['draws'][1]['cross_ratio']:.2f}" in _markdown(describe_machine(), args,
                                                               [two], None)


def test_scenarios_parse_with_and_without_draws():
    assert parse_scenarios("16:0:10:5,8:3:2.5") == [(16.0, 0.0, 10.0, 5), (8.0, 3.0, 2.5, 1)]


@pytest.mark.parametrize("bad", ["16:0", "16:x:10", "16:1:10:0", "16:1:10:2.5", "0:1:10",
                                 "16:1:10:2:9"])
def test_a_malformed_scenario_is_one_line_and_exit_2(bad, tmp_path, capsys):
    assert main(["bench", "track", "--scenarios", bad, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and bad in err and "lens_mm:rate_deg_s:seconds[:draws]" in err
