"""Lens calibration from identified stars: a small bundle adjustment.

Unknowns: the intrinsics (focal length f in pixels, principal point cx, cy,
radial distortion k1, k2 of tracker.camera) shared by all frames, and one
small rotation theta_i per frame (R_i = exp([theta_i]x) R_i0). Residuals:
measured centroid minus the catalogue star projected through the model, in
pixels. Solved by Levenberg-Marquardt with a forward-difference Jacobian
(the problem has 5 + 3F parameters and a few hundred residuals, so the
numbers are small); stars whose residual exceeds ``clip`` times the robust
RMS (1.4826 x median absolute residual) are dropped and the fit repeated.

With one frame the principal point and the attitude are nearly degenerate
(moving both shifts every star alike); distortion and the field's extent
separate them only weakly, so ``fit_centre=False`` keeps cx, cy fixed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.attitude import matrix_from_rotation_vector
from tracker.camera import CameraModel

__all__ = ["CalibrationFrame", "CalibrationResult", "calibrate"]

_NAMES = ("f_px", "cx", "cy", "k1", "k2")


@dataclass
class CalibrationFrame:
    """One solved frame: centroids ``xy`` (n, 2) px of stars with ICRS ``ref`` (n, 3)."""

    xy: np.ndarray
    ref: np.ndarray
    R: np.ndarray


@dataclass
class CalibrationResult:
    camera: CameraModel
    rotations: list
    rms_px: float
    stars: int
    rejected: int
    iterations: int


def _camera(template: CameraModel, p: np.ndarray) -> CameraModel:
    return CameraModel(template.width, template.height, float(p[0]), float(p[1]),
                       float(p[2]), float(p[3]), float(p[4]))


def _residuals(p, free, x0, template, frames, masks) -> np.ndarray:
    full = x0.copy()
    full[free] = p
    cam = _camera(template, full[:5])
    out = []
    for i, (fr, m) in enumerate(zip(frames, masks, strict=True)):
        R = matrix_from_rotation_vector(full[5 + 3 * i:8 + 3 * i]) @ fr.R
        pix = cam.vector_to_pixel(fr.ref[m] @ R.T)
        out.append((pix - fr.xy[m]).ravel())
    return np.concatenate(out)


def _levenberg_marquardt(fun, p, iterations: int) -> tuple[np.ndarray, int]:
    lam = 1e-3
    r = fun(p)
    cost = r @ r
    steps = np.maximum(1e-7, 1e-7 * np.abs(p))
    done = 0
    while done < iterations:
        done += 1
        J = np.empty((len(r), len(p)))
        for k in range(len(p)):
            q = p.copy()
            q[k] += steps[k]
            J[:, k] = (fun(q) - r) / steps[k]
        A = J.T @ J
        g = J.T @ r
        improved = False
        while lam < 1e12:
            try:
                delta = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            r_new = fun(p + delta)
            cost_new = r_new @ r_new
            if np.isfinite(cost_new) and cost_new < cost:
                p, r, lam, improved = p + delta, r_new, lam * 0.3, True
                break
            lam *= 10
        if not improved or cost - r @ r < 1e-12 * max(cost, 1e-30):
            cost = r @ r
            break
        cost = r @ r
    return p, done


def calibrate(template: CameraModel, frames: list[CalibrationFrame], *, fit_centre: bool = True,
              fit_k2: bool = False, clip: float = 4.0, iterations: int = 50
              ) -> CalibrationResult:
    """Fit the intrinsics and per-frame rotations to the identified stars.

    ``template`` gives the image size and the starting intrinsics. Raises
    ValueError when there are fewer stars than unknowns.
    """
    x0 = np.concatenate([[template.f_px, template.cx, template.cy, template.k1, template.k2],
                         np.zeros(3 * len(frames))])
    free = np.ones(len(x0), dtype=bool)
    free[1:3] = fit_centre
    free[4] = fit_k2
    masks = [np.ones(len(fr.xy), dtype=bool) for fr in frames]
    total = sum(len(fr.xy) for fr in frames)
    if 2 * total <= int(free.sum()):
        raise ValueError(f"{total} identified stars cannot fix {int(free.sum())} unknowns")
    p = x0[free]
    iters = 0
    for _ in range(3):
        p, n = _levenberg_marquardt(
            lambda q: _residuals(q, free, x0, template, frames, masks), p, iterations)
        iters += n
        full = x0.copy()
        full[free] = p
        cam = _camera(template, full[:5])
        changed = False
        dists = []
        for i, fr in enumerate(frames):
            R = matrix_from_rotation_vector(full[5 + 3 * i:8 + 3 * i]) @ fr.R
            dists.append(np.hypot(*(cam.vector_to_pixel(fr.ref @ R.T) - fr.xy).T))
        kept = np.concatenate([d[m] for d, m in zip(dists, masks, strict=True)])
        robust = 1.4826 * np.median(kept)
        for i, d in enumerate(dists):
            keep = d <= clip * max(robust, 1e-3)
            changed |= bool(np.any(keep != masks[i]))
            masks[i] = keep
        if not changed:
            break
    full = x0.copy()
    full[free] = p
    res = _residuals(p, free, x0, template, frames, masks)
    rotations = [matrix_from_rotation_vector(full[5 + 3 * i:8 + 3 * i]) @ fr.R
                 for i, fr in enumerate(frames)]
    kept = int(sum(m.sum() for m in masks))
    return CalibrationResult(camera=_camera(template, full[:5]), rotations=rotations,
                             rms_px=float(np.sqrt(np.mean(res ** 2) * 2)), stars=kept,
                             rejected=total - kept, iterations=iters)
