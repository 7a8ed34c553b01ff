"""A sky flat to within its 8-bit rounding (the seed's glare model away from the glare): no
noise at all, so a faint star is a few pixels one ADU above the sky, and its threshold is
that of the sparse noise such a sky may hide (tracker.detect.threshold.NoiseTail.constant_sky),
not of white rounding noise that is not there."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from tracker.config import DetectConfig
from tracker.detect import make_detector
from tracker.detect.default import effective_sigma
from tracker.normal import pixel_fractions

SHAPE = (640, 640)
SKY_ADU = 65.0
SIGMA_PX = 1.2
GLARE_CENTRE = (-150.0, -150.0)   # px, beyond the top-left corner
GLARE_RADIUS_PX = 100.0


def _frame(seed: int):
    """Stars of 7-12 ADU on a 40-px grid at random sub-pixel phases over a flat sky, the
    glare's Gaussian (full scale at its centre) reaching in from the top-left corner,
    rounded to 8 bits; returns (image, x, y, the ADU each star shows above the rounded
    sky and glare, glare ADU at each star)."""
    rng = np.random.default_rng(seed)
    grid = np.arange(20.0, 630.0, 40.0)
    xs, ys = (a.ravel() + rng.uniform(-0.5, 0.5, a.size) for a in np.meshgrid(grid, grid))
    flux = np.exp(rng.uniform(math.log(7.0), math.log(12.0), xs.size))
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    r2 = (cols - GLARE_CENTRE[0]) ** 2 + (rows - GLARE_CENTRE[1]) ** 2
    glare = 255.0 * np.exp(-r2 / (2 * GLARE_RADIUS_PX ** 2))
    clean = SKY_ADU + glare
    edges = np.arange(-6, 8) - 0.5
    for x, y, f in zip(xs, ys, flux, strict=True):
        ix, iy = int(round(x)), int(round(y))
        fx, _ = pixel_fractions(edges + ix - x, SIGMA_PX)
        fy, _ = pixel_fractions(edges + iy - y, SIGMA_PX)
        clean[iy - 6: iy + 7, ix - 6: ix + 7] += f * np.outer(fy, fx)
    image = np.clip(np.rint(clean), 0, 255).astype(np.uint8)
    excess = image.astype(np.int32) - np.clip(np.rint(SKY_ADU + glare), 0, 255).astype(np.int32)
    shown = np.array([excess[int(round(y)) - 6: int(round(y)) + 7,
                             int(round(x)) - 6: int(round(x)) + 7].sum()
                      for x, y in zip(xs, ys, strict=True)])
    at = glare[np.rint(ys).astype(int), np.rint(xs).astype(int)]
    return image, xs, ys, shown, at


@pytest.fixture(scope="module")
def found():
    """Over four frames, of the stars where the glare adds under half an ADU: (those
    showing 4 ADU, found of them, those showing 5 or more, found of them), and (false
    detections, detections)."""
    detector = make_detector(DetectConfig(max_stars=1024), SHAPE, 8)
    counts = np.zeros(4, np.int64)
    false = detected = 0
    for seed in range(4):
        image, xs, ys, shown, glare = _frame(seed)
        stars = detector.detect(image).stars
        d = np.hypot(stars["x"][:, None] - xs[None], stars["y"][:, None] - ys[None])
        hit = d.min(axis=0) <= 1.0
        flat = glare < 0.5
        for i, wanted in enumerate((flat & (shown == 4), flat & (shown >= 5))):
            counts[2 * i] += wanted.sum()
            counts[2 * i + 1] += (wanted & hit).sum()
        false += int((d.min(axis=1) > 2.0).sum())
        detected += len(d)
    return counts, (false, detected)


def test_stars_four_pixels_one_above_a_noiseless_sky_are_found(found):
    """A star of 9-10 ADU (matched-filter SNR 7-8 against 1/12 ADU^2 of rounding) shows
    as four pixels one ADU above the sky, a 2 x 2 block mostly: 0 of 214 found with the
    white rounding noise's floor (k times its filtered 0.29 ADU asks for five), 210 with
    the flat sky's own threshold; 747 of 760 of 5 ADU or more either way (the rest
    by another star or the frame's edge)."""
    (four, four_found, more, more_found), _ = found
    assert four >= 150
    assert four_found >= 0.9 * four
    assert more > 500
    assert more_found >= 0.97 * more


def test_the_glare_contours_and_rounding_give_no_false_stars(found):
    """The glare's 8-bit contours across the frame's corner and the stars' rounded wings:
    no detection more than 2 px from a star."""
    _, (false, detected) = found
    assert detected > 0
    assert false == 0


def test_the_flat_sky_threshold_lies_between_three_pixels_and_four():
    """For the 1.2 px PSF's filter and no pixel above the level among 9 tiles' 576 samples
    (rate 3 / 576), at the budget's 5.4 sigma tail: above three pixels one ADU up side by
    side (an L), below four (a 2 x 2 block); the white rounding floor (5.4 x 0.29 ADU x
    the gain) lies above four."""
    from tracker.detect.threshold import NoiseTail, constant_sky_rate

    kernel = cv2.getGaussianKernel(9, effective_sigma(SIGMA_PX), cv2.CV_64F).ravel()
    gain = float(np.sum(kernel ** 2))
    tail = NoiseTail(np.zeros((1, 1, 4), np.intp))
    tail.configure(kernel)
    level = tail.constant_sky(5.4, float(constant_sky_rate(0, 576)), gain)
    k2 = np.outer(kernel, kernel)
    c = len(kernel) // 2
    three = k2[c, c] + k2[c, c + 1] + k2[c + 1, c]
    four = three + k2[c + 1, c + 1]
    assert three < level < four
    assert four < 5.4 * math.sqrt(1 / 12) * gain
