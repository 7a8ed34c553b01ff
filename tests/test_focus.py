"""`tracker focus` on replayed frames: a lens sharp on the left and soft on the right."""

import cv2
import numpy as np
import pytest

from tracker.cli import main
from tracker.config import load_config
from tracker.detect.psf import FWHM_PER_SIGMA
from tracker.focus import draw_map, focus_map, terminal_lines
from tracker.sim import render_points, write_frame
from tracker.sim.psf_shapes import PsfShape

WIDTH, HEIGHT = 800, 600
SHARP = PsfShape("gaussian", 1.0)
SOFT = PsfShape("gaussian", 2.0, ellipticity=0.2, angle_rad=0.5)


def half_frame(rng, psf, x0, cfg):
    """Stars in columns x0 .. x0 + 360 only, drawn with ``psf`` on the realistic sensor."""
    n = 45
    xs = rng.uniform(x0 + 20, x0 + 360, n)
    ys = rng.uniform(20, HEIGHT - 20, n)
    electrons = rng.uniform(3000, 12000, n)
    return render_points((HEIGHT, WIDTH), xs, ys, electrons, cfg.sim, rng, psf=psf)


@pytest.fixture(scope="module", name="frames")
def fixture_frames(tmp_path_factory):
    """Two frames whose left half has a sharp round PSF (FWHM 2.35 px) and right half a soft,
    elongated Moffat one (FWHM 4.71 px), plus a configuration naming the 800x600 sensor."""
    folder = tmp_path_factory.mktemp("focus")
    cfg = load_config(None)
    rng = np.random.default_rng(5)
    for i in range(2):
        left = half_frame(rng, SHARP, 0, cfg)
        right = half_frame(rng, SOFT, WIDTH // 2, cfg)
        left.image[:, WIDTH // 2:] = right.image[:, WIDTH // 2:]
        write_frame(left, folder / "frames", f"f{i}")
    config = folder / "camera.yaml"
    config.write_text(f"camera:\n  width: {WIDTH}\n  height: {HEIGHT}\n")
    return folder / "frames", config


def test_focus_maps_the_sharp_and_the_soft_half(tmp_path, frames, capsys):
    folder, config = frames
    png = tmp_path / "focus.png"
    assert main(["focus", "--config", str(config), "--replay", str(folder),
                 "--png", str(png), "--grid", "4x3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 * 4                    # a header and three rows per frame
    for block in (lines[0:4], lines[4:8]):
        assert block[0].startswith(("f0.png: FWHM", "f1.png: FWHM"))
        grid = np.array([[float(v) for v in row.split()] for row in block[1:]])
        assert grid.shape == (3, 4)
        sharp = FWHM_PER_SIGMA * SHARP.sigma_px
        soft = FWHM_PER_SIGMA * SOFT.sigma_px
        # every cell within 6 % of its half's FWHM (the optics', pixel width removed)
        assert np.all(np.abs(grid[:, :2] / sharp - 1) < 0.06), grid
        assert np.all(np.abs(grid[:, 2:] / soft - 1) < 0.06), grid
    picture = cv2.imread(str(png))
    assert picture is not None and picture.shape == (HEIGHT, WIDTH, 3)
    # the soft half is drawn red, the sharp half green
    left, right = picture[:, :WIDTH // 2].astype(int), picture[:, WIDTH // 2:].astype(int)
    assert (left[..., 1] - left[..., 2]).mean() > 30
    assert (right[..., 2] - right[..., 1]).mean() > 30


def test_focus_map_reads_the_ellipticity_and_leaves_empty_cells_blank():
    rng = np.random.default_rng(1)
    stars = np.zeros(40, dtype=[("x", "f8"), ("y", "f8"), ("sigma_px", "f8"),
                                ("ellipticity", "f8")])
    stars["x"] = rng.uniform(0, 399, 40)             # only the left half of the frame
    stars["y"] = rng.uniform(0, 599, 40)
    stars["sigma_px"] = 1.5
    stars["ellipticity"] = 0.3
    fm = focus_map(stars, (HEIGHT, WIDTH), (2, 2))
    assert np.allclose(fm.fwhm_px[:, 0], FWHM_PER_SIGMA * 1.5)
    assert np.allclose(fm.ellipticity[:, 0], 0.3)
    assert np.isnan(fm.fwhm_px[:, 1]).all() and fm.stars[:, 1].sum() == 0
    assert fm.stars.sum() == fm.total == 40
    assert terminal_lines(fm)[1].split()[1] == "--"
    empty = focus_map(stars[:0], (HEIGHT, WIDTH), (2, 2))
    assert terminal_lines(empty)[0] == "no stars bright and isolated enough"
    image = np.zeros((HEIGHT, WIDTH), np.uint16)
    assert draw_map(image, 10, empty).shape == (HEIGHT, WIDTH, 3)


@pytest.mark.parametrize("argv, message", [
    (["--grid", "0x3"], "1 to 32 cells"),
    (["--grid", "four"], "expected COLSxROWS"),
    (["--png", "/nonexistent/dir/focus.png"], "--png"),
])
def test_focus_mistakes_are_one_line_and_exit_2(frames, capsys, argv, message):
    folder, config = frames
    assert main(["focus", "--config", str(config), "--replay", str(folder), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
