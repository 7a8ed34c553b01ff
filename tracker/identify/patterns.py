"""Four-star patterns and their scale-free code.

A pattern is four stars. Its six pairwise angles, sorted and divided by
the largest, give five numbers in (0, 1]: the pattern's *code*. The code
does not change when the whole pattern is scaled, rotated or moved, so an
image pattern measured with a focal length a few percent off has (nearly)
the code of its catalogue pattern. What a wrong focal length does change
is second order: the gnomonic projection stretches radially by 1/cos^2 and
tangentially by 1/cos of the off-axis angle, so a relative focal-length
error e changes the pattern's shape by about e sin^2(off-axis angle);
:func:`code_bounds` takes that into account by evaluating the code at both
ends of the focal-length range.

The code is the sorted-edge-ratio key of Tetra (G. Brown, K. Stubis 2017,
"Tetra: Star Identification with Hash Tables", AIAA/USU SmallSat); the
lookup, the correspondence and everything around them are this project's.

Angles are radians. Edges are ordered as ``EDGES`` (star index pairs).
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

__all__ = ["EDGES", "edge_angles", "codes", "code_bounds", "match_stars", "pattern_order"]

EDGES = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)], dtype=np.int64)
_EDGE_OF = {(int(a), int(b)): k for k, (a, b) in enumerate(EDGES)}
_PERMS = np.array(list(itertools.permutations(range(4))), dtype=np.int64)
# _PERM_EDGES[p, k]: the edge of the permuted pattern that image edge k maps to
_PERM_EDGES = np.array([[_EDGE_OF[tuple(sorted((int(p[a]), int(p[b]))))] for a, b in EDGES]
                        for p in _PERMS], dtype=np.int64)


def edge_angles(vectors: np.ndarray) -> np.ndarray:
    """Angles (..., 6) between the stars of patterns given as unit vectors (..., 4, 3).

    Computed from the chord (2 asin(|a - b| / 2)), exact for small angles.
    """
    diff = vectors[..., EDGES[:, 0], :] - vectors[..., EDGES[:, 1], :]
    chord = np.sqrt(np.einsum("...i,...i->...", diff, diff))
    return 2.0 * np.arcsin(np.minimum(chord * 0.5, 1.0))


def codes(edges: np.ndarray) -> np.ndarray:
    """The code (..., 5) of patterns with edge angles (..., 6): sorted ratios to the largest."""
    s = np.sort(edges, axis=-1)
    return s[..., :5] / s[..., 5:6]


def code_bounds(edges_by_focal: np.ndarray, slack: np.ndarray) -> tuple[np.ndarray,
                                                                         np.ndarray]:
    """(low, high) bounds (..., 5) of the code of patterns measured under several focal lengths.

    ``edges_by_focal`` (F, ..., 6) holds the same image patterns' edge angles
    computed with F focal lengths spanning the prior (its ends and centre);
    the true code lies between their smallest and largest codes, widened
    by ``slack`` (..., 5), the effect of centroid errors.
    """
    c = codes(edges_by_focal)
    return c.min(axis=0) - slack, c.max(axis=0) + slack


def match_stars(image_edges: np.ndarray, cat_edges: np.ndarray) -> tuple[np.ndarray,
                                                                          np.ndarray]:
    """The star correspondence of an image pattern with candidate catalogue patterns.

    ``image_edges`` (C, 6) or (6,) and ``cat_edges`` (C, 6) are edge angles.
    For each candidate, of the 24 ways to assign the image's four stars to
    the catalogue's, the one whose edges (each divided by the pattern's edge
    sum, so the scale drops out) differ least in the worst edge. Returns
    the permutation (C, 4) (image star i is catalogue star perm[i]) and that
    worst difference (C,), relative to the edge sum.
    """
    img = np.broadcast_to(image_edges, cat_edges.shape)
    img = img / img.sum(axis=-1, keepdims=True)
    cat = cat_edges / cat_edges.sum(axis=-1, keepdims=True)
    # (C, 24, 6): catalogue edge that each image edge maps to under each permutation
    err = np.abs(cat[:, _PERM_EDGES] - img[:, None, :]).max(axis=-1)
    best = np.argmin(err, axis=1)
    return _PERMS[best], err[np.arange(len(best)), best]


@lru_cache(maxsize=16)
def pattern_order(n: int) -> np.ndarray:
    """Index quadruples (Q, 4), a < b < c < d < n, in the order lost in space tries them.

    Quadruples whose faintest star is brighter come first (all of the
    brightest four, then those adding the fifth, ...); among equals, the
    brighter the other three the earlier. A false or missing star among the
    brightest thus blocks only a few consecutive tries.
    """
    out = []
    for d in range(3, n):
        rest = sorted(itertools.combinations(range(d), 3), key=lambda t: (sum(t), t))
        out += [(*t, d) for t in rest]
    quads = np.array(out, dtype=np.int64).reshape(-1, 4)
    quads.flags.writeable = False
    return quads
