"""Simulated frames on disk: PNG + truth JSON, and the `tracker simulate` command."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from tracker.capture.imagefile import read_image
from tracker.commands import simulate
from tracker.config import SimConfig, load_config
from tracker.errors import UserError
from tracker.sim import render_points, truth_path, write_frame

TRUTH_KEYS = {"frame", "seed", "q", "ra_deg", "dec_deg", "roll_deg", "epoch_year", "t_s",
              "rate_deg_s", "camera", "bit_depth", "psf_sigma_px", "exposure_ms",
              "noise_model", "snr_db", "snr_db_definition", "stars", "false_sources"}
STAR_KEYS = {"x", "y", "mag", "hip", "flux_e", "peak_snr", "mf_snr"}


def _frame(model, bit_depth=10):
    return render_points((60, 80), [20.3, 50.7], [30.1, 10.9], [3000.0, 1e6], SimConfig(),
                         np.random.default_rng(4), bit_depth=bit_depth, noise_model=model,
                         mags=[5.0, 1.0], hips=[11, 12])


@pytest.mark.parametrize("model, depth", [("realistic", 10), ("speckle", 8), ("none", 8)])
def test_png_round_trips_with_its_bit_depth(tmp_path, model, depth):
    frame = _frame(model, bit_depth=depth)
    path = write_frame(frame, tmp_path / "out", "f0001")
    assert path.name == "f0001.png"
    image, bit_depth = read_image(path)
    assert bit_depth == depth
    assert image.dtype == frame.image.dtype and np.array_equal(image, frame.image)
    truth = json.loads(truth_path(path).read_text())
    assert truth_path(path).name == "f0001.png.truth.json"
    assert TRUTH_KEYS <= set(truth) and truth["frame"] == "f0001.png"
    assert [s["hip"] for s in truth["stars"]] == [11, 12]
    assert STAR_KEYS <= set(truth["stars"][0])
    assert truth["stars"][1]["saturated"] and not truth["stars"][0]["saturated"]


def test_frame_name_must_be_a_plain_file_name(tmp_path):
    with pytest.raises(ValueError, match="frame name must be a plain file name"):
        write_frame(_frame("none"), tmp_path, "../escape")


def _run(argv):
    parser = argparse.ArgumentParser()
    simulate.register(parser.add_subparsers(), argparse.ArgumentParser(add_help=False))
    args = parser.parse_args(["simulate", *argv])
    return args.func(args, load_config(None))


def test_simulate_writes_a_slew_with_truth(tmp_path, capsys):
    out = tmp_path / "sim"
    assert _run(["--out", str(out), "--frames", "2", "--seed", "3", "--ra", "83.8", "--dec",
                 "-5.4", "--roll", "10", "--rate-deg-s", "0", "0.2", "0", "--fps", "5"]) == 0
    truths = [json.loads((out / f"f000{i}.png.truth.json").read_text()) for i in range(2)]
    assert truths[0]["ra_deg"] == pytest.approx(83.8) and truths[0]["seed"] == 3
    assert truths[0]["roll_deg"] == pytest.approx(10.0)
    assert truths[1]["t_s"] == pytest.approx(0.2) and truths[1]["rate_deg_s"] == [0, 0.2, 0]
    image, depth = read_image(out / "f0001.png")
    assert depth == 10 and image.shape == (1300, 1600)
    assert "wrote 2 frame(s)" in capsys.readouterr().err


def test_simulate_explains_bad_options(tmp_path):
    with pytest.raises(UserError, match="give all of --ra, --dec and --roll"):
        _run(["--out", str(tmp_path), "--ra", "10"])
    with pytest.raises(UserError, match="--frames must be >= 1"):
        _run(["--out", str(tmp_path), "--frames", "0"])
    with pytest.raises(UserError, match="a target SNR applies to the seed noise models"):
        _run(["--out", str(tmp_path), "--noise", "realistic", "--snr-db", "1"])
    with pytest.raises(UserError, match="out of reach for speckle"):
        _run(["--out", str(tmp_path), "--noise", "speckle", "--snr-db", "50"])
