"""Pattern databases: what a build holds, the index, the cache, ``tracker database``."""

import dataclasses
import hashlib
import io
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from identify_sim import camera, catalogue
from test_identify_real import REAL, rough_config, truth_focal_mm

from tracker.camera import CameraModel
from tracker.catalogue import Catalogue, load_catalogue
from tracker.cli import main
from tracker.commands.calibrate import load_stars
from tracker.config import IdentifyConfig
from tracker.identify import DatabaseError, make_solver
from tracker.identify.cache import BUILD_EPOCH, cache_dir, design_for, serves
from tracker.identify.database import (
    _MISSING,
    PatternDatabase,
    _blended,
    _fibonacci_lattice,
    _region_members,
    build_database,
)
from tracker.identify.patterns import codes, edge_angles, match_stars, pattern_order


@pytest.fixture(scope="module", name="bright")
def fixture_bright():
    """The catalogue to Hp 5.5 at the build epoch: small enough for brute force."""
    return load_catalogue(epoch_year=BUILD_EPOCH, mag_limit=5.5)


def test_region_members_are_each_regions_brightest_stars(bright):
    """The declination-band search equals a brute-force search on 300 random centres."""
    rng = np.random.default_rng(1)
    centres = rng.normal(size=(300, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    radius = math.radians(6.0)
    got = _region_members(centres, bright.vectors, radius, 10)
    for c, row in zip(centres, got, strict=True):
        inside = np.flatnonzero(bright.vectors @ c >= math.cos(radius))[:10]
        np.testing.assert_array_equal(row[row != _MISSING], inside)


def test_codes_do_not_change_with_scale_rotation_or_order():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(4, 3)) * 0.02 + [0, 0, 1]
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    base = codes(edge_angles(v))
    np.testing.assert_allclose(codes(edge_angles(v @ q.T)), base, atol=1e-12)
    np.testing.assert_allclose(codes(edge_angles(v[[2, 0, 3, 1]])), base, atol=1e-12)
    # the same image read with a 5 % shorter focal length (gnomonic plane scaled):
    # the code moves only at second order, about 0.05 x (0.03 rad)^2 = 4.5e-5
    plane = v[:, :2] / v[:, 2:]
    big = np.column_stack((1.05 * plane, np.ones(4)))
    big /= np.linalg.norm(big, axis=1, keepdims=True)
    np.testing.assert_allclose(codes(edge_angles(big)), base, atol=1e-4)
    perm, err = match_stars(edge_angles(v[[2, 0, 3, 1]]), edge_angles(v)[None])
    np.testing.assert_array_equal(perm[0], [2, 0, 3, 1])
    assert err[0] < 1e-12


def test_pattern_order_tries_the_brightest_first():
    quads = pattern_order(7)
    assert len(quads) == 35 and len({tuple(q) for q in quads}) == 35
    np.testing.assert_array_equal(quads[0], [0, 1, 2, 3])
    assert all(np.all(np.diff(q) > 0) for q in quads)
    assert np.all(np.diff(quads[:, 3]) >= 0)     # the faintest star never gets brighter


@pytest.fixture(scope="module", name="wide_db")
def fixture_wide_db():
    """A 40 deg field's database (builds in a second): design, arrays, bound index."""
    cam = camera(6.0)
    design = design_for(cam)
    cat = load_catalogue(epoch_year=BUILD_EPOCH)
    return design, build_database(cat, design), cat


def test_build_is_deterministic(wide_db):
    design, built, cat = wide_db
    again = build_database(cat, design)
    assert again["meta"]["sha256"] == built["meta"]["sha256"]
    np.testing.assert_array_equal(again["patterns"], built["patterns"])


def test_database_holds_every_quad_of_each_regions_brightest_stars(wide_db):
    """Brute force on 30 region centres: all quads of their brightest stars are stored."""
    design, built, cat = wide_db
    stored = {tuple(sorted(built["hip"][p])) for p in built["patterns"]}
    usable = ~_blended(cat.vectors, np.asarray(cat.mag, dtype=np.float64),
                       math.radians(design.blend_deg))
    centres = _fibonacci_lattice(built["meta"]["regions"])
    radius = math.radians(design.region_radius_deg)
    rng = np.random.default_rng(3)
    checked = 0
    for c in centres[rng.choice(len(centres), 30, replace=False)]:
        inside = np.flatnonzero((cat.vectors @ c >= math.cos(radius)) & usable)
        brightest = inside[:design.pattern_stars]
        for quad in itertools.combinations(brightest, 4):
            quad = list(quad)
            if edge_angles(cat.vectors[quad]).min() >= math.radians(design.min_edge_deg):
                assert tuple(sorted(cat.hip[quad])) in stored
                checked += 1
    assert checked > 1000


def test_lookup_finds_every_pattern_inside_its_box(wide_db):
    """Tiny boxes around 500 stored codes, also straddling bin edges, find their pattern."""
    design, built, cat = wide_db
    db = PatternDatabase(path="mem", meta=built["meta"], hip=built["hip"],
                         patterns=built["patterns"])
    bound = db.bind(cat)
    rng = np.random.default_rng(4)
    picks = rng.choice(len(bound.patterns), 500, replace=False)
    code = codes(edge_angles(bound.vectors[bound.patterns[picks].astype(np.int64)]))
    for width in (1e-9, 0.5 * bound.key_bin, 2.5 * bound.key_bin):
        found, box, share = bound.lookup(code - width, code + width)
        for k, pick in enumerate(picks):
            assert pick in found[box == k]
        assert np.all(share > 0)


def test_cache_builds_once_and_reuses_only_the_cameras_own_design(tmp_path):
    calls = []
    cfg = IdentifyConfig(cache_dir=str(tmp_path))
    first = make_solver(cfg, camera(8.0), catalogue(), lambda s, f: calls.append((s, f)))
    assert calls and calls[-1] == ("done", 1.0)
    path = Path(first.bound.path)
    assert path.parent == tmp_path
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert Path(f"{path}.sha256").read_text() == f"{digest}  {path.name}\n"
    calls.clear()
    again = make_solver(cfg, camera(8.0), catalogue(), lambda s, f: calls.append(s))
    assert again.bound.path == first.bound.path and calls == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name, f"{path.name}.sha256"]
    # a lens 3 % longer, which the 8 mm database would suit, gets its own design
    longer = make_solver(cfg, camera(8.24), catalogue(), lambda s, f: calls.append(s))
    assert calls and longer.bound.design == design_for(camera(8.24)) != first.bound.design


