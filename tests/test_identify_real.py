"""Real frames (tests/data/real/, see its README): solved within the truth's tolerances.

Each frame's centroid list (SEP, extracted once by make_centroids.py) is
solved lost in space with the camera ``tracker calibrate`` fitted for its
source; the boresight at the image centre must be within 60 arcsec of the
astrometry.net truth and the roll within 0.1 deg (the truth's own
tolerances, tests/data/real/MANIFEST of the shared data).
"""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from tracker.attitude import radec_to_vector
from tracker.camera import CameraModel
from tracker.capture.imagefile import read_image
from tracker.catalogue import Catalogue
from tracker.commands.calibrate import load_stars
from tracker.config import load_config
from tracker.identify import make_solver
from tracker.identify.database import build_database, save_database
from tracker.pipeline import Pipeline

REAL = Path(__file__).parent / "data" / "real"

FRAMES = {
    "tetra3/2019-07-29T204726_Alt40_Azi-135_Try1.tiff": "tetra3/camera.yaml",
    "tetra3/2019-07-29T204726_Alt40_Azi45_Try1.tiff": "tetra3/camera.yaml",
    "tetra3/2019-07-29T204726_Alt60_Azi-45_Try1.tiff": "tetra3/camera.yaml",
    "tetra3/2019-07-29T204726_Alt60_Azi135_Try1.tiff": "tetra3/camera.yaml",
    "cedar-solve/jan1_g90_e100ms.jpg": "cedar-solve/jan1.yaml",
    "cedar-solve/jan1_g90_e50ms.jpg": "cedar-solve/jan1.yaml",
    "cedar-solve/crappy.jpg": "cedar-solve/crappy.yaml",
    "cedar-solve/orion_belt.jpg": "cedar-solve/orion_belt.yaml",
    "cedar-solve/hale_bopp.jpg": "cedar-solve/hale_bopp.yaml",
    "cedar-solve/tree.jpg": "cedar-solve/tree.yaml",
    "openstartracker/img3.png": "openstartracker/camera.yaml",
    "openstartracker/img6.png": "openstartracker/camera.yaml",
    "openstartracker/img0.png": "openstartracker/camera.yaml",
}
KNOWN_MISSES = {
    "cedar-solve/tree.jpg": "roll 0.19 deg from the truth: all 22 stars lie left of the tree, "
                            "the truth fit has 58 arcsec RMS",
    "openstartracker/img0.png": "only 4 of the 60 extracted sources are Hipparcos stars "
                                "(the brightest are merged or split by the extraction)",
}


# Through our own detector (test_real_image_through_detector_and_solver).
KNOWN_PIPELINE_MISSES = {
    "cedar-solve/tree.jpg": "solved (the lit branches are flagged EXTENDED) with the centre "
                            "within the tolerance, but roll 0.196 deg from the truth, the same "
                            "offset as the centroid-list test above",
}


def assert_within_truth_tolerances(sol, truth: dict) -> None:
    """Boresight within 60 arcsec of the truth's centre, roll within 0.1 deg (MANIFEST)."""
    a = radec_to_vector(math.radians(sol.ra_deg), math.radians(sol.dec_deg))
    b = radec_to_vector(math.radians(truth["ra_deg"]), math.radians(truth["dec_deg"]))
    centre_arcsec = math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)) * 3600
    roll_deg = (sol.roll_deg - truth["roll_deg"] + 180.0) % 360.0 - 180.0
    assert centre_arcsec < 60.0
    assert abs(roll_deg) < 0.1


@pytest.fixture(scope="session")
def narrow_database(tmp_path_factory):
    """A database for the openstartracker lens (7.6 deg diagonal; no OV2311 one fits).

    Built as tools/build_database.py would (mag 8.0, 8 stars per region),
    in a few seconds.
    """
    cfg = load_config(REAL / "openstartracker" / "camera.yaml")
    cam = CameraModel.from_config(cfg.camera)
    diag = math.degrees(cam.fov_diagonal_rad)
    fov_y = 2 * math.degrees(math.atan(cam.height / 2 / cam.f_px))
    built = build_database(Catalogue.from_config(cfg.catalogue), fov_min_deg=diag * 0.82,
                           fov_max_deg=diag * 1.18, mag_limit=8.0, max_pair_deg=diag,
                           stars_per_region=8, region_radius_deg=fov_y / 2, name="ost")
    path = tmp_path_factory.mktemp("db") / "patterns_ost.npz"
    save_database(path, built)
    return str(path)


@pytest.mark.parametrize("frame", [
    pytest.param(f, marks=pytest.mark.xfail(reason=KNOWN_MISSES[f], strict=True))
    if f in KNOWN_MISSES else f for f in FRAMES])
def test_real_frame_matches_truth(frame, narrow_database):
    cfg = load_config(REAL / FRAMES[frame])
    if frame.startswith("openstartracker"):
        cfg = dataclasses.replace(cfg, identify=dataclasses.replace(
            cfg.identify, database=narrow_database))
    solver = make_solver(cfg.identify, CameraModel.from_config(cfg.camera),
                         Catalogue.from_config(cfg.catalogue))
    stars, _, _ = load_stars(REAL / f"{frame}.centroids.json", cfg)
    truth = json.loads((REAL / f"{frame}.truth.json").read_text())
    sol = solver.solve(stars, 0)
    assert sol.ok, sol.reason
    assert_within_truth_tolerances(sol, truth)
    assert sol.matched >= 7


SHARED_REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def image_path(frame: str) -> Path | None:
    """The real image: bundled beside its truth, or the project's shared data (CI has it)."""
    for folder in (REAL, SHARED_REAL):
        if (folder / frame).is_file():
            return folder / frame
    return None


@pytest.mark.parametrize("frame", [
    pytest.param(f, marks=pytest.mark.xfail(reason=KNOWN_PIPELINE_MISSES[f], strict=True))
    if f in KNOWN_PIPELINE_MISSES else f for f in FRAMES])
def test_real_image_through_detector_and_solver(frame, narrow_database):
    """The whole per-frame pipeline on the real pixels: our detector, then lost in space."""
    path = image_path(frame)
    if path is None:
        pytest.skip(f"{frame}: image not bundled and shared/data/real not beside the checkout")
    cfg = load_config(REAL / FRAMES[frame])
    if frame.startswith("openstartracker"):
        cfg = dataclasses.replace(cfg, identify=dataclasses.replace(
            cfg.identify, database=narrow_database))
    image, depth = read_image(path, cfg.camera.bit_depth)
    result = Pipeline(cfg).process(image, depth, 0)
    sol = result.solution
    assert sol is not None and sol.ok, (result.solve_reason or sol.reason,
                                        result.detections.count)
    truth = json.loads((REAL / f"{frame}.truth.json").read_text())
    assert_within_truth_tolerances(sol, truth)
    # the solver accepts only matches whose false-match probability is < 1e-6
    assert sol.matched >= cfg.identify.min_matched
