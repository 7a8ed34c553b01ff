"""Camera model: pinhole with principal point and radial distortion.

Conventions (docs/conventions.md):

* Pixel coordinates (x, y): x = column, y = row, origin at the centre of the
  top-left pixel (that pixel spans -0.5..0.5 in both axes).
* Camera frame: +Z is the boresight toward the sky, +X toward increasing x,
  +Y toward increasing y.
* Ideal pinhole: x = cx + f*X/Z, y = cy + f*Y/Z with f in pixels
  (focal_length_mm * 1000 / pixel_size_um).
* Radial distortion acts on the ideal normalised coordinates (u, v) = (X/Z,
  Y/Z): (u_d, v_d) = (u, v) * (1 + k1*r^2 + k2*r^4), r^2 = u^2 + v^2, and
  pixel = (cx + f*u_d, cy + f*v_d). The inverse is solved by Newton's method
  to machine precision.

All functions are vectorised over leading axes; angles are radians.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tracker.config import CameraConfig

__all__ = ["CameraModel"]

_NEWTON_STEPS = 12


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera; build it with :meth:`from_config`.

    ``pixel_size_um`` (None if unknown) only converts focal lengths to mm.
    """

    width: int
    height: int
    f_px: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    pixel_size_um: float | None = None

    @classmethod
    def from_config(cls, cfg: CameraConfig) -> CameraModel:
        """Model from the ``camera`` section of the configuration."""
        return cls(
            width=cfg.width,
            height=cfg.height,
            f_px=cfg.focal_length_mm * 1000.0 / cfg.pixel_size_um,
            cx=(cfg.width - 1) / 2.0 if cfg.cx is None else cfg.cx,
            cy=(cfg.height - 1) / 2.0 if cfg.cy is None else cfg.cy,
            k1=cfg.k1,
            k2=cfg.k2,
            pixel_size_um=cfg.pixel_size_um,
        )

    # -- geometry -----------------------------------------------------------

    @cached_property
    def principal_point(self) -> np.ndarray:
        """(cx, cy) px as a read-only array, made once per model: a tuple in the frame
        loop's whole-array operations is converted to one at every call."""
        point = np.array((self.cx, self.cy))
        point.flags.writeable = False
        return point

    @property
    def pixel_scale_rad(self) -> float:
        """Angle subtended by one pixel at the principal point, radians."""
        return 1.0 / self.f_px

    @property
    def fov_diagonal_rad(self) -> float:
        """Full diagonal field of view, radians (from the corner rays)."""
        corners = self.pixel_to_vector(np.array([[-0.5, -0.5], [self.width - 0.5,
                                                 self.height - 0.5]]))
        return float(np.arccos(np.clip(corners[0] @ corners[1], -1.0, 1.0)))

    @property
    def fov_x_rad(self) -> float:
        """Full horizontal field of view through the principal point, radians."""
        ends = self.pixel_to_vector(np.array([[-0.5, self.cy], [self.width - 0.5, self.cy]]))
        return float(np.arccos(np.clip(ends[0] @ ends[1], -1.0, 1.0)))

    def _radial(self, r2: np.ndarray) -> np.ndarray | float:
        """k1 + k2 r^2 at ``r2`` = r^2: k1 when k2 is 0 (the same numbers for finite r2,
        with two numpy calls fewer in the loops that call it)."""
        return self.k1 + self.k2 * r2 if self.k2 else self.k1

    def _undistort(self, distorted: np.ndarray) -> np.ndarray:
        """Invert the radial model: solve rho*(1+k1 rho^2+k2 rho^4) = rho_d for rho.

        ``distorted`` (..., 2) the distorted normalised coordinates; returns
        the ideal ones (a new array). Newton's method starts from the
        first-order inverse rho_d / (1 + k1 rho_d^2 + k2 rho_d^4), within
        about 2 k1^2 rho^5 of the root: two steps reach machine precision
        for real lenses.
        """
        sq = distorted * distorted
        rho_d = np.sqrt(sq[..., 0] + sq[..., 1])
        r2 = rho_d * rho_d
        rho = rho_d / (1.0 + r2 * self._radial(r2))
        tolerance = 1e-16 * (1.0 + rho_d)
        for _ in range(_NEWTON_STEPS):
            r2 = rho * rho
            g = rho * (1.0 + r2 * self._radial(r2)) - rho_d
            dg = 1.0 + r2 * (3.0 * self.k1 + 5.0 * self.k2 * r2 if self.k2 else 3.0 * self.k1)
            step = g / dg
            rho = rho - step
            if not (np.abs(step) > tolerance).any():
                break   # converged (quadratically)
        # rho / rho_d, 1 at the centre (rho_d = 0)
        ratio = np.divide(rho, rho_d, out=np.ones(rho.shape), where=rho_d > 0)
        return distorted * ratio[..., None]

    def vector_to_pixel(self, vectors: np.ndarray) -> np.ndarray:
        """Project camera-frame vectors (..., 3) to pixels (..., 2).

        Vectors with Z <= 0 (behind the camera) give NaN. Vectors need not be
        unit length.
        """
        vectors = np.asarray(vectors, dtype=np.float64)
        z = vectors[..., 2:3]
        # (u, v) = (X, Y) / Z; NaN behind the camera, without a warning (X / NaN raises none)
        uv = vectors[..., :2] / np.where(z > 0, z, np.nan)
        sq = uv * uv
        r2 = sq[..., 0] + sq[..., 1]
        uv *= (1.0 + r2 * self._radial(r2))[..., None]     # distorted
        uv *= self.f_px
        uv += self.principal_point
        return uv

    def pixel_to_vector(self, pixels: np.ndarray) -> np.ndarray:
        """Unit vectors (..., 3) in the camera frame for pixel positions (..., 2)."""
        pixels = np.asarray(pixels, dtype=np.float64)
        uv = (pixels - self.principal_point) / self.f_px
        if self.k1 != 0.0 or self.k2 != 0.0:
            uv = self._undistort(uv)
        vec = np.empty(uv.shape[:-1] + (3,))
        vec[..., :2] = uv
        vec[..., 2] = 1.0
        sq = vec * vec
        vec /= np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])[..., None]
        return vec

    def in_frame(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask: pixel positions inside the image, ``margin`` px from its edge."""
        pixels = np.asarray(pixels, dtype=np.float64)
        x, y = pixels[..., 0], pixels[..., 1]
        # (a NaN compares false, with no warning)
        return ((x >= -0.5 + margin) & (x <= self.width - 0.5 - margin)
                & (y >= -0.5 + margin) & (y <= self.height - 0.5 - margin))
