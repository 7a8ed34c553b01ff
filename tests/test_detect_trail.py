"""The line-spread fit (tracker.detect.trail) on trails drawn from its own model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tracker.detect.trail import TrailFit, normal_cdf

SIGMA = 1.2      # px, the PSF
SKY, NOISE = 100.0, 3.0


def _trails(rng, centres, smear, flux):
    """A frame (float64) of trails of ``flux`` each, centred on ``centres`` (n, 2) and
    swept by ``smear`` (2,), px, over a flat sky with Gaussian noise; the line-spread
    function integrated over each pixel's area by 4 x 4 sub-samples."""
    image = np.full((200, 300), SKY)
    length = math.hypot(*smear)
    u = np.asarray(smear) / length
    sub = (np.arange(4) - 1.5) / 4
    for cx, cy in centres:
        y, x = np.mgrid[int(cy) - 15:int(cy) + 16, int(cx) - 15:int(cx) + 16]
        xs = x[..., None, None] + sub[None, None, None, :] - cx
        ys = y[..., None, None] + sub[None, None, :, None] - cy
        a, b = xs * u[0] + ys * u[1], ys * u[0] - xs * u[1]
        g = (np.exp(-0.5 * (b / SIGMA) ** 2) / (math.sqrt(2 * math.pi) * SIGMA)
             * (normal_cdf((a + length / 2) / SIGMA) - normal_cdf((a - length / 2) / SIGMA))
             / length)
        image[y, x] += flux * g.mean(axis=(2, 3))
    return image + rng.normal(0.0, NOISE, image.shape)


@pytest.mark.parametrize("smear", [(5.0, 2.0), (-3.0, 7.5), (9.0, -9.0)])
def test_the_fit_spends_its_work_on_the_pixels_its_model_reaches(smear, monkeypatch):
    """Trails of 5.4-12.7 px from a detection 2.5 px along from the centre: the centres hold to the
    truth, and the fit's band holds only the pixels within L / 2 + 3 sigma along and
    3 sigma across of the trail (issue 13: the band had 2 px along and 1 px across to
    spare around the detection, 40-50 % more pixels in each step)."""
    rng = np.random.default_rng(31)
    grid = np.stack(np.meshgrid(np.arange(50, 251, 50), np.arange(50, 151, 50)), -1)
    truth = grid.reshape(-1, 2) + rng.uniform(-5, 5, (15, 2))   # 15 trails 40-60 px apart
    image = _trails(rng, truth, smear, 20000.0)
    start = truth + 2.5 * np.asarray(smear) / math.hypot(*smear)   # toward the trail's end
    fit = TrailFit(SIGMA)
    pixels = []
    step = TrailFit._step

    def counted(self, table, runs, z):
        pixels.append(table.shape[1])
        return step(self, table, runs, z)

    monkeypatch.setattr(TrailFit, "_step", counted)
    centres = fit.refine(image, start, np.tile(smear, (len(truth), 1)))
    error = np.hypot(*(centres - truth).T)
    assert error.max() < 0.1, error
    length = math.hypot(*smear)
    # a band's pixel centres within a rectangle of (L + 6 sigma) x 6 sigma: its area and
    # at most half a pixel's overhang around it
    reach = (length + 6 * SIGMA + 1.0) * (6 * SIGMA + 1.0)
    assert pixels[0] <= len(truth) * reach, (pixels[0] / len(truth), reach)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_normal_cdf_is_the_written_out_approximation_bit_for_bit(dtype):
    """normal_cdf (the trail model's erf, its steps written into two arrays) gives the very
    numbers of Abramowitz and Stegun 7.1.26 written out as one expression, in the input's
    type: the trail fit's float32 band depends on each of them (issue 13)."""
    z = (np.random.default_rng(3).normal(0.0, 3.0, 5000)).astype(dtype)
    z[:4] = (0.0, -0.0, 1e-30, -40.0)
    t = 1.0 / (1.0 + (0.3275911 / math.sqrt(2.0)) * np.abs(z))
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027
                                                                           + t * 1.061405429))))
    want = 0.5 + 0.5 * np.copysign(1.0 - poly * np.exp(-0.5 * z * z), z)
    got = normal_cdf(z)
    assert got.dtype == want.dtype == dtype
    assert np.array_equal(got, want)
