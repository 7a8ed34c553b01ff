"""``tracker validate``: the seed method's affine identification and ours, scored."""

import json
import math

import numpy as np
import pytest
from test_identify_real import REAL

from tracker.attitude import radec_to_vector
from tracker.cli import main
from tracker.identify.affine import apply_affine, fit_affine, law_of_cosines


def test_affine_fit_is_exact_for_an_affine_field_across_ra_zero():
    rng = np.random.default_rng(51)
    xy = rng.uniform(0, 1000, size=(10, 2))
    ra = np.mod(-0.01 + 2e-5 * xy[:, 0] - 1e-5 * xy[:, 1], 2 * np.pi)   # wraps past 0
    dec = 0.3 + 1e-5 * xy[:, 0] + 2e-5 * xy[:, 1]
    coef, ra0 = fit_affine(xy[:3], ra[:3], dec[:3])
    ra_fit, dec_fit = apply_affine(coef, ra0, xy)
    # the law of cosines resolves no better than sqrt(2 eps) = 1.5e-8 rad near zero
    assert np.allclose(law_of_cosines(ra_fit, dec_fit, ra, dec), 0.0, atol=3e-8)


def test_affine_fit_needs_three_spanning_references():
    with pytest.raises(ValueError, match="at least 3 reference stars, got 2"):
        fit_affine(np.zeros((2, 2)), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="collinear"):
        fit_affine(np.array([[0, 0], [1, 1], [2, 2]]), np.zeros(3), np.zeros(3))


def test_law_of_cosines_matches_vector_angles():
    a = radec_to_vector(1.0, 0.2)
    b = radec_to_vector(1.1, 0.25)
    assert law_of_cosines(1.0, 0.2, 1.1, 0.25) == pytest.approx(math.acos(a @ b), rel=1e-12)


@pytest.mark.parametrize("affine", [True, False], ids=["affine", "solver"])
def test_validate_scores_the_tetra3_frames(tmp_path, capsys, affine):
    """Real frames: our solver has FIR <= 5 % and < 0.005 deg errors; the affine
    method (3 references, no distortion model) errs by up to its 0.1 deg tolerance."""
    out = tmp_path / "v.json"
    lists = sorted(str(p) for p in (REAL / "tetra3").glob("*.centroids.json"))
    args = ["validate", *lists, "--config", str(REAL / "tetra3" / "camera.yaml"),
            "--json", str(out)] + (["--affine"] if affine else [])
    assert main(args) == 0
    assert "| frame | centroids |" in capsys.readouterr().out
    frames = json.loads(out.read_text())["frames"]
    assert len(frames) == 4
    for f in frames:
        assert f["matched"] >= 4
        if affine:
            assert f["max_err_deg"] <= 0.1
        else:
            assert f["fir"] <= 0.05
            assert f["mean_err_deg"] < 0.005
            assert f["matched"] >= 0.9 * f["with_truth"]


def test_validate_needs_truth_and_enough_references(tmp_path, capsys):
    lone = tmp_path / "a.centroids.json"
    lone.write_text(json.dumps({"width": 10, "height": 10, "stars": []}))
    assert main(["validate", "--affine", str(lone)]) == 2
    assert "truth file not found" in capsys.readouterr().err
    assert main(["validate", "--affine", "--refs", "2", str(lone)]) == 2
    assert "--refs must be >= 3" in capsys.readouterr().err