def test_a_frame_solves_the_same_whatever_else_the_cache_holds(tmp_path):
    """A real frame (cedar-solve, configured 5 % short) with an empty cache and with
    one holding a database of a neighbouring field (a lens 4 % longer, whose
    regions are 4 % smaller), which an earlier run of another camera leaves:
    the same database, the same matches, the same attitude to the bit."""
    frame = "cedar-solve/jan1_g90_e100ms.jpg"
    cfg = rough_config(frame, 0.95 * truth_focal_mm(frame))
    cam = CameraModel.from_config(cfg.camera)
    cat = Catalogue.from_config(cfg.catalogue)
    stars, _, _ = load_stars(REAL / f"{frame}.centroids.json", cfg)
    neighbour = CameraModel.from_config(dataclasses.replace(
        cfg.camera, focal_length_mm=1.04 * cfg.camera.focal_length_mm))
    prefilled = tmp_path / "prefilled"
    make_solver(IdentifyConfig(cache_dir=str(prefilled)), neighbour, cat)
    solutions = []
    for folder in (tmp_path / "empty", prefilled):
        solver = make_solver(dataclasses.replace(cfg.identify, cache_dir=str(folder)), cam, cat)
        assert solver.bound.design == design_for(cam)
        solutions.append(solver.solve(stars, 0))
    fresh, crowded = solutions
    assert fresh.ok and crowded.ok
    np.testing.assert_array_equal(fresh.q, crowded.q)
    np.testing.assert_array_equal(fresh.hip, crowded.hip)
    assert len(list(prefilled.glob("patterns_*.npz"))) == 2


def test_a_corrupt_cached_database_is_built_again(tmp_path):
    cfg = IdentifyConfig(cache_dir=str(tmp_path))
    path = Path(make_solver(cfg, camera(8.0), catalogue()).bound.path)
    good = path.read_bytes()
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["hip"] = arrays["hip"][::-1].copy()
    np.savez(path, **arrays)
    calls = []
    solver = make_solver(cfg, camera(8.0), catalogue(), lambda s, f: calls.append(s))
    assert calls and solver.bound.path == str(path)
    assert PatternDatabase.load(path).meta["sha256"] == \
        json.loads(str(np.load(io.BytesIO(good))["meta"]))["sha256"]


def test_a_design_serves_its_lens_over_the_whole_prior():
    cam = camera(16.0)
    design = design_for(cam)
    assert serves(design, cam, cam.f_px * 0.94, cam.f_px * 1.06)
    assert not serves(design, cam, cam.f_px * 0.7, cam.f_px * 1.3)
    assert not serves(design_for(camera(8.0)), cam, cam.f_px * 0.94, cam.f_px * 1.06)


def test_cache_folder_comes_from_config_then_systemd_then_xdg(monkeypatch, tmp_path):
    monkeypatch.setenv("STATE_DIRECTORY", "/var/lib/startracker:/var/lib/other")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir("~/dbs") == Path.home() / "dbs"
    assert cache_dir(None) == Path("/var/lib/startracker")
    monkeypatch.delenv("STATE_DIRECTORY")
    assert cache_dir(None) == tmp_path / "startracker"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_dir(None) == Path.home() / ".cache" / "startracker"


def test_an_unwritable_cache_folder_is_one_clear_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(DatabaseError, match=r"cannot write the pattern database.*"
                                            r"set identify.cache_dir to a writable folder"):
        make_solver(IdentifyConfig(cache_dir=str(blocker / "sub")), camera(7.0), catalogue())


def test_database_command_builds_with_progress_then_finds_it(tmp_path, capsys):
    config = tmp_path / "c.yaml"
    config.write_text("camera: {focal_length_mm: 7.5}\n")
    args = ["database", "build", "--config", str(config), "--cache-dir", str(tmp_path / "db")]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "building the pattern database: regions" in err
    assert ": built (" in err and "serves 1600x1300 at 7.5 mm +- 6 %" in err
    assert main(args) == 0
    assert ": already there (" in capsys.readouterr().err
    assert main(["database", "list", "--config", str(config), "--cache-dir",
                 str(tmp_path / "db")]) == 0
    assert "<- the camera's" in capsys.readouterr().out
