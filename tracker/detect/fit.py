"""Star centres from a fit of the pixel-integrated Gaussian PSF: no pixel-phase bias.

A windowed centroid is exact for a well-sampled Gaussian, but a PSF of
sigma 0.6-0.9 px is undersampled: the light in a pixel is the PSF
integrated over it, and any centroid of the sampled values is pulled
toward the pixel centre or edge depending on where the star falls (the
pixel-phase bias, tens of millipixels at sigma 0.6 px). Fitting the model
the pixels really follow removes it:

    mu(c, r) = F * wx(c) * wy(r),   wx(c) = the Gaussian of sigma s integrated over pixel c

(tracker.normal.pixel_fractions; s is the frame's measured PSF sigma,
tracker.detect.psf). Unknowns are the centre (x, y) and the flux F; the
background is known (the detector subtracted it). Gauss-Newton steps
minimise sum (S - mu)^2 / var, var = noise^2 + max(mu, 0) ADU^2 (the
background's noise plus the star's own shot noise counted as one ADU^2 per
ADU, i.e. gains near 1 e-/ADU; the weights only set how pixels share the
information, so a gain several times off costs a few per cent of
precision, never bias). Pixels at or above ``saturation`` are left out
(censored): a clipped pixel says only "at least full scale", so saturated
stars are centred on their unclipped wings by the same fit. Pixels beyond
the frame's edge are left out the same way (they say nothing): a star cut
by the edge is fitted on the part the frame holds, its centre free to lie
beyond the edge.

Every step is clamped to ``max_shift`` px from the window's centre pixel.

The model is separable, mu = F fy(r) fx(c), so every entry of the normal
matrix and the gradient is a bilinear form a(r)^T M b(c) of a per-window
matrix M (the weights W, or W times the residual) with outer products of
the per-axis fractions and their derivatives: sum W jx jx = F^2 sum_r
fy^2 (W dfx^2)_r, and so on. Each Gauss-Newton step therefore passes over
the windows' pixels a handful of times (model, weights, weighted residual,
two batched matrix products), not once per entry of the normal matrix.
The per-axis fractions and their derivatives come from a table made once
per (radius, sigma) by :meth:`PixelGaussianFit.configure`: both are
functions of one variable, the pixel's centre less the star's, tabulated
every 1/``_TABLE_PER_PX`` px and interpolated linearly (error below 1e-6
of the star's light per pixel for sigma >= 0.5 px; the centres move by
less than 1e-4 px), a handful of operations a step instead of an error
function. The 3 x 3 normal equations are solved in closed form (the
adjugate of the symmetric matrix), all stars at once.

All arrays are preallocated for ``chunk`` windows of up to ``max_side``^2
pixels (the table's entries for them too); the per-axis fractions and their
products are the only per-call temporaries (a few kB).
"""

from __future__ import annotations

import math

import numpy as np

from tracker.normal import spaced_pixel_fractions

__all__ = ["PixelGaussianFit"]

_MIN_VAR = 1e-6
_TABLE_PER_PX = 256      # table nodes per px of the fractions' argument
_TABLE_REACH_PX = 2.0    # the table runs this far beyond the window's radius


def _adjugate_index() -> np.ndarray:
    """Flat indices (a, b, c, d) (4, 9) of a symmetric 3 x 3 matrix A with adj(A) = A[a] A[b]
    - A[c] A[d], row-major (adj_ij = the cofactor C_ji), each read from A's upper triangle
    (the only one :meth:`PixelGaussianFit._normal_equations` fills)."""
    i, j = np.divmod(np.arange(9), 3)
    row, col = np.divmod(np.array(((j + 1) % 3 * 3 + (i + 1) % 3, (j + 2) % 3 * 3 + (i + 2) % 3,
                                   (j + 1) % 3 * 3 + (i + 2) % 3, (j + 2) % 3 * 3 + (i + 1) % 3)),
                         3)
    return np.minimum(row, col) * 3 + np.maximum(row, col)


_ADJ = _adjugate_index()


