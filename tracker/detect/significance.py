"""How well a spot's shape is known: its windowed SNR with its own shot noise counted.

The windowed centroider (tracker.detect.windowed) reports
``snr = sum(W S) / (noise sqrt(sum W^2))`` against the background's noise
alone, the right figure for finding a star on dark sky. A spot's shape
(its width, ellipticity and pixel-scale roughness) is measured on its own
pixels, whose noise also holds the spot's shot noise: where the background
is nearly noiseless (a black sky of 8-bit photon counts, most pixels
reading 0) that noise is most of it, and a faint star whose background-only
SNR reads 70 is measured as if at SNR 9 (its width to about a third, not
to a few per cent).

With each pixel's variance noise^2 + g S (g: ADU^2 of shot noise per ADU of
light, the reciprocal of the gain in e-/ADU; the detector takes 1, the
convention tracker.detect.fit weights with: the OV2311's 1.35 e-/ADU at
10 bits gives 0.74, photon-counting 8-bit frames 1. The sky's variance
against its level across the frame's tiles gave the same detections on the
bench, but a mosaic of windows around stars or lit ground would make that
slope from light that is not sky),
the weighted sum's variance is noise^2 sum(W^2) + g sum(W^2 S). For a star
whose width the window's Gaussian weight W matches (the centroider's),
S = F/(2 pi s^2) exp(-r^2/(2 s^2)) and W = exp(-r^2/(2 s^2)), so
sum(W S) = F/2 and sum(W^2 S) = F/3 = (2/3) sum(W S): the weighted sum's
shot-noise variance is (2/3) g sum(W S). The background term is
(sum(W S) / snr)^2. Hence

    snr_shot = sum(W S) / sqrt((sum(W S) / snr)^2 + (2/3) g max(sum(W S), 0)).
"""

from __future__ import annotations

import numpy as np

__all__ = ["SHOT_ADU", "shot_noise_snr"]

SHOT_ADU = 1.0   # ADU^2 of shot noise per ADU of light (1 e-/ADU; tracker.detect.fit's)
_SHOT_SHARE = 2.0 / 3.0   # sum(W^2 S) / sum(W S) for a Gaussian star under its own weight


def shot_noise_snr(weighted: np.ndarray, snr: np.ndarray,
                   shot_adu: float = SHOT_ADU) -> np.ndarray:
    """The windowed SNR of each spot with its shot noise counted (module docstring).

    ``weighted``: sum(W S) per spot, ADU; ``snr``: the same over the
    background's noise alone (tracker.detect.windowed). Spots of zero SNR
    stay at zero.
    """
    weighted = np.asarray(weighted, np.float64)
    snr = np.asarray(snr, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        background = np.where(snr != 0, weighted / snr, 0.0)
        variance = background * background + _SHOT_SHARE * shot_adu * np.maximum(weighted, 0.0)
        return np.where(variance > 0, weighted / np.sqrt(variance), 0.0)
