"""Whether a spot is a particle's short track rather than a star: elongated and sharp across.

A particle's charge is deposited along its path without the optics' blur:
across the track it is as narrow as its diffusion (about 0.45 px), along it
a line of its projected length. A star is the frame's PSF, whatever its
brightness, so its light's shape is the frame's stars' shape. Under a sharp
PSF (sigma 0.6-0.8 px) a track one to four pixels long is about as wide
overall as a star, and the moments' tests (tracker.detect.spot_shapes),
which must allow for the worst sub-pixel phase, pass it; its light's
second-order shape at its own phase does not.

On the 5 x 5 pixels around the pixel nearest each spot's centre the light
S (background subtracted, ADU) is modelled as

    S = a P + bx Px + by Py + hxx Pxx + hxy Pxy + hyy Pyy + noise,

P the pixel-integrated round Gaussian of the PSF's sigma at the spot's
centre (unit flux) and Px ... Pyy its first and second derivatives by the
centre. A Gaussian light of covariance sigma^2 I + dC is, to first order in
dC, P + (dCxx Pxx + 2 dCxy Pxy + dCyy Pyy) / 2 (the heat equation), so
``shear`` = ((hxx - hyy) / a, hxy / a) is (dCxx - dCyy, 2 dCxy) / 2: how
much longer than wide the light is, px^2, measured at the spot's own pixel
phase (the derivatives carry it) and with its centring error absorbed by
Px and Py. A star's is its frame's stars' (0 for a round PSF, the PSF's own
ellipticity otherwise), a track's grows as its length squared over 24 and
points along it; the spot's light across that direction, dC there, is the
frame's stars' for a star (a trailed star, a blend of two keep the PSF's
width across) and below it for a track.

A spot is a track (:func:`track_spots`) when its shear differs from the
frame's stars' (the median over its bright unsaturated spots) by more than
:data:`Z_LINE` standard errors (chi-square of two degrees of freedom: a
star's chance 1 in 10^4; each standard error includes :data:`_FIELD_SHEAR`
of the PSF's variance, what the lens's field may change a star by), by
more than :data:`_LINE_SHEAR` of that variance (a track at least 1.5 px
long under a sharp PSF), and its light across is narrower than the stars'
by :data:`Z_ACROSS` standard errors (a star a track touches keeps its own
width across: at 2 a star with a track 1.5 px from its centre was lost).
Each pixel's variance is noise^2 + g a P (the background's and the
star's own shot noise, g ADU^2 per ADU: tracker.detect.significance's
convention). The frame's stars set the reference only when at least
:data:`LINE_REFERENCE_SPOTS` of them are bright, and a frame whose stars are
trailed (their shear over the PSF's variance beyond
:data:`_TRAILED_SHEAR`) is not tested for elongation: a trail is no
second-order change of the PSF. With fewer bright spots (a lunar frame of a
particle event, its few bright stars outnumbered by tracks) the PSF measured
on the frame's own stars sets the stars' shape: its ellipticity e at angle t
is a shear e sigma^2 (cos 2t, sin 2t) about the fit's round sigma^2 and a
trace of 0, known less well than the median of many bright spots, so each
standard error takes :data:`_PSF_FIELD_SHEAR` of the PSF's variance (the
field's and as much for the few stars' measurement; across the elongation,
where the reference is the trace less half the shear, half of it beside the
field's) and the shear's limit is :data:`Z_PSF_LINE` (a star's chance 1 in
10^5).

A hit of 1-1.5 px, round, is no longer than it is wide: its charge cloud
alone, with no optics to blur it, is narrower overall than the stars, its
trace (dCxx + dCyy) / 2 below theirs by sigma^2 - 0.45^2 (a charge's
diffusion, 0.45 px) to first order, half the PSF's variance at sigma 0.65
px. A spot is such a hit (:func:`track_spots` given the stars the PSF was
measured on: isolated, round, unsaturated; not the bright spots at large,
which beside the Moon are broad bumps as often) when its trace lies below
those stars' median by :data:`Z_NARROW` standard errors (one-sided, a
star's chance 1 in 10^5; with :data:`_FIELD_SHEAR` of the PSF's variance
as above) and by :data:`_NARROW_TRACE` of the PSF's variance (the deficit
of a charge cloud under a PSF of sigma 0.52 px and wider). A trailed frame's
stars are wider than its PSF, not narrower, and a hit is narrower than them
too, so this test runs on trailed frames as well.

A saturated spot is fitted on its unclipped pixels (``usable``): a pixel
light clipped at full scale says only "at least full scale" (censored, as
tracker.detect.fit does), and the model of the unclipped ring about a
clipped core is the same. A star's clipped core is round and centred on
its PSF, its ring the PSF's wings; a track's core is as elongated as its
light and its ring falls off as fast as its charge's diffusion.

A saturated spot of one clipped pixel is also judged narrow on the fit that
takes that pixel at its floor, full scale (:func:`floor_fit`): its light is at
least that, and the fit's coefficients are linear in each pixel's light, so
the trace is a ratio of two linear functions of it, monotonic; where a second
fit with that pixel's light doubled reads no wider (more light in it only
narrows the spot: the pixel at the centre of a PSF of sigma 0.5 px and wider),
the trace at the floor bounds the spot's from above. A star's so bounded
trace reads wider than its own (3000 stars of sigma 0.55-1.3 px, clipped 1.1-4
times below their peak, at most 2 standard errors narrow), a charge cloud's
stays narrow: a hit's censored fit, without its brightest pixel, says little of
its width.

A saturated spot's clipped core is judged by its own shape too
(:func:`clipped_lines`), on untrailed frames. A star's is a superlevel set of
its PSF: an ellipse of the PSF's axis ratio, centred on it. Its pixels (each
a unit square) have second moments whose minor over major variance is the
PSF's (1 - e) / (1 + e) for ellipticity e, less the pixels' coarseness: at
:data:`CLIP_MIN_PIXELS` pixels and more, a round PSF's core reads at least 4 / 9
at the worst pixel phase (a 2 x 3 block). A particle's clipped core is a
line, its variance across the diffusion's and along it the path's. A core
whose ratio lies below :data:`_CLIP_RATIO` of the PSF's is a track (a third
of a round PSF's: three quarters of the worst phase's 4 / 9). The core is
the clipped pixels of the 5 x 5 4-connected to the clipped pixel nearest
the centre, so saturated ground or a neighbour's core beside it is not
counted.

The 6 x 6 normal equations are solved by Gauss-Jordan elimination written
out over the spots (no LAPACK call, whose BLAS threads would spin on the
core the detector's own slab thread runs on).
"""