class PixelGaussianFit:
    """Fits flux and centre of a pixel-integrated Gaussian to square windows."""

    def __init__(self, chunk: int, max_side: int, iterations: int = 3) -> None:
        self.chunk = int(chunk)
        self.max_side = int(max_side)
        self.iterations = int(iterations)
        size = self.chunk * self.max_side ** 2
        self._flat = {name: np.zeros(size, np.float64)
                      for name in ("model", "weight", "resid", "usable")}
        self._rows = np.zeros(self.chunk * self.max_side * 3, np.float64)   # W b(c), R b(c)
        self._axis = np.zeros(self.chunk * self.max_side * 3, np.float64)   # b(c)
        self._normal = np.zeros((self.chunk, 9), np.float64)   # upper triangle, row-major
        self._grad = np.zeros((self.chunk, 3), np.float64)
        self._at = np.zeros(2 * self.chunk * self.max_side, np.float64)
        self._node = np.zeros(2 * self.chunk * self.max_side, np.intp)
        self._entries = np.zeros(2 * self.chunk * self.max_side * 4, np.float64)
        self._state = np.zeros((3, self.chunk), np.float64)   # x, y, F
        self.side = 0
        self.sigma = 0.0
        # the table (module docstring) for the largest window: a smaller one is a view
        nodes = 2 * int(math.ceil((self.max_side // 2 + _TABLE_REACH_PX) * _TABLE_PER_PX)) + 1
        self._table_buffer = np.zeros((nodes, 4), np.float64)
        self._nodes_buffer = np.zeros(self.max_side, np.float64)
        self._table = self._table_buffer[:0]
        self._nodes = self._nodes_buffer[:0]
        self._last = 0.0

    def configure(self, radius: int, sigma: float) -> None:
        """Windows of (2 radius + 1)^2 pixels; PSF sigma ``sigma`` px (optical, not integrated)."""
        self.side = 2 * int(radius) + 1
        if self.side > self.max_side:
            raise ValueError(f"window side {self.side} exceeds the fit's {self.max_side}")
        self.sigma = float(sigma)
        # the table: fraction and d fraction / d centre of a pixel whose centre lies t px
        # from the star's, and their slopes to the next node, t from -reach to reach
        reach = int(radius) + _TABLE_REACH_PX
        t = np.arange(-reach, reach + 1.5 / _TABLE_PER_PX, 1.0 / _TABLE_PER_PX)
        # pixel i spans t_i -+ 0.5: its edges lie on one grid, _TABLE_PER_PX nodes apart
        # (all these are whole multiples of 1/_TABLE_PER_PX: exact in float64)
        edges = np.concatenate((t - 0.5, t[-_TABLE_PER_PX:] + 0.5))
        frac, dfrac = spaced_pixel_fractions(edges, _TABLE_PER_PX, self.sigma)
        values = np.stack((frac, dfrac), axis=1)                       # (K, 2)
        self._table = self._table_buffer[:len(t) - 1]
        self._table[:, 0::2] = values[:-1]
        self._table[:, 1::2] = np.diff(values, axis=0)
        self._last = float(len(t) - 2)
        # the pixels' centres in table units from the table's start
        self._nodes = self._nodes_buffer[:self.side]
        self._nodes[:] = (np.arange(-radius, radius + 1, dtype=np.float64) + reach) * _TABLE_PER_PX

    def _views(self, m: int) -> dict:
        side = self.side
        k = side * side
        return {name: buf[: m * k].reshape(m, side, side) for name, buf in self._flat.items()}

    def _columns(self, m: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(m, side, n) views of the per-axis factors b(c) and of W b(c) (or R b(c))."""
        size = m * self.side * n
        shape = (m, self.side, n)
        return self._axis[:size].reshape(shape), self._rows[:size].reshape(shape)

    def _normal_equations(self, m: int, fx, dfx, fy, dfy, flux, v: dict) -> None:
        """The normal matrix's upper triangle (m, 9, row-major; the lower left is left
        unset) and grad (m, 3) over (x, y, F) from the weights ``v["weight"]`` and the
        weighted residuals ``v["resid"]`` (module docstring: bilinear forms).

        Each row factor meets all the column products it needs in one
        contraction (fy^2 with W dfx^2, W dfx fx and W fx^2; fy dfy with the
        last two; fy with R dfx and R fx).
        """
        normal, grad = self._normal[:m], self._grad[:m]
        cols, wb = self._columns(m, 3)
        np.multiply(dfx, dfx, out=cols[..., 0])
        np.multiply(dfx, fx, out=cols[..., 1])
        np.multiply(fx, fx, out=cols[..., 2])
        np.matmul(v["weight"], cols, out=wb)            # (W dfx^2, W dfx fx, W fx^2)
        fy2, fydy = fy * fy, fy * dfy
        f, f2 = flux, flux * flux
        by_fy2 = np.einsum("ij,ijk->ik", fy2, wb)       # (xx, xf, ff) / (F^2, F, 1)
        by_fydy = np.einsum("ij,ijk->ik", fydy, wb[..., 1:])   # (xy, yf) / (F^2, F)
        np.multiply(f2, by_fy2[:, 0], out=normal[:, 0])
        np.multiply(f2, by_fydy[:, 0], out=normal[:, 1])
        np.multiply(f, by_fy2[:, 1], out=normal[:, 2])
        np.multiply(f2, np.einsum("ij,ij->i", dfy * dfy, wb[..., 2]), out=normal[:, 4])
        np.multiply(f, by_fydy[:, 1], out=normal[:, 5])
        normal[:, 8] = by_fy2[:, 2]
        cols, rb = self._columns(m, 2)
        cols[..., 0], cols[..., 1] = dfx, fx
        np.matmul(v["resid"], cols, out=rb)             # (R dfx, R fx)
        by_fy = np.einsum("ij,ijk->ik", fy, rb)
        np.multiply(by_fy[:, 0], f, out=grad[:, 0])
        np.multiply(np.einsum("ij,ij->i", dfy, rb[..., 1]), f, out=grad[:, 1])
        grad[:, 2] = by_fy[:, 1]

    def run(self, m: int, signal: np.ndarray, raw: np.ndarray, x: np.ndarray, y: np.ndarray,
            noise: np.ndarray, saturation: float | np.ndarray, max_shift: float,
            inside: np.ndarray | None = None, flux0: np.ndarray | None = None) -> np.ndarray:
        """Refine centres ``x``, ``y`` (m,) in place; returns the fitted fluxes (m,).

        ``signal`` (m, side^2): background-subtracted windows, ADU; ``raw``
        the same pixels as delivered (for the saturation test); centres are
        px from each window's centre pixel; ``noise`` (m,) the background's
        pixel noise, ADU; ``saturation`` (ADU) one level for all or one per
        star (m,), inf for a star none of whose pixels is to be left out.
        ``inside`` (m, side^2), if given, is false for the
        window's pixels beyond the frame's edge: they are left out like
        clipped ones, so a star cut by the edge is fitted on the light the
        frame holds and its centre may lie beyond the edge (up to
        ``max_shift``). ``flux0`` (m,): the fluxes to start from (None: each
        window's sum), so that a run continues one before it. A star whose
        normal matrix is singular keeps its centre.
        """
        v = self._views(m)
        side = self.side
        grid = (m, side, side)
        state = self._state[:, :m]
        pos, flux = state[:2], state[2]
        if flux0 is None:
            np.sum(signal, axis=1, out=flux)
            np.maximum(flux, 1.0, out=flux)
        else:
            flux[:] = flux0
        usable = v["usable"]
        if getattr(saturation, "ndim", 0):
            saturation = saturation[:m, None, None]
        np.less(raw.reshape(grid), saturation, out=usable)   # 1.0 where not clipped
        if inside is not None:
            np.multiply(usable, inside.reshape(grid), out=usable)
        noise2 = np.maximum(np.square(noise[:m]), _MIN_VAR)[:, None, None]
        normal, grad = self._normal[:m], self._grad[:m]
        w, model, resid = v["weight"], v["model"], v["resid"]
        pos[0], pos[1] = x, y
        for _ in range(self.iterations):
            fx, fy, dfx, dfy = self._fractions(pos)
            np.multiply((flux[:, None] * fy)[:, :, None], fx[:, None, :], out=model)
            # weights 1 / (noise^2 + model), zero for clipped pixels (the model, a flux of
            # at least 1 times fractions interpolated between non-negative nodes, is never
            # negative)
            np.add(model, noise2, out=w)
            np.divide(usable, w, out=w)
            np.subtract(signal.reshape(grid), model, out=resid)
            np.multiply(resid, w, out=resid)
            self._normal_equations(m, fx, dfx, fy, dfy, flux, v)
            step = self._solve(normal, grad)
            if step is None:
                break
            np.add(state, step, out=state)
            np.maximum(pos, -max_shift, out=pos)    # np.clip's Python layers cost more
            np.minimum(pos, max_shift, out=pos)
            np.maximum(flux, 1.0, out=flux)
        x[:], y[:] = pos[0], pos[1]
        return flux

    def _fractions(self, pos: np.ndarray) -> tuple[np.ndarray, ...]:
        """fx, fy, dfx, dfy (m, side): the fractions of the light of stars at ``pos`` (2, m)
        px from the windows' centre pixels in each pixel column and row, and their
        derivatives by the centre, from the table (module docstring)."""
        m = pos.shape[1]
        at = self._at[: 2 * m * self.side].reshape(2, m, self.side)
        np.subtract(self._nodes, (pos * _TABLE_PER_PX)[:, :, None], out=at)
        np.maximum(at, 0.0, out=at)
        np.minimum(at, self._last, out=at)
        node = self._node[: at.size].reshape(at.shape)
        np.copyto(node, at, casting="unsafe")
        np.subtract(at, node, out=at)                        # the way to the next node
        rows = self._entries[: at.size * 4].reshape(*at.shape, 4)
        np.take(self._table, node, axis=0, out=rows)         # (2, m, side, 4)
        frac = rows[..., 0] + at * rows[..., 1]
        dfrac = rows[..., 2] + at * rows[..., 3]
        return frac[0], frac[1], dfrac[0], dfrac[1]

    @staticmethod
    def _solve(normal: np.ndarray, grad: np.ndarray) -> np.ndarray | None:
        """The steps (3, m) in (x, y, F) solving ``normal`` step = ``grad`` (m, 3) (the normal
        matrix's upper triangle, (m, 9) row-major) by the adjugate (zero for a star whose
        matrix is not positive definite), or None when no star's is."""
        a, b, c, d = normal.take(_ADJ, axis=1).transpose(1, 0, 2)     # (4, m, 9)
        adj = a * b - c * d
        det = np.einsum("ij,ij->i", normal[:, :3], adj[:, :3])
        good = np.isfinite(det) & (det > 0)
        if not good.any():
            return None
        scale = np.divide(1.0, det, out=np.zeros(len(det)), where=good)
        return np.einsum("nij,nj->in", adj.reshape(-1, 3, 3), grad) * scale
