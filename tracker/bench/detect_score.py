"""Scoring detections against simulated truth for ``tracker bench detect``.

Matching: each detection is paired with the nearest truth star within
``MATCH_PX`` or the frame's PSF sigma if wider (one-to-one, closest pairs
first): a centroid at the detection limit (matched-filter SNR 5) has a
standard error of about 0.3 sigma per axis, so a star of a wide PSF found
3 px from its truth is that star, poorly centred, not a false detection. Every rendered star counts
as truth, faint or just outside the frame, so finding one is never a false
detection; hot pixels, cosmic rays and noise are false.

Detectable stars (the recall denominator and the error statistics): inside
the frame at least ``BORDER_PX`` from the edge, not blended (no other star
of at least ``BLEND_FLUX`` of its flux within ``BLEND_PX``), on a background
below full scale (a star under glare or lit ground that already saturates
its pixels leaves no trace in them), and meeting the set's criterion (peak
SNR >= 5 or matched-filter SNR >= 7).

Metrics (docs/seed-method.md's definitions): Euclidean error d per matched
detectable star, RMSE = sqrt(mean d^2), mean d, FDR = false / detected,
recall = matched detectable / detectable; the Cramer-Rao bound of the same
stars (tracker.detect.crb) as RMS over them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.detect.crb import centroid_crb
from tracker.sim.psf_shapes import PsfShape, shape_model
from tracker.sim.scene import LABELS

LABEL_NAMES = {v: k for k, v in LABELS.items()}

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
    labels: np.ndarray | None = None   # tracker.sim.scene.LABELS per pixel, if a scene
    match_px: float = MATCH_PX

    @classmethod
    def from_frame(cls, frame, criterion: str, variance, flux_unit: float,
                   sigma_px: float, saturation) -> FrameTruth:
        """``sigma_px``: the frame's PSF sigma; a PSF other than a round Gaussian comes
        from the frame's truth (its bound is then computed, from supersampled stamps,
        only for the stars at peak SNR >= 20 that the ratio uses)."""
        s = frame.stars
        rows, cols = frame.image.shape
        inside = ((s["x"] >= BORDER_PX) & (s["x"] <= cols - 1 - BORDER_PX)
                  & (s["y"] >= BORDER_PX) & (s["y"] <= rows - 1 - BORDER_PX))
        d = np.hypot(s["x"][:, None] - s["x"][None], s["y"][:, None] - s["y"][None])
        np.fill_diagonal(d, np.inf)
        loud = s["flux_e"][None, :] >= BLEND_FLUX * s["flux_e"][:, None]
        blended = np.any((d < BLEND_PX) & loud, axis=1)
        good = s["peak_snr"] >= 5.0 if criterion.startswith("peak") else s["mf_snr"] >= 7.0
        seen = np.array([saturation(frame, i) > 0.0 for i in range(len(s))], bool)
        detectable = inside & ~blended & good & seen
        crb = np.full(len(s), np.nan)
        psf = _truth_psf(frame)
        model, box_sigma, which = None, sigma_px, detectable
        if psf is not None and not psf.is_round_gaussian:
            model, box_sigma = shape_model(psf), 2.0 * psf.sigma_px
            which = detectable & (s["peak_snr"] >= HIGH_SNR)
        for i in np.flatnonzero(which):
            crb[i] = centroid_crb([s["x"][i]], [s["y"][i]], [s["flux_e"][i] / flux_unit],
                                  box_sigma, variance(frame, i),
                                  saturation(frame, i) / flux_unit, model=model)[0]
        return cls(s["x"], s["y"], s["mag"], s["peak_snr"], detectable, crb,
                   getattr(frame, "labels", None), max(MATCH_PX, float(sigma_px)))


def _truth_psf(frame) -> PsfShape | None:
    p = frame.truth.get("psf")
    if not p:
        return None
    return PsfShape(p["kind"], p["sigma_px"], p["beta"], p["ellipticity"],
                    np.radians(p["angle_deg"]))


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
    false_on: dict = field(default_factory=dict)   # scene label name -> false detections

    def add(self, truth: FrameTruth, x: np.ndarray, y: np.ndarray, ms: float,
            stages: dict | None = None, rejected: int = 0) -> None:
        owner = match(truth.x, truth.y, x, y, truth.match_px)
        self.detected += len(x)
        self.false += int(np.count_nonzero(owner < 0))
        labels = getattr(truth, "labels", None)
        if labels is not None and np.any(owner < 0):
            rows, cols = labels.shape
            r = np.clip(np.rint(y[owner < 0]).astype(int), 0, rows - 1)
            c = np.clip(np.rint(x[owner < 0]).astype(int), 0, cols - 1)
            for label in labels[r, c]:
                name = LABEL_NAMES[int(label)]
                self.false_on[name] = self.false_on.get(name, 0) + 1
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
        for part in (self.false_on, other.false_on):
            for k, v in part.items():
                out.false_on[k] = out.false_on.get(k, 0) + v
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
            "false_on": dict(self.false_on),
        }


def _rms(values: np.ndarray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else None
