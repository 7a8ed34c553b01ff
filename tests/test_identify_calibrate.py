"""Lens calibration (tracker.identify.calibration, ``tracker calibrate``)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.cli import main
from tracker.commands.calibrate import expand_frames, search_pieces
from tracker.config import load_config
from tracker.identify.calibration import CalibrationFrame, calibrate

REAL = Path(__file__).parent / "data" / "real"


def _frames(true_cam, n, rng, noise_px=0.1):
    cat = catalogue()
    out, stars_out = [], []
    for _ in range(n):
        R = random_rotation(rng)
        stars, truth = synthetic_stars(true_cam, R, rng, noise_px=noise_px, n_false=0)
        rows = np.searchsorted(cat.hip, truth, sorter=np.argsort(cat.hip))
        rows = np.argsort(cat.hip)[rows]
        out.append(CalibrationFrame(xy=np.column_stack([stars["x"], stars["y"]]),
                                    ref=cat.vectors[rows], R=R))
        stars_out.append(stars)
    return out, stars_out


def test_bundle_adjustment_recovers_a_lens_that_differs_from_nominal():
    """f +3 %, principal point off by (12, -8) px, k1 = -0.05, from 4 frames.

    With ~50 stars a frame and 0.1 px noise the fit is good to ~0.01 % in f
    and a fraction of a pixel in cx, cy; the tolerances are 5x that.
    """
    nominal = camera(16.0)
    true_cam = dataclasses.replace(nominal, f_px=nominal.f_px * 1.03, cx=nominal.cx + 12,
                                   cy=nominal.cy - 8, k1=-0.05)
    rng = np.random.default_rng(41)
    frames, _ = _frames(true_cam, 4, rng)
    # start from the nominal lens and attitudes that are off by its error
    res = calibrate(nominal, frames)
    cam = res.camera
    assert cam.f_px == pytest.approx(true_cam.f_px, rel=5e-4)
    assert cam.cx == pytest.approx(true_cam.cx, abs=2.0)
    assert cam.cy == pytest.approx(true_cam.cy, abs=2.0)
    assert cam.k1 == pytest.approx(-0.05, abs=0.01)
    assert res.rms_px == pytest.approx(0.1 * np.sqrt(2), rel=0.25)
    assert res.rejected == 0


def test_too_few_stars_is_an_error():
    frame = CalibrationFrame(xy=np.zeros((2, 2)), ref=np.tile([0.0, 0.0, 1.0], (2, 1)),
                             R=np.eye(3))
    with pytest.raises(ValueError, match="2 identified stars cannot fix 7 unknowns"):
        calibrate(camera(16.0), [frame])


def test_calibrate_command_writes_a_config(tmp_path):
    """The CLI from centroid lists of a lens 1 % longer than the config says."""
    nominal = camera(16.0)
    true_cam = dataclasses.replace(nominal, f_px=nominal.f_px * 1.01, k1=0.03)
    rng = np.random.default_rng(42)
    _, stars = _frames(true_cam, 3, rng)
    paths = []
    for i, s in enumerate(stars):
        path = tmp_path / f"f{i}.centroids.json"
        path.write_text(json.dumps({"width": 1600, "height": 1300, "stars": [
            {"x": float(r["x"]), "y": float(r["y"]), "flux": float(r["flux"])} for r in s]}))
        paths.append(str(path))
    out = tmp_path / "cal.yaml"
    assert main(["calibrate", *paths, "--out", str(out)]) == 0
    cfg = load_config(out)
    assert cfg.camera.focal_length_mm == pytest.approx(16.0 * 1.01, rel=5e-4)
    assert cfg.camera.k1 == pytest.approx(0.03, abs=0.01)


def test_calibrate_recovers_a_lens_label_twenty_percent_off(tmp_path, capsys):
    """The tetra3 frames with 42 mm and 28 mm configured (the lens is 35.29 mm).

    The fitted focal length must match the one calibrated from the right
    neighbourhood (tetra3/camera.yaml) within 0.05 % (4 frames, ~220 stars,
    0.14 px RMS: a few 1e-5 of statistical error). Progress and the pieces
    searched are printed; --help states the range.
    """
    fitted = load_config(REAL / "tetra3" / "camera.yaml").camera.focal_length_mm
    for guess in (42.0, 28.0):
        rough = tmp_path / f"rough{guess:g}.yaml"
        rough.write_text("camera: {width: 1024, height: 768, pixel_size_um: 6.9, "
                         f"focal_length_mm: {guess}}}\n")
        out = tmp_path / f"cal{guess:g}.yaml"
        assert main(["calibrate", str(REAL / "tetra3"), "--config", str(rough),
                     "--out", str(out)]) == 0
        err = capsys.readouterr().err
        assert "[4/4]" in err and "searching" in err and "not solved" not in err
        assert load_config(out).camera.focal_length_mm == pytest.approx(fitted, rel=5e-4)
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    assert "0.7-1.3 times it" in capsys.readouterr().out


def test_an_image_and_its_centroid_list_count_once(tmp_path):
    (tmp_path / "a.png").write_bytes(b"")
    (tmp_path / "a.png.centroids.json").write_text("{}")
    (tmp_path / "b.png").write_bytes(b"")
    names = [p.name for p in expand_frames([str(tmp_path), str(tmp_path / "b.png")])]
    assert names == ["a.png.centroids.json", "b.png"]


def test_search_pieces_cover_the_range_from_the_middle_out():
    assert search_pieces(0.0) == [1.0]
    pieces = search_pieces(0.3)
    assert pieces[0] == 1.0 and pieces[1] > 1.0 > pieces[2]
    covered = sorted((c * 0.9, c * 1.1) for c in pieces)
    assert covered[0][0] <= 0.7 and covered[-1][1] >= 1.3
    assert all(a[1] >= b[0] for a, b in zip(covered, covered[1:], strict=False))


def test_calibrate_command_refuses_unsolvable_input(tmp_path, capsys):
    path = tmp_path / "x.centroids.json"
    path.write_text(json.dumps({"width": 1600, "height": 1300, "stars": [
        {"x": 10.0 * i, "y": 7.0 * i, "flux": 1.0} for i in range(1, 9)]}))
    assert main(["calibrate", str(path), "--out", str(tmp_path / "o.yaml")]) == 2
    assert "no frame could be solved" in capsys.readouterr().err
    bad = tmp_path / "bad.centroids.json"
    bad.write_text("{}")
    assert main(["calibrate", str(bad), "--out", str(tmp_path / "o.yaml")]) == 2
    assert "not a centroid list" in capsys.readouterr().err
