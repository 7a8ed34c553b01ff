"""Match image stars to catalogue stars predicted by an attitude; the false-match odds.

Projection: catalogue stars within the field's half-diagonal of the
optical axis go through the camera model; those landing in the image are
the predictions. Each image star takes the nearest prediction within a radius
(in pixels); a prediction claimed twice goes to the nearer star.

Probability that a wrong attitude verifies (the model behind ``prob_false``):
under a wrong hypothesis the catalogue stars land at places unrelated to the
image stars, so each of the ``n`` image stars that were not used to form the
hypothesis falls within ``r`` pixels of one of the ``m`` predictions with
probability p = min(1, m * pi r^2 / (W H)) (uniform positions). The chance
that ``k`` or more of them match is the binomial tail
P(X >= k | n, p). Every wrong hypothesis met in the frame is another
chance, so the per-frame probability is bounded by ``trials * tail`` (union
bound), where ``trials`` is the expected number of wrong hypotheses: in
lost in space the catalogue patterns whose code fell in a lookup's box by
chance (tracker.identify.lost.WorkBudget.chance), in tracking one.
"""

from __future__ import annotations

import math

import numpy as np

from tracker.astrometry.aberration import aberrate
from tracker.camera import CameraModel
from tracker.identify.skyindex import DecSorted

__all__ = ["Projector", "match_nearest", "binomial_tail", "false_match_probability"]

_DENSE_PAIRS = 4096   # match_nearest compares all pairs up to this many


