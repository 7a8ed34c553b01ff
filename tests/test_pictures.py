"""Pictures for people: overlays checked pixel by pixel, the sky chart's geometry, the
star names against the catalogue, and the replay report as a headless browser draws it."""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from sky_frames import sky_frames

from tracker.attitude import radec_to_vector
from tracker.catalogue import load_catalogue
from tracker.cli import main
from tracker.config import load_config
from tracker.overlay import AMBER, CYAN, GREEN, render_overlay
from tracker.pipeline import Pipeline
from tracker.sky_chart import BORESIGHT_COLOUR, SkyProjection
from tracker.star_names import NAMED_STARS
from tracker.truth import read_truth

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "tests" / "data" / "real" / "cedar-solve"


@pytest.fixture(scope="module", name="sky")
def fixture_sky(tmp_path_factory):
    """Two simulated frames over Orion (16 mm, realistic sensor) with truth files."""
    folder = tmp_path_factory.mktemp("sky")
    sky_frames([(83.8, -5.4, 20.0), (86.0, -3.0, 35.0)], 17, folder)
    return folder


def near(canvas: np.ndarray, x: int, y: int, colour, radius: int = 2, tol: int = 60) -> bool:
    """Whether a pixel within ``radius`` of (x, y) has ``colour`` (BGR) within ``tol``."""
    h, w = canvas.shape[:2]
    patch = canvas[max(y - radius, 0):min(y + radius + 1, h),
                   max(x - radius, 0):min(x + radius + 1, w)].astype(int)
    return bool(np.any(np.all(np.abs(patch - np.array(colour)) <= tol, axis=-1)))


def test_star_names_belong_to_the_catalogue_stars_they_name():
    catalogue = load_catalogue(epoch_year=2000.0)
    row = {int(h): i for i, h in enumerate(catalogue.hip)}
    for hip, name, ra, dec in NAMED_STARS:
        assert hip in row, name
        v = catalogue.vectors[row[hip]]
        sep = math.degrees(math.acos(min(1.0, float(v @ radec_to_vector(*np.radians([ra, dec]))))))
        assert sep * 3600 < 60, (name, hip, sep * 3600)
        assert catalogue.mag[row[hip]] < 4.2, (name, hip)     # V <= 3.5 stars; Hp is close
    assert len({hip for hip, *_ in NAMED_STARS}) == len(NAMED_STARS) == 183


def test_overlay_of_a_solved_frame(sky):
    path = sky / "f0000.png"
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    result = Pipeline(load_config(None)).process(image, 10, 0)
    assert result.solution.ok
    truth = read_truth(path)
    canvas = render_overlay(image, result, path.name, truth)
    assert canvas.shape == (1300, 1600, 3)
    # a dark sky: most of the picture is near black, not grey noise
    assert np.median(canvas) < 30
    stars, hips = result.detections.stars, result.solution.hip
    circled = 0
    for star, hip in zip(stars, hips, strict=True):
        x, y = int(round(star["x"])), int(round(star["y"]))
        r = int(np.clip(3.0 + np.sqrt(max(int(star["npix"]), 1)), 6, 30))
        if y < 90 or y > 1200:          # under the title bar or the legend
            continue
        circled += near(canvas, x + r, y, GREEN if hip else AMBER)
    assert circled >= 0.95 * np.count_nonzero((stars["y"] >= 90) & (stars["y"] <= 1200))
    # each true star is marked where it is
    marked = [near(canvas, int(round(x)), int(round(y)), CYAN, radius=1)
              for x, y in truth.xy if 90 < y < 1200]
    assert len(marked) >= 30 and np.mean(marked) > 0.9
    # the title bar says the result in green; nothing in it is red
    bar = canvas[:50].astype(int)
    assert np.all(np.abs(bar - GREEN) < 40, axis=-1).sum() > 200
    assert not np.any(np.all(np.abs(bar - (70, 70, 255)) < 40, axis=-1))