from __future__ import annotations

import math
from statistics import NormalDist

import cv2
import numpy as np

from tracker.detect.order import median
from tracker.detect.significance import SHOT_ADU
from tracker.normal import erf

__all__ = ["CLIP_MIN_PIXELS", "LINE_RADIUS", "LINE_REFERENCE_SNR", "LINE_REFERENCE_SPOTS",
           "LINE_USABLE", "Z_ACROSS", "Z_LINE", "Z_NARROW", "Z_PSF_LINE", "clipped_lines",
           "floor_fit", "line_fit", "track_spots"]

LINE_RADIUS = 2                # the 5 x 5 pixels around the spot's central pixel
LINE_USABLE = 16               # a saturated spot is fitted on at least this many of them
Z_LINE = math.sqrt(-2.0 * math.log(1e-4))   # chi(2) at a star's chance of 1 in 10^4: 4.29
Z_ACROSS = 3.0                 # ... and narrower across than the frame's stars by this
_FIELD_SHEAR = 0.05            # a star's shear varies across the field by this x sigma^2
_LINE_SHEAR = 0.25             # a track's shear beyond the stars' is at least this x sigma^2
Z_NARROW = NormalDist().inv_cdf(1.0 - 1e-5)   # a star's trace this far below: 1 in 10^5
_NARROW_TRACE = 0.25           # a hit's trace below the stars' by at least this x sigma^2
LINE_REFERENCE_SNR = 30.0          # spots this significant, unsaturated, set the stars' shear
LINE_REFERENCE_SPOTS = 5           # ... when there are at least this many
_TRAILED_SHEAR = 0.25          # the stars' shear over sigma^2 beyond this: a trailed frame
Z_PSF_LINE = math.sqrt(-2.0 * math.log(1e-5))   # against the PSF's own shape: 1 in 10^5
_PSF_FIELD_SHEAR = 0.10        # ... each standard error with this x sigma^2: the field's
                               # _FIELD_SHEAR and as much for the few stars' measurement
