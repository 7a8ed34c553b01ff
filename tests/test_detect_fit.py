"""The pixel-integrated Gaussian fit's parts (tracker.detect.fit) against their definitions."""

import numpy as np

from tracker.detect.fit import PixelGaussianFit


def test_the_normal_equations_are_solved_from_the_matrix_upper_triangle_alone():
    """The fit fills only the normal matrix's upper triangle (row-major, (m, 9)); its solve
    must read nothing else: with NaN in the lower left, the steps of 200 random positive
    definite systems match np.linalg.solve (to 1e-9 relative), and a singular and an
    indefinite matrix get no step."""
    rng = np.random.default_rng(7)
    m = 200
    a = rng.normal(size=(m, 3, 3))
    full = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(3)
    full[0] = np.outer([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])     # singular
    full[1] = np.diag([1.0, -1.0, 2.0])                       # indefinite
    grad = rng.normal(size=(m, 3))
    upper = full.copy()
    upper[:, [1, 2, 2], [0, 0, 1]] = np.nan
    step = PixelGaussianFit._solve(upper.reshape(m, 9), grad)
    truth = np.linalg.solve(full[2:], grad[2:, :, None])[:, :, 0].T
    np.testing.assert_allclose(step[:, 2:], truth, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(step[:, :2], 0.0)


def test_the_fractions_never_go_negative_so_the_model_needs_no_floor():
    """The weights take the model as it is (no max(model, 0)): the interpolated fractions
    are at least 0 for centres anywhere the table reaches and beyond it (clamped), at PSF
    sigmas 0.5-3.5 px, so the model, a flux of at least 1 times two of them, is too."""
    offsets = np.linspace(-15.0, 15.0, 30001)
    for sigma, radius in ((0.5, 2), (1.2, 4), (3.5, 11)):
        fit = PixelGaussianFit(len(offsets), 2 * radius + 1)
        fit.configure(radius, sigma)
        fx, fy, _, _ = fit._fractions(np.stack((offsets, offsets[::-1])))
        assert fx.min() >= 0.0 and fy.min() >= 0.0, sigma
