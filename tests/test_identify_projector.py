"""Projector: the catalogue stars in the image for an attitude, in the order of their key
(issue 13: the cone's stars come key-ordered from an index built in that order, with no
sort per search), the same as a scan of every star."""

import math

import numpy as np
import pytest

from tracker.attitude import matrix_from_quat, matrix_from_rotation_vector
from tracker.camera import CameraModel
from tracker.identify.verify import Projector


def _scan(vectors, key, R, camera, key_max):
    """Every star through the camera: indices in the image with key <= key_max, by (key,
    index)."""
    pix = camera.vector_to_pixel(vectors @ R.T)
    keep = camera.in_frame(pix) & (key <= key_max)
    rows = keep.nonzero()[0]
    return rows[np.lexsort((rows, key[rows]))]


@pytest.mark.parametrize("seed", range(4))
def test_key_ordered_projection_is_the_scan_of_every_star(seed):
    rng = np.random.default_rng(seed)
    vectors = rng.normal(size=(30000, 3))
    vectors /= np.linalg.norm(vectors, axis=1)[:, None]
    key = np.round(rng.uniform(0.0, 8.0, len(vectors)), 1)       # many equal keys
    camera = CameraModel(width=1600, height=1300, f_px=5333.3, cx=799.5, cy=649.5, k1=1e-3)
    proj = Projector(vectors, reuse_cone_rad=math.radians(0.5), key=key)
    R = matrix_from_quat(rng.normal(size=4))
    step = matrix_from_rotation_vector(rng.normal(size=3) * math.radians(0.2))
    for frame in range(8):          # a slew: the cone searched, then reused, then again
        key_max = (math.inf, 6.0, 3.3)[frame % 3]
        near, cam, pix = proj.project(R, camera, key_max=key_max)
        assert np.array_equal(near, _scan(vectors, key, R, camera, key_max))
        np.testing.assert_allclose(cam, vectors[near] @ R.T, rtol=0, atol=1e-15)
        np.testing.assert_allclose(pix, camera.vector_to_pixel(cam), rtol=0, atol=1e-9)
        R = step @ R


def test_unkeyed_projection_keeps_index_order():
    rng = np.random.default_rng(7)
    vectors = rng.normal(size=(20000, 3))
    vectors /= np.linalg.norm(vectors, axis=1)[:, None]
    camera = CameraModel(width=1600, height=1300, f_px=2666.7, cx=799.5, cy=649.5)
    R = matrix_from_quat(rng.normal(size=4))
    near, _ = Projector(vectors).predict(R, camera)
    assert np.array_equal(near, _scan(vectors, np.zeros(len(vectors)), R, camera, math.inf))