CLIP_MIN_PIXELS = 6            # a clipped core judged by its shape from this many pixels
_CLIP_RATIO = 1.0 / 3.0        # ... a line below this x the PSF's minor/major variance
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _axis_terms(phase: np.ndarray, sigma_px: float) -> np.ndarray:
    """(m, 3, 5): a unit Gaussian of ``sigma_px`` integrated over the 5 unit pixels of
    one axis, and its first and second derivatives by the centre; ``phase`` (m,) is the
    centre's offset from the middle pixel's centre, px. The 6 pixel edges are shared."""
    edges = np.arange(-LINE_RADIUS - 0.5, LINE_RADIUS + 1.0) - phase[:, None]
    u = edges / sigma_px                                        # (m, 6)
    pdf = np.exp(-0.5 * u * u) / _SQRT_2PI
    terms = np.stack([0.5 * erf(u / math.sqrt(2.0)), -pdf / sigma_px,
                      -u * pdf / sigma_px ** 2], axis=1)         # (m, 3, 6) at the edges
    return terms[:, :, 1:] - terms[:, :, :-1]


# the basis P, Px, Py, Pxx, Pxy, Pyy as (y term, x term) of :func:`_axis_terms`
_ROW_TERMS = [0, 0, 1, 0, 1, 2]
_COL_TERMS = [0, 1, 0, 2, 1, 0]


def _basis(phase_x: np.ndarray, phase_y: np.ndarray, sigma_px: float) -> np.ndarray:
    """(m, 6, 25): P, Px, Py, Pxx, Pxy, Pyy on each spot's 5 x 5, row-major."""
    m = len(phase_x)
    terms = _axis_terms(np.concatenate([phase_x, phase_y]), sigma_px)
    rows = terms[m:, _ROW_TERMS]                                 # (m, 6, 5)
    cols = terms[:m, _COL_TERMS]
    return np.einsum("mky,mkx->mkyx", rows, cols).reshape(m, 6, -1)


_SECOND = slice(3, 6)       # hxx, hxy, hyy among the coefficients
_SECOND_UNIT = np.eye(6)[:, _SECOND]    # their columns of the identity