def test_overlay_of_an_unsolved_frame_says_why_in_red():
    image = cv2.imread(str(REAL / "orion_belt.jpg"), cv2.IMREAD_GRAYSCALE)
    result = Pipeline(load_config(None)).process(image, 8, 0)     # the camera is 1600x1300
    assert result.solution is None and result.solve_reason == "frame_size"
    canvas = render_overlay(image, result, "orion_belt.jpg")
    assert canvas.shape[1] >= 1000                                   # enlarged to be read
    red = np.all(np.abs(canvas[:60].astype(int) - (70, 70, 255)) < 40, axis=-1)
    assert red.sum() > 200                                           # "NOT SOLVED: ..."
    # nothing identified: no green outside the legend (bottom left)
    assert not np.any(np.all(np.abs(canvas.astype(int) - GREEN) < 30, axis=-1)[80:-150])


def test_sky_chart_projection_keeps_north_up_and_east_left():
    centre = radec_to_vector(math.radians(84.0), math.radians(-5.0))
    proj = SkyProjection(centre[None], 900, 560)
    x0, y0, _ = proj(centre)
    north = radec_to_vector(math.radians(84.0), math.radians(-4.0))
    east = radec_to_vector(math.radians(85.0), math.radians(-5.0))
    xn, yn, _ = proj(north)
    xe, ye, _ = proj(east)
    step = proj.scale * 2 * math.tan(math.radians(0.5))             # 1 deg, stereographic
    assert proj.stereographic and abs(xn - x0) < 0.05 and abs((y0 - yn) - step) < 0.05
    assert xe < x0 and abs((x0 - xe) - step * math.cos(math.radians(5.0))) < 0.1
    spread = radec_to_vector(np.radians([10.0, 130.0, 250.0]), np.radians([60.0, -40.0, 0.0]))
    wide = SkyProjection(spread, 900, 560)
    assert not wide.stereographic


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        if os.environ.get("CI"):
            pytest.fail("chromium is missing in CI (.ci/run installs Debian's chromium)")
        pytest.skip("chromium not installed (apt-get install -y chromium); .ci/run installs it")
    return found


def browser(page: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--force-device-scale-factor=1", "--window-size=1000,1600",
         f"--user-data-dir={tmp_path / 'chromium'}", "--disable-background-networking",
         *args, page.as_uri()], capture_output=True, text=True, timeout=120)


def test_report_in_a_headless_browser(sky, tmp_path, capsys):
    frames = tmp_path / "frames"
    shutil.copytree(sky, frames)
    shutil.copyfile(REAL / "orion_belt.jpg", frames / "g_other_camera.jpg")
    (frames / "h_cut.png").write_bytes(b"\x89PNG\r\n\x1a\n cut short")
    report = tmp_path / "report"
    assert main(["replay", str(frames), "--report", str(report), "--quiet"]) == 0
    out = capsys.readouterr()
    assert f"report {report / 'index.html'}" in out.err
    html = (report / "index.html").read_text()
    # static: no script, nothing from the network (the only URL is the SVG namespace)
    assert "<script" not in html
    assert re.findall(r"https?://[^\"' ]+", html) == ["http://www.w3.org/2000/svg"]
    dom = browser(report / "index.html", tmp_path, "--dump-dom")
    assert dom.returncode == 0, dom.stderr[-500:]
    assert dom.stdout.count('<tr class="solved">') == 2
    assert dom.stdout.count('<tr class="unsolved">') == 1
    assert dom.stdout.count('<tr class="unreadable">') == 1
    assert "the frame is not the configured camera" in dom.stdout
    shot = tmp_path / "shot.png"
    drawn = browser(report / "index.html", tmp_path, f"--screenshot={shot}")
    assert drawn.returncode == 0 and shot.exists(), drawn.stderr[-500:]
    picture = cv2.imread(str(shot))
    pink = tuple(int(BORESIGHT_COLOUR[i:i + 2], 16) for i in (5, 3, 1))     # BGR
    dots = [(float(a), float(b)) for a, b in
            re.findall(r'class="boresight" cx="([\d.]+)" cy="([\d.]+)"', html)]
    assert len(dots) == 2
    for x, y in dots:        # the chart is at the page's top left, 1 CSS px = 1 pixel
        assert near(picture, int(round(x)), int(round(y)), pink, radius=1, tol=40), (x, y)
    # the thumbnails are drawn: below the chart there are bright overlay pixels
    assert (report / "thumbs" / "f0000.jpg").exists()
    table = picture[600:]
    assert np.any(np.all(np.abs(table.astype(int) - GREEN) < 60, axis=-1))
