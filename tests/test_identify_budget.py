"""Work, not time, decides lost in space: the same stars give the same answer under any load.

The search is capped by counts (``identify.max_patterns``, ``max_hypotheses``)
and nothing in it reads a clock. These tests show the counts stop it, that a
clock running wild changes nothing, and that the answer is identical while
two other processes keep both cores busy.
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from identify_sim import camera, catalogue, random_rotation, synthetic_stars

from tracker.camera import CameraModel
from tracker.catalogue import Catalogue
from tracker.commands.calibrate import load_stars
from tracker.config import IdentifyConfig, config_from_dict
from tracker.detect import STAR_DTYPE
from tracker.identify import make_solver

TREE = Path(__file__).parent / "data" / "real" / "cedar-solve" / "tree.jpg.centroids.json"


def _random_points(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    stars = np.zeros(n, dtype=STAR_DTYPE)
    stars["x"], stars["y"] = rng.uniform(0, 1599, n), rng.uniform(0, 1299, n)
    stars["flux"] = rng.uniform(100, 5000, n)
    return stars


@pytest.fixture(scope="module", name="tree")
def fixture_tree():
    """tree.jpg's centroid list: seven of its nine brightest sources are foliage, so the
    search needs about 300 patterns; and a solver with a rough camera for it."""
    cfg = config_from_dict({"camera": {"width": 512, "height": 512, "pixel_size_um": 1.0,
                                       "focal_length_mm": 2.88 * 1.05}})
    stars, _, _ = load_stars(TREE, cfg)
    return stars, cfg


def _tree_solver(cfg, **identify):
    ident = IdentifyConfig(**{"focal_search": 0.0, **identify})
    return make_solver(ident, CameraModel.from_config(cfg.camera),
                       Catalogue.from_config(cfg.catalogue))


def test_the_pattern_count_stops_the_search():
    stars = _random_points(20, 1)
    for cap in (1, 37, 200):
        solver = make_solver(IdentifyConfig(max_patterns=cap, focal_search=0.0), camera(16.0),
                             catalogue())
        sol = solver.solve(stars, 0)
        assert (sol.ok, sol.reason, sol.patterns) == (False, "budget", cap)
    # with room for every pattern of the 12 brightest the search ends by itself
    solver = make_solver(IdentifyConfig(max_patterns=10000, focal_search=0.0), camera(16.0),
                         catalogue())
    sol = solver.solve(stars, 0)
    assert sol.reason in ("no_match", "not_verified") and sol.patterns <= 495


def test_the_hypothesis_count_stops_the_search(tree):
    stars, cfg = tree
    full = _tree_solver(cfg).solve(stars, 0)
    assert full.ok and full.hypotheses > 3
    capped = _tree_solver(cfg, max_hypotheses=full.hypotheses - 1).solve(stars, 0)
    assert (capped.ok, capped.reason, capped.hypotheses) == (False, "budget",
                                                             full.hypotheses - 1)
    capped = _tree_solver(cfg, max_patterns=full.patterns - 1).solve(stars, 0)
    assert (capped.ok, capped.reason, capped.patterns) == (False, "budget", full.patterns - 1)


def _answer(sol) -> tuple:
    return (sol.ok, sol.reason, sol.patterns, sol.hypotheses, sol.matched,
            None if sol.R is None else sol.R.tobytes(), sol.focal_length_mm)


def test_a_clock_running_wild_changes_nothing(tree, monkeypatch):
    """Every clock read during the solve jumps ten seconds: the same answer to the last bit.

    (The solver is made first: its catalogue's epoch is "now" unless configured.)
    """
    stars, cfg = tree
    solver = _tree_solver(cfg)
    before = _answer(solver.solve(stars, 0))
    solver.reset()
    solver.lens.reset()
    fake = iter(range(10**9))
    for name in ("perf_counter", "monotonic", "time", "process_time"):
        monkeypatch.setattr(time, name, lambda: 10.0 * next(fake))
    monkeypatch.setattr(time, "perf_counter_ns", lambda: 10_000_000_000 * next(fake))
    assert _answer(solver.solve(stars, 0)) == before


def test_same_answer_while_both_cores_are_busy(tree):
    """Two processes spinning on both cores: the hard frame and 20 simulated ones agree."""
    stars, cfg = tree
    sim_cam = camera(16.0)
    rng = np.random.default_rng(5)
    frames = [synthetic_stars(sim_cam, random_rotation(rng), rng, keep_brightest=6)[0]
              for _ in range(20)]
    solver = _tree_solver(cfg)
    sim = make_solver(IdentifyConfig(), camera(16.0 * 1.05), catalogue())

    def answers():
        solver.reset()
        solver.lens.reset()
        out = [_answer(solver.solve(stars, 0))]
        for f in frames:
            sim.reset()
            sim.lens.reset()
            out.append(_answer(sim.solve(f, 0)))
        return out

    quiet = answers()
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        time.sleep(0.2)
        busy = answers()
    finally:
        for p in burners:
            p.kill()
            p.wait()
    assert busy == quiet
    assert quiet[0][0] and sum(a[0] for a in quiet) >= 18
