"""The library API: tracker.solve / solve_centroids on every kind of array, its docs executed."""

import doctest
import subprocess
import sys
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
from sky_frames import sky_frames

import tracker
import tracker.api
from tracker.attitude import attitude_error, matrix_from_quat
from tracker.config import Config, ConfigError, load_config

ROOT = Path(__file__).resolve().parent.parent
ORION = ROOT / "tests" / "data" / "real" / "cedar-solve" / "orion_belt.jpg"
ORION_CFG = ROOT / "tests" / "data" / "real" / "cedar-solve" / "orion_belt.yaml"


@pytest.fixture(scope="module", name="sky")
def fixture_sky():
    """One simulated OV2311 frame (16 mm, realistic sensor, 10-bit) and its truth."""
    (frame,) = sky_frames([(201.3, 54.9, 140.0)], 21)
    assert frame.image.dtype == np.uint16 and int(frame.image.max()) < 1024
    return frame


def arcsec_from_truth(result, truth) -> tuple[float, float]:
    assert result.ok, result.reason
    cross, roll = attitude_error(matrix_from_quat(result.q), matrix_from_quat(truth["q"]))
    return np.degrees(cross) * 3600, np.degrees(roll) * 3600


def test_the_docstring_examples_run(monkeypatch):
    monkeypatch.chdir(ROOT)
    failures, tried = doctest.testmod(tracker.api, raise_on_error=False)
    assert tried >= 6 and failures == 0


def test_every_kind_of_array_gives_the_same_attitude(sky):
    img10 = sky.image
    reference = tracker.solve(img10)
    cross, roll = arcsec_from_truth(reference, sky.truth)
    # 1-sigma sizes at 16 mm are ~1.6 arcsec across and ~12 about the boresight
    assert cross < 8 and roll < 60 and reference.matched >= 10
    assert reference.sigma_arcsec > 0 and reference.stars["hip"].astype(bool).sum() >= 10
    bgr = cv2.cvtColor((img10 >> 2).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    variants = {
        "uint16 as 16-bit": img10.astype(np.uint16) << 6,
        "uint8": (img10 >> 2).astype(np.uint8),
        "float 0..1": img10 / 1023.0,
        "float ADU": img10.astype(np.float32),
        "int64": img10.astype(np.int64),
        "colour BGR": bgr,
        "colour BGRA": cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA),
    }
    for name, array in variants.items():
        result = tracker.solve(array)
        cross, roll = arcsec_from_truth(result, sky.truth)
        assert cross < 8 and roll < 60, name
        assert abs(result.ra_deg - reference.ra_deg) * 3600 < 5, name


def test_a_file_and_its_array_give_the_same_answer(tmp_path, sky):
    cv2.imwrite(str(tmp_path / "f.png"), sky.image)
    from_file = tracker.solve(tmp_path / "f.png")
    from_array = tracker.solve(sky.image)
    assert from_file.q == from_array.q and len(from_file.stars) == len(from_array.stars)


def test_solve_centroids_from_the_true_pixels(sky):
    stars = sorted((s for s in sky.truth["stars"] if s["in_frame"]), key=lambda s: s["mag"])
    xy = [(s["x"], s["y"]) for s in stars[:40]]
    result = tracker.solve_centroids(xy)
    cross, roll = arcsec_from_truth(result, sky.truth)
    assert cross < 0.5 and roll < 2, (cross, roll)     # exact pixels: only rounding is left
    hips = [s["hip"] for s in stars[:40]]
    assert list(result.stars["hip"][result.stars["hip"] > 0]) == \
        [h for h, got in zip(hips, result.stars["hip"], strict=True) if got]
    assert np.all(np.isnan(result.stars["flux"]))
    with_flux = tracker.solve_centroids([(x, y, 10.0 ** (-0.4 * s["mag"]))
                                         for (x, y), s in zip(xy, stars, strict=False)][::-1])
    assert arcsec_from_truth(with_flux, sky.truth)[0] < 0.5
    assert list(with_flux.stars["x"][:3]) == [xy[0][0], xy[1][0], xy[2][0]]   # bright first


def test_config_may_be_a_path_a_config_a_mapping_or_none():
    answers = [tracker.solve(ORION, config=c) for c in (
        ORION_CFG, str(ORION_CFG), load_config(ORION_CFG),
        {"camera": load_config(ORION_CFG).camera.__dict__})]
    assert all(a.ok for a in answers) and len({a.q for a in answers}) == 1


def test_mistakes_raise_one_line_user_errors(tmp_path, sky):
    with pytest.raises(tracker.UserError, match=r"^image is 512x512 px, the camera "
                                                r"configuration says 1600x1300: give"):
        tracker.solve(np.zeros((512, 512), np.uint8) + 3)
    with pytest.raises(tracker.UserError, match=r"^orion_belt.jpg: image is 512x512 px, the "
                                                r"camera configuration says 1600x1300"):
        tracker.solve(ORION, config=Config())
    with pytest.raises(tracker.UserError, match=r"found a int, expected a YAML file path"):
        tracker.solve(sky.image, config=5)
    with pytest.raises(ConfigError, match=r"camera.widht: found an unknown key"):
        tracker.solve(sky.image, config={"camera": {"widht": 3}})
    with pytest.raises(tracker.UserError, match=r"NaN or infinity"):
        tracker.solve(np.full((1300, 1600), np.nan))
    with pytest.raises(tracker.UserError, match=r"centroids: an array of shape \(3,\)"):
        tracker.solve_centroids([1, 2, 3])
    with pytest.raises(tracker.UserError, match=r"nothing.png: no such file"):
        tracker.solve(tmp_path / "nothing.png")


def test_an_unsolvable_image_is_a_result_not_an_error():
    result = tracker.solve(np.zeros((1300, 1600), np.uint16))
    assert not result.ok and result.reason == "too_few_stars" and len(result.stars) == 0
    assert np.isnan(result.ra_deg) and result.q is None
    assert "ok=False" in repr(result)


def test_import_tracker_stays_light_and_version_is_one_number():
    code = "import sys, tracker; print('cv2' in sys.modules, tracker.__version__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "False"
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert out[1] == tracker.__version__ == project["version"]
    script = Path(sys.executable).parent / "tracker"
    shown = subprocess.run([str(script), "--version"], capture_output=True, text=True,
                           check=True).stdout
    assert shown.startswith(f"tracker {tracker.__version__} (Python ")


def test_the_readme_example_runs_as_written(monkeypatch, capsys):
    text = (ROOT / "README.md").read_text()
    section = text.split("\n## Library API\n", 1)[1].split("\n## ", 1)[0]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["result"].ok
    printed = capsys.readouterr().out
    assert printed.startswith("SolveResult(ok=True, ra_deg=84.0")
