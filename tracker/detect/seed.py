"""The dissertation's pipeline ("seed method"), as docs/seed-method.md states it.

1. Gaussian blur, 7x7 kernel, sigma 1.5 px (``detect.seed_blur_sigma_px``,
   ``detect.seed_blur_ksize_px``).
2. 3x3 median filter against impulse noise.
3. Global threshold T = a * max(filtered image), a = 0.3
   (``detect.seed_threshold_frac``): pixels > T are foreground.
4. 8-connected blobs; each blob's centre is the intensity-weighted centre of
   mass of the filtered image over the blob's pixels.

No background is subtracted and there is no noise model, so ``snr`` is 0.
``flux`` is the blob's sum and ``peak`` its maximum, both of the filtered
image in ADU. Blobs of one pixel are kept (the method does not reject them).
When there are more blobs than ``detect.max_stars``, the highest-flux ones
are kept and the reason is ``too_many``.
"""

from __future__ import annotations

import cv2
import numpy as np

from tracker.config import DetectConfig
from tracker.detect.frame_input import FrameInput, Reason
from tracker.detect.result import Detections, StarFlag
from tracker.detect.stars import StarTable
from tracker.timing import StageTimer

__all__ = ["SeedDetector"]


class SeedDetector:
    """Blur, median, threshold at a fraction of the maximum, centre of mass.

    Subclasses (tracker.detect.baselines) keep the segmentation and change
    the centroid: ``com_on_filtered`` False takes the centre of mass of the
    unfiltered frame, and :meth:`_refine` may replace the positions.
    """

    com_on_filtered = True

    def __init__(self, cfg: DetectConfig, shape: tuple[int, int], bit_depth: int) -> None:
        self.cfg = cfg
        self.input = FrameInput(shape, bit_depth)
        self.table = StarTable(cfg.max_stars)
        self.timer = StageTimer()
        k = int(cfg.seed_blur_ksize_px)
        self.ksize = (k, k)
        self.filtered = np.zeros(self.input.shape, np.float32)
        self.blurred = np.zeros(self.input.shape, np.float32)
        self.mask = np.zeros(self.input.shape, np.uint8)

    def detect(self, image: np.ndarray) -> Detections:
        """Stars in ``image`` (pixel convention: tracker.detect.result)."""
        timer = self.timer
        timer.reset()
        timer.start("input")
        reason = self.input.load(image)
        if reason is not None:
            timer.stop()
            return self.table.result(0, reason, {}, timer.ms)
        timer.start("filter")
        cv2.GaussianBlur(self.input.work, self.ksize, self.cfg.seed_blur_sigma_px,
                         dst=self.blurred, borderType=cv2.BORDER_REFLECT)
        cv2.medianBlur(self.blurred, 3, dst=self.filtered)
        timer.start("threshold")
        _, hi, _, _ = cv2.minMaxLoc(self.filtered)
        cv2.compare(self.filtered, self.cfg.seed_threshold_frac * hi, cv2.CMP_GT, dst=self.mask)
        timer.start("label")
        n, labels = cv2.connectedComponents(self.mask, connectivity=8, ltype=cv2.CV_32S)
        timer.start("centroid")
        count, reason = self._centroids(n, labels)
        self._refine(count)
        timer.stop()
        return self.table.result(count, reason, {"blobs": n - 1}, timer.ms)

    def _centroids(self, n: int, labels: np.ndarray) -> tuple[int, str | None]:
        """Intensity-weighted centre of mass per blob into the star table."""
        if n <= 1:
            return 0, None
        rows, cols = np.nonzero(labels)
        lab = labels[rows, cols]
        w = self.filtered[rows, cols].astype(np.float64)
        flux = np.bincount(lab, w, n)[1:]
        c = w if self.com_on_filtered else self.input.work[rows, cols].astype(np.float64)
        weight = np.bincount(lab, c, n)[1:]
        sx = np.bincount(lab, c * cols, n)[1:]
        sy = np.bincount(lab, c * rows, n)[1:]
        if not self.com_on_filtered:  # a blob of zeros in the raw frame: filtered COM
            dark = weight <= 0
            sx[dark] = np.bincount(lab, w * cols, n)[1:][dark]
            sy[dark] = np.bincount(lab, w * rows, n)[1:][dark]
            weight[dark] = flux[dark]
        npix = np.bincount(lab, None, n)[1:]
        peak = np.zeros(n)
        np.maximum.at(peak, lab, w)
        order = np.argsort(-flux, kind="stable")[: self.table.capacity]
        count = len(order)
        s = self.table.stars
        s["x"][:count] = sx[order] / weight[order]
        s["y"][:count] = sy[order] / weight[order]
        s["flux"][:count] = flux[order]
        s["peak"][:count] = peak[1:][order]
        s["snr"][:count] = 0.0
        s["npix"][:count] = npix[order]
        s["flags"][:count] = 0
        self._edge_flags(count, rows, cols, lab, order)
        return count, (Reason.TOO_MANY if n - 1 > count else None)

    def _refine(self, count: int) -> None:
        """Hook for baselines that re-measure the first ``count`` stars' positions."""

    def _edge_flags(self, count: int, rows: np.ndarray, cols: np.ndarray, lab: np.ndarray,
                    order: np.ndarray) -> None:
        """EDGE on blobs that touch the border, SATURATED where the input is at full scale."""
        h, w = self.input.shape
        touches = np.zeros(lab.max() + 1, bool)
        touches[lab[(rows == 0) | (cols == 0) | (rows == h - 1) | (cols == w - 1)]] = True
        sat = np.zeros_like(touches)
        sat[lab[self.input.work[rows, cols] >= self.input.full_scale]] = True
        flags = self.table.stars["flags"]
        flags[:count] |= np.where(touches[1:][order], StarFlag.EDGE, 0).astype(np.uint16)
        flags[:count] |= np.where(sat[1:][order], StarFlag.SATURATED, 0).astype(np.uint16)
