"""Lost-in-space search: image star triangles against catalogue pair separations.

For three image stars i, j, k the three measured separations each select a
band of catalogue pairs from the sorted table (binary search, the k-vector's
job). A catalogue triangle (I, J, K) is a candidate when (I, J), (J, K) and
(I, K) are each in their band and its handedness (sign of the triple product)
equals the image's (a rotation cannot mirror the sky). Triangles are tried in
the order of the Pyramid technique (Mortari et al. 2004): the index gaps
``dj``, ``dk`` grow in the outer loops, so a false or missing star among the
brightest blocks only a few consecutive triads. Each candidate is handed to
the caller, which verifies it against the rest of the field
(tracker.identify.verify); that replaces the pyramid's fourth-star test with
one that uses every star.

Everything is numpy; the join of two bands on their shared star sorts one
band (a few thousand entries) and expands the matches with ``np.repeat``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from tracker.identify.database import BoundDatabase

__all__ = ["triad_order", "TriangleSearch"]


@lru_cache(maxsize=64)
def triad_order(n: int) -> np.ndarray:
    """Image-star index triads (T, 3), i < j < k < n, in the Pyramid order."""
    out = []
    for dj in range(1, n - 1):
        for dk in range(1, n - dj):
            for i in range(0, n - dj - dk):
                out.append((i, i + dj, i + dj + dk))
    triads = np.array(out, dtype=np.int64).reshape(-1, 3)
    triads.flags.writeable = False
    return triads


class TriangleSearch:
    """Finds catalogue triangles matching image triangles.

    Parameters
    ----------
    bound : the database tied to the catalogue epoch.
    tolerance : half-width (radians) of the band each separation selects.
    """

    def __init__(self, bound: BoundDatabase, tolerance: float) -> None:
        self.bound = bound
        self.tolerance = float(tolerance)
        self._n = len(bound.vectors)

    def _band(self, angle: float) -> tuple[np.ndarray, np.ndarray]:
        """Both orientations (first, second) of the catalogue pairs near ``angle``."""
        sep = self.bound.sep
        lo = np.searchsorted(sep, angle - self.tolerance, side="left")
        hi = np.searchsorted(sep, angle + self.tolerance, side="right")
        a = self.bound.a[lo:hi]
        b = self.bound.b[lo:hi]
        return np.concatenate((a, b)), np.concatenate((b, a))

    def candidates(self, vij: float, vjk: float, vik: float, handed: float) -> np.ndarray:
        """Catalogue triangles (C, 3) for image separations ij, jk, ik (radians).

        ``handed`` is the sign of the image triple product b_i . (b_j x b_k).
        """
        ij_first, ij_second = self._band(vij)
        if len(ij_first) == 0:
            return np.empty((0, 3), dtype=np.int32)
        jk_first, jk_second = self._band(vjk)
        ik_first, ik_second = self._band(vik)
        if len(jk_first) == 0 or len(ik_first) == 0:
            return np.empty((0, 3), dtype=np.int32)
        # join (I, J) with (J, K) on J
        order = np.argsort(jk_first, kind="stable")
        jk_sorted = jk_first[order]
        lo = np.searchsorted(jk_sorted, ij_second, side="left")
        hi = np.searchsorted(jk_sorted, ij_second, side="right")
        counts = hi - lo
        total = int(counts.sum())
        if total == 0:
            return np.empty((0, 3), dtype=np.int32)
        which = np.repeat(np.arange(len(counts)), counts)
        offset = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
        cand_i = ij_first[which]
        cand_j = ij_second[which]
        cand_k = jk_second[order[lo[which] + offset]]
        keep = cand_k != cand_i
        cand_i, cand_j, cand_k = cand_i[keep], cand_j[keep], cand_k[keep]
        if len(cand_i) == 0:
            return np.empty((0, 3), dtype=np.int32)
        # (I, K) must be in the ik band
        ik_keys = np.sort(ik_first.astype(np.int64) * self._n + ik_second)
        keys = cand_i.astype(np.int64) * self._n + cand_k
        pos = np.minimum(np.searchsorted(ik_keys, keys), len(ik_keys) - 1)
        keep = ik_keys[pos] == keys
        if not np.any(keep):
            return np.empty((0, 3), dtype=np.int32)
        tri = np.stack((cand_i[keep], cand_j[keep], cand_k[keep]), axis=1)
        v = self.bound.vectors
        triple = np.einsum("ij,ij->i", v[tri[:, 0]], np.cross(v[tri[:, 1]], v[tri[:, 2]]))
        return tri[np.sign(triple) == handed]