def _solve(gram: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solutions (m, 6) of symmetric positive definite ``gram`` (6, 6, m) against
    ``rhs`` (6, m), and the block (m, 3, 3) of the inverses over the second-order
    coefficients, by Gauss-Jordan elimination over the spots at once (no LAPACK;
    a positive definite matrix needs no pivoting). The spots run along the last axis,
    so each step's rows are contiguous."""
    k, _, m = gram.shape
    aug = np.empty((k, k + 4, m))
    aug[:, :k] = gram
    aug[:, k] = rhs
    aug[:, k + 1:] = _SECOND_UNIT[:, :, None]
    for j in range(k):
        row = aug[j, j:] / aug[j, j]
        aug[:, j:] -= aug[:, j, None] * row
        aug[j, j:] = row
    return aug[:, k].T, aug[_SECOND, k + 1:].transpose(2, 0, 1)


def line_fit(light: np.ndarray, phase_x: np.ndarray, phase_y: np.ndarray,
             noise: np.ndarray, sigma_px: float, shot_adu: float = SHOT_ADU,
             usable: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The model's coefficients (m, 6) and the covariance (m, 3, 3) of its second-order
    ones, hxx, hxy, hyy (module docstring).

    ``light``: (m, 25) background-subtracted ADU of the 5 x 5 pixels around
    the pixel nearest each spot's centre, row-major; ``phase_x``, ``phase_y``:
    (m,) the centre's offset from that pixel's centre, px; ``noise``: (m,) the
    pixel noise without the spot's light, ADU; ``sigma_px``: the frame's PSF sigma;
    ``usable``: (m, 25) bool, the pixels fitted (default all): a pixel light clipped at
    full scale says only "at least full scale" and is left out (censored), so a
    saturated spot is judged on its unclipped pixels (at least :data:`LINE_USABLE`).
    """
    basis = _basis(np.asarray(phase_x, float), np.asarray(phase_y, float), sigma_px)
    p = basis[:, 0]
    fitted = p if usable is None else p * usable
    flux = np.maximum(np.einsum("mi,mi->m", fitted, light)
                      / np.einsum("mi,mi->m", fitted, p), 0.0)
    # each pixel's terms and light over its noise: the normal equations' weights
    root_weight = 1.0 / np.sqrt(np.square(noise)[:, None] + (shot_adu * flux)[:, None] * p)
    if usable is not None:
        root_weight *= usable
    basis *= root_weight[:, None, :]
    # row by row: einsum's one product over the whole stack takes 200 KB of iteration buffers
    gram = np.empty((6, 6, len(basis)))
    for k in range(6):
        np.einsum("mi,mli->lm", basis[:, k], basis, out=gram[k])
    return _solve(gram, np.einsum("mki,mi->km", basis, light * root_weight))


def track_spots(coef: np.ndarray, cov: np.ndarray, reference: np.ndarray,
                sigma_px: float, measured: np.ndarray | None = None,
                fitted: np.ndarray | None = None, clipped: np.ndarray | None = None,
                ellipticity: float = 0.0, psf_shear: np.ndarray | None = None,
                floor: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The spots that are particles' tracks (module docstring): (m,) bool.

    ``coef``, ``cov``: :func:`line_fit`'s; ``reference``: the spots (m,) bool
    that may set the frame's stars' shear (bright, unsaturated); ``measured``: the
    spots (m,) bool the frame's PSF was measured on (stars, isolated and round), whose
    width sets the stars' for the test of spots narrower overall (none: not tested);
    ``fitted``: the spots (m,) bool whose fit is judged (none: all; a saturated spot
    with too few unclipped pixels is not); ``clipped``: each spot's 5 x 5 pixels
    (m, 25) bool, row by row, that light clipped, judged by :func:`clipped_lines`
    against the PSF's ``ellipticity`` when the frame's stars set an untrailed shape
    (none: not judged); ``psf_shear``: the PSF measured on this frame's stars, its
    ((Cxx - Cyy) / 2, Cxy) about sigma^2 I (px^2), sets the stars' shape when too few
    bright spots do (none: not tested then); ``floor``: :func:`floor_fit`'s coefficients
    and covariances of some saturated spots and their indices among the m, whose traces
    there bound theirs from above: judged narrow on those too (none: not)."""
    fit, scale, value, var = _shapes(coef, cov)
    variance = sigma_px ** 2
    shape = _stars_shape(value, reference & fit, variance)
    field, across, z_line = _FIELD_SHEAR, _FIELD_SHEAR, Z_LINE
    if shape is None and psf_shear is not None:
        shape = _psf_shape(psf_shear, variance)
        # across, the reference is the trace less the shear along: half the shear's spread
        field, across, z_line = (_PSF_FIELD_SHEAR, math.hypot(_FIELD_SHEAR, 0.5 * _PSF_FIELD_SHEAR),
                                 Z_PSF_LINE)
    out = np.zeros(len(value), bool)
    if shape is not None:
        out = _elongated(coef, cov, value, var, shape, variance, scale, (field, across), z_line)
    if measured is not None:
        traces = value[measured & fit, 2]
        out |= _narrow(value, var, traces, variance)
        if floor is not None:
            floor_fitted, _, floor_value, floor_var = _shapes(*floor[:2])
            out[floor[2]] |= floor_fitted & _narrow(floor_value, floor_var, traces, variance)
    out &= fit if fitted is None else fit & fitted
    if shape is not None and clipped is not None:
        out |= clipped_lines(clipped, ellipticity)
    return out


def _shapes(coef: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, ...]:
    """Of :func:`line_fit`'s ``coef`` and ``cov``: which spots have a positive flux (m,),
    1 / flux (m,), and their shear and trace (dCxx - dCyy) / 2, dCxy, (dCxx + dCyy) / 2
    with those's variances (m, 3) each."""
    flux = coef[:, 0]
    fit = flux > 0.0
    scale = 1.0 / np.where(fit, flux, 1.0)
    combos = np.array([[1, 0, -1], [0, 1, 0], [1, 0, 1]], float)
    value = np.einsum("jk,mk->mj", combos, coef[:, _SECOND]) * scale[:, None]
    var = np.einsum("jk,mkl,jl->mj", combos, cov, combos) * np.square(scale)[:, None]
    return fit, scale, value, var


def floor_fit(light: np.ndarray, clipped: np.ndarray, phase_x: np.ndarray,
              phase_y: np.ndarray, noise: np.ndarray, sigma_px: float,
              shot_adu: float = SHOT_ADU) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`line_fit` of spots with one pixel clipped, that pixel taken at its floor
    (its ``light`` as delivered, full scale less the background), and whether its trace
    bounds the spot's from above (module docstring): (coefficients (m, 6), covariances
    (m, 3, 3), bounded (m,) bool). ``light``, ``phase_x``, ``phase_y``, ``noise`` as
    :func:`line_fit`'s; ``clipped``: (m, 25) bool, one pixel a row."""
    m = len(light)
    # both fits in one stack: each spot's is its own, the same to the bit as alone
    coef, cov = line_fit(np.concatenate([light, light + clipped * light]),
                         np.tile(phase_x, 2), np.tile(phase_y, 2), np.tile(noise, 2),
                         sigma_px, shot_adu)
    fit, _, value, _ = _shapes(coef, cov)
    return coef[:m], cov[:m], fit[:m] & fit[m:] & (value[m:, 2] <= value[:m, 2])


def clipped_lines(clipped: np.ndarray, ellipticity: float) -> np.ndarray:
    """The spots whose clipped core is a line, not a star's PSF (module docstring):
    (m,) bool. ``clipped``: each spot's 5 x 5 pixels (m, 25) bool, row by row, that
    light clipped; ``ellipticity``: the PSF's, (a^2 - b^2) / (a^2 + b^2)."""
    out = np.zeros(len(clipped), bool)
    side = 2 * LINE_RADIUS + 1
    limit = _CLIP_RATIO * (1.0 - ellipticity) / (1.0 + ellipticity)
    for i in np.flatnonzero(np.count_nonzero(clipped, axis=1) >= CLIP_MIN_PIXELS):
        count, labels = cv2.connectedComponents(
            clipped[i].reshape(side, side).astype(np.uint8), connectivity=4)
        rows, cols = np.nonzero(labels)
        nearest = np.argmin(np.square(rows - LINE_RADIUS) + np.square(cols - LINE_RADIUS))
        core = labels[rows, cols] == labels[rows[nearest], cols[nearest]]
        if np.count_nonzero(core) < CLIP_MIN_PIXELS:
            continue
        y, x = rows[core].astype(float), cols[core].astype(float)
        # each pixel a unit square: its own 1/12 px^2 on either axis
        cxx, cyy = x.var() + 1.0 / 12.0, y.var() + 1.0 / 12.0
        cxy = np.mean((x - x.mean()) * (y - y.mean()))
        half_sum = 0.5 * (cxx + cyy)
        spread = math.hypot(0.5 * (cxx - cyy), cxy)
        out[i] = half_sum - spread < limit * (half_sum + spread)
    return out


def _stars_shape(value: np.ndarray, ref: np.ndarray, variance: float) -> np.ndarray | None:
    """The frame's stars' shear and trace (3,), the ``ref`` spots' medians; None when
    fewer than ``LINE_REFERENCE_SPOTS`` set it or the frame is trailed (their shear
    beyond ``_TRAILED_SHEAR`` of the PSF's ``variance``)."""
    if np.count_nonzero(ref) < LINE_REFERENCE_SPOTS:
        return None
    shape = np.array([median(value[ref, j]) for j in range(3)])
    if math.hypot(shape[0], shape[1]) > _TRAILED_SHEAR * variance:
        return None
    return shape


def _psf_shape(psf_shear: np.ndarray, variance: float) -> np.ndarray | None:
    """The stars' shear and trace (3,) of the PSF measured on the frame (the fit's
    round sigma^2 is its own, so a trace of 0); None when it is trailed (as
    :func:`_stars_shape`)."""
    if math.hypot(psf_shear[0], psf_shear[1]) > _TRAILED_SHEAR * variance:
        return None
    return np.array([psf_shear[0], psf_shear[1], 0.0])


def _elongated(coef: np.ndarray, cov: np.ndarray, value: np.ndarray, var: np.ndarray,
               shape: np.ndarray, variance: float, scale: np.ndarray,
               field_share: tuple[float, float], z_line: float) -> np.ndarray:
    """The spots whose shear differs from the stars' ``shape`` (:func:`_stars_shape` or
    :func:`_psf_shape`) by ``z_line`` standard errors and that are narrower across than
    they are by ``Z_ACROSS`` (module docstring), each standard error with the
    reference's own spread added, ``field_share`` (shear, across) of the PSF's
    ``variance``. ``value``: each spot's shear and trace (m, 3), ``var`` their
    variances, ``scale`` 1 / flux."""
    diff = value - shape[None, :]
    field = (field_share[0] * variance) ** 2
    z_shear = np.hypot(diff[:, 0] / np.sqrt(var[:, 0] + field),
                       diff[:, 1] / np.sqrt(var[:, 1] + field))
    # across the elongation: its unit normal (nx, ny) = (-sin t, cos t) for the shear's
    # angle 2t; dC_nn / 2 = nx^2 hxx + nx ny hxy + ny^2 hyy over the flux
    angle = 0.5 * np.arctan2(diff[:, 1], diff[:, 0])
    nx, ny = -np.sin(angle), np.cos(angle)
    across = np.stack([nx * nx, nx * ny, ny * ny], axis=1)
    across_value = np.einsum("mk,mk->m", across, coef[:, _SECOND]) * scale
    across_ref = (shape[2] - np.cos(2 * angle) * shape[0] - np.sin(2 * angle) * shape[1]) / 2
    across_var = np.einsum("mk,mkl,ml->m", across, cov, across) * np.square(scale)
    z_across = (across_ref - across_value) / np.sqrt(across_var + (field_share[1] * variance) ** 2)
    shear = np.hypot(diff[:, 0], diff[:, 1])
    return (z_shear > z_line) & (z_across > Z_ACROSS) & (shear > _LINE_SHEAR * variance)


def _narrow(value: np.ndarray, var: np.ndarray, traces: np.ndarray,
            variance: float) -> np.ndarray:
    """The spots whose trace, (dCxx + dCyy) / 2, lies below the median of the stars'
    ``traces`` by ``Z_NARROW`` standard errors and ``_NARROW_TRACE`` of the PSF's
    variance (module docstring); none when fewer than ``LINE_REFERENCE_SPOTS`` stars
    set it."""
    if len(traces) < LINE_REFERENCE_SPOTS:
        return np.zeros(len(value), bool)
    deficit = median(traces) - value[:, 2]
    field = (_FIELD_SHEAR * variance) ** 2
    return ((deficit > _NARROW_TRACE * variance)
            & (deficit > Z_NARROW * np.sqrt(var[:, 2] + field)))
