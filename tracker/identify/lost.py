"""Lost-in-space search: four-star image patterns looked up by their scale-free code.

The brightest image stars are taken four at a time in a fixed order
(tracker.identify.patterns.pattern_order); given the detector's flags
(the solver's second pass), those it flagged as doubtful (``DOUBTFUL``:
saturated, elongated, at the frame's edge) only after the others
(:func:`clean_first`). For each four:

1. their pixel positions become unit vectors with the focal length at both
   ends and the centre of the prior [f_low, f_high]; the code (sorted edge
   ratios) over that range, widened by what ``tolerance_px`` of error on
   any edge can do, bounds the catalogue pattern's code;
2. the database returns the patterns in the bins of that box; each is
   checked exactly against the box, its stars are put in correspondence
   with the image's (the assignment whose edges agree best), the focal
   length it implies (image angles over catalogue angles) must lie in the
   prior, and its handedness must be the image's (a rotation cannot mirror
   the sky);
3. each survivor is a :class:`Hypothesis`: the attitude from the four stars
   (Wahba) and the focal length.

The caller verifies hypotheses against the rest of the field and stops at
the first that holds. Work is counted, not timed: :class:`WorkBudget` caps
the patterns looked up and the hypotheses verified, so the same stars give
the same answer on any machine under any load.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from tracker.attitude import solve_wahba
from tracker.camera import CameraModel
from tracker.detect.result import StarFlag
from tracker.identify.database import BoundDatabase
from tracker.identify.patterns import EDGES, code_bounds, codes, edge_angles, match_stars
from tracker.identify.patterns import pattern_order as _pattern_order

__all__ = ["WorkBudget", "Hypothesis", "PatternSearch", "DOUBTFUL", "clean_first"]

# Detector flags that make a source a poor pattern star. On the lunar frames of
# tracker bench detect (8 and 16 mm, 10 frames each, the 20 brightest sources of
# each frame) 24 of the 26 sources so flagged were not stars (particle hits
# saturating on glare, glare and crescent fragments, sources cut by the frame's
# edge), against 157 of the 284 unflagged; a real star so flagged is still verified
# and matched.
DOUBTFUL = StarFlag.SATURATED | StarFlag.ELONGATED | StarFlag.EDGE
_BATCH = 24
_TRIPLES = np.array([(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)], dtype=np.int64)


@dataclass
class WorkBudget:
    """Work allowed and done in one lost-in-space search (counts, never time).

    ``chance`` sums, over the patterns looked up, the expected number of
    wrong catalogue patterns that would pass the lookup by chance: those
    whose code falls in its box (tracker.identify.database.BoundDatabase.
    lookup), times the share of patterns whose size the focal-length prior
    allows, times one half (a random match has the image's handedness half
    the time). It is the union bound's factor in the false-match probability.
    """

    max_patterns: int
    max_hypotheses: int
    patterns: int = 0
    hypotheses: int = 0
    chance: float = 0.0

    @property
    def exhausted(self) -> bool:
        return self.patterns >= self.max_patterns or self.hypotheses >= self.max_hypotheses


@dataclass
class Hypothesis:
    """A candidate: attitude ``R`` (v_cam = R v_icrs) and focal length ``f_px``.

    ``image`` (4,) are the image stars (indices into the search's input) and
    ``stars`` (4,) the database stars they were matched to.
    """

    R: np.ndarray
    f_px: float
    image: np.ndarray
    stars: np.ndarray


class PatternSearch:
    """Generates hypotheses for a frame (module docstring).

    ``tolerance_px``: the largest error expected on the length of a pattern
    edge (centroid errors plus unmodelled distortion); ``min_edge_px``:
    patterns with a shorter edge are not tried.
    """

    def __init__(self, bound: BoundDatabase, tolerance_px: float, min_edge_px: float) -> None:
        self.bound = bound
        self.tolerance_px = float(tolerance_px)
        self.min_edge_px = float(min_edge_px)
        self._max_edge = 2.0 * math.radians(bound.design.region_radius_deg)

    def _quads(self, xy: np.ndarray, vec_narrow: np.ndarray, n: int) -> np.ndarray:
        """The image quadruples worth a lookup, in trying order."""
        quads = _pattern_order(n)
        d = np.hypot(xy[:n, None, 0] - xy[None, :n, 0], xy[:n, None, 1] - xy[None, :n, 1])
        px = d[quads[:, EDGES[:, 0]], quads[:, EDGES[:, 1]]]
        # the database holds no pattern wider than two region radii
        widest = edge_angles(vec_narrow[quads]).max(axis=1)
        return quads[(px.min(axis=1) >= self.min_edge_px) & (widest <= self._max_edge)]

    def hypotheses(self, xy: np.ndarray, camera: CameraModel, f_low: float, f_high: float,
                   n_stars: int, budget: WorkBudget,
                   skip_f: tuple[float, float] | None = None,
                   flags: np.ndarray | None = None) -> Iterator[Hypothesis]:
        """Hypotheses from ``n_stars`` of ``xy`` (m, 2), sorted brightest first: the
        brightest, those ``flags`` (m,) marks doubtful last (:func:`clean_first`).

        ``camera`` gives the principal point and distortion; its focal length
        is replaced by f_low, the centre and f_high (px). Stops when the
        budget's pattern count is reached (the caller counts hypotheses).
        ``skip_f`` (low, high): hypotheses whose focal length lies inside are
        not yielded (already tried by a narrower search). A hypothesis'
        ``image`` indexes ``xy``.
        """
        pick = clean_first(len(xy), n_stars, flags)
        n = len(pick)
        if n < 4:
            return
        xy = xy[pick]
        f_mid = 0.5 * (f_low + f_high)
        cams = [dataclasses.replace(camera, f_px=f) for f in (f_low, f_mid, f_high)]
        vecs = np.stack([c.pixel_to_vector(xy[:n]) for c in cams])     # (3, n, 3)
        quads = self._quads(xy, vecs[2], n)
        if len(quads) == 0:
            return
        edges = edge_angles(vecs[:, quads])                              # (3, Q, 6)
        mid = edges[1]
        slack = (1.0 + codes(mid)) * (self.tolerance_px / (mid.max(axis=1) * f_mid))[:, None]
        low, high = code_bounds(edges, slack)
        spread = np.max(high - low, axis=1) / 2.0
        # catalogue sizes the prior allows for each image pattern's largest edge
        widest = mid.max(axis=1) * f_mid
        allowed = self.bound.size_fraction(widest / (f_high * (1 + spread)),
                                           widest / (f_low * (1 - spread)))
        for start in range(0, len(quads), _BATCH):
            batch = slice(start, start + _BATCH)
            found = self._candidates(mid[batch], low[batch], high[batch], spread[batch],
                                     f_mid, f_low, f_high, skip_f)
            shares = found[3] * allowed[batch] * 0.5
            for q in range(len(shares)):
                if budget.patterns >= budget.max_patterns:
                    return
                budget.patterns += 1
                budget.chance += float(shares[q])
                quad = quads[start + q]
                for stars, f_est in zip(*(a[found[0] == q] for a in found[1:3]), strict=True):
                    ref = self.bound.vectors[stars]
                    if not _same_handedness(cams[1].pixel_to_vector(xy[quad]), ref):
                        continue
                    obs = dataclasses.replace(camera, f_px=float(f_est)).pixel_to_vector(xy[quad])
                    yield Hypothesis(R=solve_wahba(obs, ref), f_px=float(f_est),
                                     image=pick[quad], stars=stars)

    def _candidates(self, mid, low, high, spread, f_mid, f_low, f_high, skip_f):
        """Catalogue patterns matching a batch of image patterns.

        Returns (which image pattern of the batch, catalogue stars (C, 4) in
        the image stars' order, implied focal length (C,), and the batch's
        lookup shares (B,)).
        """
        bound = self.bound
        cand, box, shares = bound.lookup(low, high)
        cat = bound.patterns[cand]
        cat_edges = edge_angles(bound.vectors[cat])
        cat_codes = codes(cat_edges)
        inside = np.all((cat_codes >= low[box]) & (cat_codes <= high[box]), axis=1)
        box, cat, cat_edges = box[inside], cat[inside], cat_edges[inside]
        perm, err = match_stars(mid[box], cat_edges)
        f_est = f_mid * mid[box].sum(axis=1) / cat_edges.sum(axis=1)
        s = spread[box]
        ok = (err <= s) & (f_est >= f_low * (1 - s)) & (f_est <= f_high * (1 + s))
        if skip_f is not None:
            ok &= (f_est < skip_f[0]) | (f_est > skip_f[1])
        stars = np.take_along_axis(cat, perm, axis=1)
        return box[ok], stars[ok], f_est[ok], shares


def clean_first(count: int, n: int, flags: np.ndarray | None = None) -> np.ndarray:
    """Indices of (at most) ``n`` of ``count`` stars, in the order lost in space uses them.

    The stars are sorted brightest first; ``flags`` (count,) are the
    detector's (tracker.detect.result.StarFlag; None: the ``n`` brightest).
    The brightest stars without a ``DOUBTFUL`` flag come first, brightest
    first; doubtful stars (the brightest of them first) only fill the list
    when fewer than ``n`` stars are clean. Pattern stars are drawn this way
    (a few bright false stars the detector flagged then cost no pattern, where
    in brightness order every pattern holding one of them is wasted and real
    stars behind them may be left out of the ``n``), and so are the stars a
    hypothesis is tested on (the pattern stars lead them): the choice depends
    on no hypothesis, so the false-match odds (tracker.identify.verify) hold.
    """
    if flags is None:
        return np.arange(min(n, count))
    doubtful = (np.asarray(flags)[:count] & DOUBTFUL) != 0
    return np.argsort(doubtful, kind="stable")[:n]


def _same_handedness(img: np.ndarray, ref: np.ndarray) -> bool:
    """Do the two four-star sets (4, 3) turn the same way (their most solid triangle)?"""
    det_img = np.einsum("ij,ij->i", img[_TRIPLES[:, 0]],
                        np.cross(img[_TRIPLES[:, 1]], img[_TRIPLES[:, 2]]))
    k = int(np.argmax(np.abs(det_img)))
    a, b, c = _TRIPLES[k]
    return bool(np.sign(det_img[k]) == np.sign(np.dot(ref[a], np.cross(ref[b], ref[c]))))
