"""Scenes beside the stars (tracker.sim.scene) and the seed models at their written
parameters (tracker.sim.seednoise.sky_for_snr)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.camera import CameraModel
from tracker.catalogue import load_catalogue
from tracker.config import load_config
from tracker.sim import random_attitude, render_points, render_sky
from tracker.sim.scene import LABELS, Scene, glare_scene, lunar_scene, particle_tracks

CFG = load_config(None)


@pytest.fixture(scope="module")
def catalogue():
    return load_catalogue(mag_limit=None)


def test_lunar_scene_hides_the_stars_behind_the_ground_and_the_earth(catalogue):
    """No star is rendered whose centre the terrain or the Earth's disc covers, and the
    truth lists what the scene holds."""
    rng = np.random.default_rng(4)
    cam = CameraModel.from_config(CFG.camera)
    for _ in range(3):
        scene = lunar_scene((CFG.camera.height, CFG.camera.width), rng, CFG.sim.full_well_e,
                            cam.f_px, earth_probability=1.0)
        frame = render_sky(CFG.camera, catalogue, random_attitude(rng), CFG.sim, rng,
                           scene=scene)
        s = frame.stars[frame.stars["in_frame"]]
        rows = np.clip(np.rint(s["y"]).astype(int), 0, CFG.camera.height - 1)
        cols = np.clip(np.rint(s["x"]).astype(int), 0, CFG.camera.width - 1)
        assert not np.any(scene.occluded[rows, cols])
        kinds = [b["kind"] for b in frame.truth["scene"]]
        assert kinds[:3] == ["glare", "terrain", "earth"]
        # the ground is lit and fills the lower part of the frame
        assert scene.occluded[-1].mean() > 0.9 and not scene.occluded[0].any()
        assert np.all(frame.labels[scene.occluded & (scene.light_e > 0)] != LABELS["sky"])


def test_glare_from_outside_the_frame_saturates_a_band_along_one_edge(catalogue):
    rng = np.random.default_rng(6)
    shape = (CFG.camera.height, CFG.camera.width)
    scene = glare_scene(shape, rng, CFG.sim.full_well_e, tracks=(50, 50))
    peak_edge = max(scene.light_e[0].max(), scene.light_e[-1].max(),
                    scene.light_e[:, 0].max(), scene.light_e[:, -1].max())
    assert peak_edge >= 1.5 * CFG.sim.full_well_e       # several times full well at the edge
    assert np.median(scene.light_e) < 0.1 * CFG.sim.full_well_e   # and steeply down inside
    assert len(scene.deposit_truth) == 50
    frame = render_sky(CFG.camera, catalogue, random_attitude(rng), CFG.sim, rng, scene=scene)
    full = (1 << CFG.camera.bit_depth) - 1
    assert np.count_nonzero(frame.image >= full) > 1000
    assert sum(f["kind"] == "cosmic_ray" for f in frame.truth["false_sources"]) >= 50


def test_particle_tracks_lengths_follow_isotropic_incidence():
    """Projected length t tan(theta), cos(theta) uniform: a third under t, a long tail."""
    rng = np.random.default_rng(8)
    scene = Scene.empty((400, 400))
    particle_tracks(scene, rng, 2000, thickness_px=1.5, max_length_px=60.0)
    lengths = np.array([t["length_px"] for t in scene.deposit_truth])
    # P(tan theta < 1) = P(cos theta > 1/sqrt 2) = 0.293
    assert np.mean(lengths < 1.5) == pytest.approx(0.293, abs=0.03)
    # P(tan theta > 10) = P(cos theta < 1 / sqrt(101))
    assert np.mean(lengths > 15.0) == pytest.approx(1 / np.sqrt(1 + 10.0 ** 2), abs=0.02)
    assert lengths.max() <= 60.0
    total = sum(t["charge_e"] for t in scene.deposit_truth)
    # charge is conserved but for what falls beyond the frame (a few per cent here)
    assert 0.9 * total < scene.deposits.sum() <= total * (1 + 1e-9)


@pytest.mark.parametrize("cos_range", [(0.99, 1.0), (0.9, 0.99), (0.7, 0.9), (0.3, 0.7),
                                       (0.05, 0.3)])
def test_particle_charge_is_its_path_in_silicon(cos_range):
    """A track's charge is mean_e x straggling x its path sqrt(length^2 + thickness^2),
    at every incidence: charge / (mean_e path) has the straggling's median (lognormal of
    median 1) whatever cos(theta) = thickness / path is. Short near-normal hits once got
    thickness / length times too much (7x at cos 0.99)."""
    thickness, mean_e = 1.5, 900.0
    rng = np.random.default_rng(81)
    scene = Scene.empty((300, 300))
    particle_tracks(scene, rng, 4000, thickness_px=thickness, mean_e=mean_e,
                    max_length_px=1e6)
    length = np.array([t["length_px"] for t in scene.deposit_truth])
    charge = np.array([t["charge_e"] for t in scene.deposit_truth])
    path = np.hypot(length, thickness)
    cos_t = thickness / path
    at = (cos_t >= cos_range[0]) & (cos_t < cos_range[1])
    assert np.count_nonzero(at) >= 40
    straggle = charge[at] / (mean_e * path[at])
    # median of a lognormal(0, 0.4) sample of >= 40: standard error <= 0.08 in log
    assert np.median(straggle) == pytest.approx(1.0, abs=0.2)


@pytest.mark.parametrize("model", ["gaussian_poisson", "salt_pepper", "glare"])
@pytest.mark.parametrize("target", [-5.0, 3.0])
def test_written_parameters_reach_the_target_snr_through_the_sky(model, target):
    """snr_sets: sky keeps the seed's variance 0.15 / density 0.05 / amplitude 1 and finds
    the sky level whose image SNR is the target (the measured SNR of one frame scatters by
    about 0.05 dB)."""
    rng = np.random.default_rng(9)
    sim = dataclasses.replace(CFG.sim, snr_sets="sky", seed_star_gain=20.0)
    xs, ys = rng.uniform(10, 390, 60), rng.uniform(10, 290, 60)
    frame = render_points((300, 400), xs, ys, 10 ** rng.uniform(2.5, 4.0, 60), sim, rng,
                          noise_model=model, snr_db=target)
    noise = frame.truth["noise"]
    written = {"gaussian_poisson": 0.15, "salt_pepper": 0.05, "glare": 1.0}[model]
    assert noise["param"] == pytest.approx(written)
    assert 0.0 < noise["sky"] < 1.0
    assert frame.truth["snr_db"] == pytest.approx(target, abs=0.3)


def test_speckle_cannot_reach_a_low_snr_through_the_sky():
    """Speckle's noise scales with the light: its SNR barely moves with the sky (~8 dB at
    variance 0.15), so -5 dB is refused with the range it can reach."""
    rng = np.random.default_rng(9)
    sim = dataclasses.replace(CFG.sim, snr_sets="sky")
    with pytest.raises(ValueError, match="out of reach for speckle"):
        render_points((100, 100), [50.0], [50.0], [1e4], sim, rng, noise_model="speckle",
                      snr_db=-5.0)


def test_clipped_star_light_does_not_count_in_the_truth_snr():
    """A star far beyond full scale delivers only the light below the clip: its expected
    matched-filter SNR is that of the clipped image, not of the light it would have given."""
    rng = np.random.default_rng(2)
    sim = dataclasses.replace(CFG.sim, seed_star_gain=1.0)
    bright = render_points((60, 60), [30.0], [30.0], [1e6], sim, rng,
                           noise_model="gaussian_poisson", snr_db=None)
    brighter = render_points((60, 60), [30.0], [30.0], [1e7], sim, rng,
                             noise_model="gaussian_poisson", snr_db=None)
    assert bright.stars["saturated"][0] and brighter.stars["saturated"][0]
    # ten times the light, but the clip takes nearly all of it
    assert brighter.stars["mf_snr"][0] < 2.0 * bright.stars["mf_snr"][0]
