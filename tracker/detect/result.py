"""The result every detection method returns.

Stars are rows of a fixed-size structured array (:data:`STAR_DTYPE`) owned by
the detector and reused frame after frame; ``Detections.stars`` is a view of
its first ``count`` rows, valid until the next call to ``detect``. Copy it
(``stars.copy()``) to keep it.

Positions follow the project's pixel convention: x = column, y = row, origin
at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["STAR_DTYPE", "StarFlag", "Detections"]

STAR_DTYPE = np.dtype([
    ("x", np.float64),      # column, px
    ("y", np.float64),      # row, px
    ("flux", np.float64),   # background-subtracted flux, ADU (default: PSF-weighted)
    ("peak", np.float64),   # highest background-subtracted pixel, ADU
    ("snr", np.float64),    # flux / its noise (background and shot noise)
    ("npix", np.int32),     # pixels in the segment
    ("flags", np.uint16),   # StarFlag bits
])


class StarFlag:
    """Bits of the ``flags`` field."""

    SATURATED = 1   # a pixel reached the sensor's full scale
    EDGE = 2        # the centroid's window reaches beyond the frame: the star is fitted
                    # on the pixels inside it (tracker.detect.edge), its centre in the frame
    ELONGATED = 4   # second moments say streak or trail, not a point
    BLENDED = 8     # split from a segment shared with another star
    EXTENDED = 16   # much broader than the frame's point sources: nebula, comet,
                    # lit cloud or terrain; identification ignores it


@dataclass
class Detections:
    """Stars found in one frame, with diagnostics.

    ``reason`` is None for a normal frame, or a short code (``"empty"``,
    ``"saturated"``, ``"bad_dtype"``, ``"non_finite"``, ``"wrong_shape"``,
    ``"too_many"``...) saying why the frame gave no or flagged results.
    ``counters`` holds what was rejected (``hot_pixels``, ``cosmic_rays``...)
    and ``left_out``, the stars found beyond ``detect.max_stars`` (the
    faintest, not reported); ``stages_ms`` the time per stage in
    milliseconds.

    The PSF the frame was measured with (the default method; None for the
    others): ``psf_sigma_px``, the optics' Gaussian-equivalent sigma (FWHM =
    2.3548 sigma), ``psf_ellipticity`` (a^2 - b^2) / (a^2 + b^2) of its axes,
    ``psf_angle_deg`` of its long axis from +x toward +y, and ``psf_stars``,
    how many of this frame's stars measured it (0: the previous estimate or
    ``detect.psf_sigma_px`` was used).
    """

    stars: np.ndarray
    reason: str | None = None
    counters: dict = field(default_factory=dict)
    stages_ms: dict = field(default_factory=dict)
    psf_sigma_px: float | None = None
    psf_ellipticity: float | None = None
    psf_angle_deg: float | None = None
    psf_stars: int = 0

    @property
    def count(self) -> int:
        return len(self.stars)
