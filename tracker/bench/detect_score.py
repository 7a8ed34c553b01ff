"""Scoring detections against simulated truth for ``tracker bench detect``.

Matching: each detection is paired with the nearest truth star within
``MATCH_PX`` (one-to-one, closest pairs first). Every rendered star counts
as truth, faint or just outside the frame, so finding one is never a false
detection; hot pixels, cosmic rays and noise are false.

Detectable stars (the recall denominator and the error statistics): inside
the frame at least ``BORDER_PX`` from the edge, not blended (no other star
of at least ``BLEND_FLUX`` of its flux within ``BLEND_PX``), and meeting the
set's criterion (peak SNR >= 5 or matched-filter SNR >= 7).

Metrics (SEED-METHOD.md's definitions): Euclidean error d per matched
detectable star, RMSE = sqrt(mean d^2), mean d, FDR = false / detected,
recall = matched detectable / detectable; the Cramer-Rao bound of the same
stars (tracker.detect.crb) as RMS over them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.detect.crb import centroid_crb

__all__ = ["MATCH_PX", "FrameTruth", "Score", "match", "MAG_BINS"]

MATCH_PX = 2.0
BORDER_PX = 5.0
BLEND_PX = 5.0
BLEND_FLUX = 0.1
MAG_BINS = (-2.0, 4.0, 5.0, 6.0, 7.0, 9.0)
HIGH_SNR = 20.0


def match(tx: np.ndarray, ty: np.ndarray, dx: np.ndarray, dy: np.ndarray,
          radius: float = MATCH_PX) -> np.ndarray:
    """For each detection, the index of its truth star or -1 (one-to-one)."""
    from scipy.spatial import cKDTree

    out = np.full(len(dx), -1, np.int64)
    if len(dx) == 0 or len(tx) == 0:
        return out
    pairs = cKDTree(np.column_stack([tx, ty])).query_ball_point(
        np.column_stack([dx, dy]), radius)
    cand = [(np.hypot(tx[t] - dx[d], ty[t] - dy[d]), d, t)
            for d, ts in enumerate(pairs) for t in ts]
    used = set()
    for _, d, t in sorted(cand):
        if out[d] < 0 and t not in used:
            out[d] = t
            used.add(t)
    return out


@dataclass
class FrameTruth:
    """What a frame's truth says about detectability, computed once per frame."""

    x: np.ndarray
    y: np.ndarray
    mag: np.ndarray
    peak_snr: np.ndarray
    detectable: np.ndarray
    crb: np.ndarray          # px, NaN where not computed (not detectable)

    @classmethod
    def from_frame(cls, frame, criterion: str, variance, flux_unit: float,
                   sigma_px: float, saturation) -> FrameTruth:
        s = frame.stars
        rows, cols = frame.image.shape
        inside = ((s["x"] >= BORDER_PX) & (s["x"] <= cols - 1 - BORDER_PX)
                  & (s["y"] >= BORDER_PX) & (s["y"] <= rows - 1 - BORDER_PX))
        d = np.hypot(s["x"][:, None] - s["x"][None], s["y"][:, None] - s["y"][None])
        np.fill_diagonal(d, np.inf)
        loud = s["flux_e"][None, :] >= BLEND_FLUX * s["flux_e"][:, None]
        blended = np.any((d < BLEND_PX) & loud, axis=1)
        good = s["peak_snr"] >= 5.0 if criterion.startswith("peak") else s["mf_snr"] >= 7.0
        detectable = inside & ~blended & good
        crb = np.full(len(s), np.nan)
        for i in np.flatnonzero(detectable):
            crb[i] = centroid_crb([s["x"][i]], [s["y"][i]], [s["flux_e"][i] / flux_unit],
                                  sigma_px, variance(frame, i),
                                  saturation(frame, i) / flux_unit)[0]
        return cls(s["x"], s["y"], s["mag"], s["peak_snr"], detectable, crb)


@dataclass
class Score:
    """Accumulated results of one method on one data set."""

    detected: int = 0
    false: int = 0
    detectable: int = 0
    found: int = 0
    errors: list = field(default_factory=list)
    crbs: list = field(default_factory=list)
    mags: list = field(default_factory=list)
    snrs: list = field(default_factory=list)
    ms: list = field(default_factory=list)
    stages: list = field(default_factory=list)
    failures: int = 0
    rejected: int = 0

    def add(self, truth: FrameTruth, x: np.ndarray, y: np.ndarray, ms: float,
            stages: dict | None = None, rejected: int = 0) -> None:
        owner = match(truth.x, truth.y, x, y)
        self.detected += len(x)
        self.false += int(np.count_nonzero(owner < 0))
        self.detectable += int(np.count_nonzero(truth.detectable))
        hit = owner[(owner >= 0)]
        hit = hit[truth.detectable[hit]]
        det = np.flatnonzero(owner >= 0)[truth.detectable[owner[owner >= 0]]]
        self.found += len(hit)
        self.errors += list(np.hypot(x[det] - truth.x[hit], y[det] - truth.y[hit]))
        self.crbs += list(truth.crb[hit])
        self.mags += list(truth.mag[hit])
        self.snrs += list(truth.peak_snr[hit])
        self.ms.append(ms)
        if stages:
            self.stages.append(dict(stages))
        self.rejected += rejected

    def merged(self, other: Score) -> Score:
        out = Score()
        for name in ("detected", "false", "detectable", "found", "failures", "rejected"):
            setattr(out, name, getattr(self, name) + getattr(other, name))
        for name in ("errors", "crbs", "mags", "snrs", "ms", "stages"):
            setattr(out, name, getattr(self, name) + getattr(other, name))
        return out

    def summary(self) -> dict:
        err = np.asarray(self.errors, float)
        crb = np.asarray(self.crbs, float)
        snr = np.asarray(self.snrs, float)
        mags = np.asarray(self.mags, float)
        high = snr >= HIGH_SNR
        rmse_hi = _rms(err[high])
        crb_hi = _rms(crb[high])
        by_mag = {}
        for lo, hi in zip(MAG_BINS[:-1], MAG_BINS[1:], strict=True):
            sel = (mags >= lo) & (mags < hi)
            by_mag[f"{lo:g}..{hi:g}"] = {"n": int(sel.sum()), "rmse_px": _rms(err[sel]),
                                         "crb_px": _rms(crb[sel])}
        stage_names = sorted({k for st in self.stages for k in st})
        return {
            "frames": len(self.ms), "detected": self.detected, "false": self.false,
            "detectable": self.detectable, "found": self.found,
            "recall": self.found / self.detectable if self.detectable else None,
            "fdr": self.false / self.detected if self.detected else 0.0,
            "rmse_px": _rms(err), "mean_err_px": float(err.mean()) if len(err) else None,
            "crb_px": _rms(crb), "rmse_snr20_px": rmse_hi, "crb_snr20_px": crb_hi,
            "n_snr20": int(high.sum()),
            "rmse_over_crb_snr20": rmse_hi / crb_hi if rmse_hi and crb_hi else None,
            "median_ms": float(np.median(self.ms)) if self.ms else None,
            "stages_median_ms": {k: float(np.median([st.get(k, 0.0) for st in self.stages]))
                                 for k in stage_names},
            "by_mag": by_mag, "failures": self.failures, "rejected_impulses": self.rejected,
        }


def _rms(values: np.ndarray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else None