class Projector:
    """Predicts where catalogue stars fall in the image for an attitude R and a lens.

    ``vectors`` (N, 3) are ICRS unit vectors (the catalogue's or the
    database's). Only stars in the declination band of the field are
    looked at (tracker.identify.skyindex). With ``reuse_cone_rad`` > 0 the
    cone is searched that much wider and reused, with its stars' vectors,
    while the optical axis stays within that angle of the cone's (tracking:
    three predictions a frame, and frames after frame, from one search).
    With ``key`` (N,), e.g. magnitudes, the cone's stars are kept in the
    order of their key (ascending; by index where equal) and a projection
    may take only those up to a limit of it: the vectors are indexed in that
    order once, so a cone's stars come in it sorted by their place, with no
    sort by key per search.
    """

    def __init__(self, vectors: np.ndarray, reuse_cone_rad: float = 0.0,
                 key: np.ndarray | None = None) -> None:
        self.vectors = np.ascontiguousarray(vectors, dtype=np.float64)
        self.reuse = float(reuse_cone_rad)
        self.key = None if key is None else np.asarray(key, dtype=np.float64)
        # the searched vectors: in key order (by index where equal) when keyed, with the
        # permutation back to ``vectors`` and the keys in that order
        self._by_key = None if key is None else np.argsort(self.key, kind="stable")
        self._searched = (self.vectors if self._by_key is None
                          else np.ascontiguousarray(self.vectors[self._by_key]))
        self._sorted_key = None if key is None else self.key[self._by_key]
        self.index = DecSorted(self._searched)
        # (axis, radius, indices, their vectors, their keys) of the last cone searched
        self._cone: tuple | None = None

    def _near(self, axis: np.ndarray, radius: float) -> tuple:
        """(indices, vectors, keys or None) of (at least) the vectors within ``radius`` of
        ``axis``: ascending indices, or by key (class docstring)."""
        if self.reuse > 0.0 and self._cone is not None:
            c_axis, c_radius, *found = self._cone
            if c_radius >= radius and float(np.dot(axis, c_axis)) >= math.cos(c_radius - radius):
                return found
        place = np.sort(self.index.cone(axis, radius + self.reuse))
        if self._by_key is None:
            found = [place, self._searched[place], None]
        else:
            found = [self._by_key[place], self._searched[place], self._sorted_key[place]]
        if self.reuse > 0.0:
            self._cone = (np.array(axis, dtype=np.float64), radius + self.reuse, *found)
        return found

    @staticmethod
    def _cone_radius(camera: CameraModel) -> float:
        """An angle from the optical axis beyond every image corner.

        The farthest corner's distance from the principal point, undistorted
        to first order (rho / (1 + k1 rho^2 + k2 rho^4), exact for k1 = k2 = 0),
        1 % and two pixels added: distortion that bends it more than 1 % at
        the corner is far beyond any lens the solver serves.
        """
        dx = max(camera.cx + 0.5, camera.width - 0.5 - camera.cx)
        dy = max(camera.cy + 0.5, camera.height - 0.5 - camera.cy)
        rho = math.hypot(dx, dy) / camera.f_px
        r2 = rho * rho
        rho /= max(0.5, 1.0 + r2 * (camera.k1 + camera.k2 * r2))
        return 1.01 * math.atan(rho) + 2.0 / camera.f_px

    def project(self, R: np.ndarray, camera: CameraModel, margin_px: float = 0.0,
                beta: np.ndarray | None = None, key_max: float = math.inf,
                extra: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(indices into ``vectors``, camera-frame vectors (m, 3), pixels (m, 2)) of the
        stars in the image, ``margin_px`` inside its edge; with a ``key``, those whose
        key is at most ``key_max``, in its order.

        With ``beta`` (the observer's velocity / c, ICRS) the stars are placed at
        their apparent directions (tracker.astrometry.aberration; at most 25
        arcsec from the astrometric ones, inside the cone's two pixels of
        slack) and ``R`` is the ICRS attitude. ``extra`` (k, 3): directions
        projected with them as they are (already apparent), those in the image
        last, with index -1.
        """
        near, seen, keys = self._near(R[2], self._cone_radius(camera))
        if keys is not None and key_max < math.inf:
            upto = int(np.searchsorted(keys, key_max, side="right"))
            near, seen = near[:upto], seen[:upto]
        if beta is not None:
            seen = aberrate(seen, beta)
        if extra is not None and len(extra):
            seen = np.concatenate((seen, extra))
            near = np.concatenate((near, np.full(len(extra), -1, near.dtype)))
        cam = seen @ R.T
        pix = camera.vector_to_pixel(cam)
        inside = camera.in_frame(pix, margin_px)
        return near[inside], cam[inside], pix[inside]

    def predict(self, R: np.ndarray, camera: CameraModel, margin_px: float = 0.0,
                beta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Indices (into ``vectors``) and pixel positions (m, 2) of stars in the image
        (:meth:`project`)."""
        near, _, pix = self.project(R, camera, margin_px, beta)
        return near, pix


def match_nearest(xy: np.ndarray, pred: np.ndarray, radius: float) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """Pair image stars ``xy`` (n, 2) with predictions ``pred`` (m, 2) within ``radius``.

    Returns (index into pred per image star, -1 if none; distance in pixels).
    Each image star takes its nearest prediction; a prediction claimed by
    more than one star goes to the nearest claim, the others get -1.

    Cost O((n + m) log m + pairs): predictions are sorted by x and each star
    looks only at those within ``radius`` in x, so tracking 200 stars
    against 1,000 predictions compares a few thousand pairs, not 200,000.
    Up to ``_DENSE_PAIRS`` pairs (a windowed frame's 30 stars and 30
    predictions) all pairs are compared at once instead: a third of the
    numpy calls, the same pairs.
    """
    n = len(xy)
    idx = np.empty(n, np.int64)         # (empty and fill: np.full's wrapper costs more)
    idx.fill(-1)
    dist = np.empty(n)
    dist.fill(np.inf)
    if n == 0 or len(pred) == 0:
        return idx, dist
    order = np.argsort(pred[:, 0], kind="stable")
    if n * len(pred) <= _DENSE_PAIRS:
        # predictions in x order, as below: equal distances resolve alike
        px, py = pred[order, 0], pred[order, 1]
        d2 = np.square(xy[:, None, 0] - px) + np.square(xy[:, None, 1] - py)
        d2[~(d2 <= radius * radius)] = np.inf               # out of reach (or NaN)
        stars = np.arange(n)
        near = d2.argmin(axis=1)                            # each star's nearest
        best = d2[stars, near]
        # a prediction claimed by several stars goes to the nearest claim
        claims = np.where(near[:, None] == np.arange(len(pred)), d2, np.inf)
        won = (best < np.inf) & (claims.argmin(axis=0)[near] == stars)
        idx[won] = order[near[won]]
        dist[won] = np.sqrt(best[won])
        return idx, dist
    px = pred[order, 0]
    lo = np.searchsorted(px, xy[:, 0] - radius, side="left")
    hi = np.searchsorted(px, xy[:, 0] + radius, side="right")
    counts = hi - lo
    total = int(counts.sum())
    if total == 0:
        return idx, dist
    star = np.repeat(np.arange(n), counts)
    first = np.cumsum(counts) - counts
    cand = order[lo[star] + np.arange(total) - first[star]]
    d2 = np.square(xy[star, 0] - pred[cand, 0]) + np.square(xy[star, 1] - pred[cand, 1])
    near = d2 <= radius * radius
    star, cand, d2 = star[near], cand[near], d2[near]
    if len(star) == 0:
        return idx, dist
    # each star's nearest candidate: sort by (star, d2) and keep the first per star
    by_star = np.lexsort((d2, star))
    keep = np.ones(len(by_star), dtype=bool)
    keep[1:] = star[by_star][1:] != star[by_star][:-1]
    best_star, best_pred, best_d2 = star[by_star][keep], cand[by_star][keep], d2[by_star][keep]
    # a prediction claimed by several stars goes to the nearest claim
    by_pred = np.lexsort((best_d2, best_pred))
    win = np.ones(len(by_pred), dtype=bool)
    win[1:] = best_pred[by_pred][1:] != best_pred[by_pred][:-1]
    winners = by_pred[win]
    idx[best_star[winners]] = best_pred[winners]
    dist[best_star[winners]] = np.sqrt(best_d2[winners])
    return idx, dist


def binomial_tail(k: int, n: int, p: float) -> float:
    """P(X >= k) for X ~ Binomial(n, p)."""
    if k <= 0:
        return 1.0
    if k > n:
        return 0.0
    if p >= 1.0:
        return 1.0
    total = 0.0
    for i in range(k, n + 1):
        total += math.comb(n, i) * p ** i * (1.0 - p) ** (n - i)
    return min(1.0, total)


def false_match_probability(matched_extra: int, tested: int, predictions: int, radius_px: float,
                            area_px: float, trials: float) -> float:
    """Per-frame probability that a wrong attitude gives this many matches (module docstring).

    ``matched_extra`` of the ``tested`` image stars outside the hypothesis
    matched one of ``predictions`` catalogue stars within ``radius_px``;
    ``trials`` wrong hypotheses may have been met in the frame.
    """
    p = min(1.0, predictions * math.pi * radius_px * radius_px / area_px)
    return min(1.0, trials * binomial_tail(matched_extra, tested, p))
