"""Pictures for people: a frame with its stars marked, readable at a glance.

* **Dark sky:** the sky level (median) maps to near black and its noise to a
  faint texture; above it an asinh stretch (linear to ~3 sigma, logarithmic
  beyond) keeps faint stars visible and bright ones unclipped.
* **Stars:** every detection circled, green when identified (labelled with
  the IAU name of bright stars, tracker.star_names, else ``HIP n``; the
  brightest :data:`MAX_LABELS` labelled), amber when not identified; labels
  on a dark backing.
* **Truth** (``<frame>.truth.json`` beside a simulated or solved frame,
  tracker.truth): a cyan cross on each true star, and the attitude error in
  the title.
* **Title bar:** the frame's name and its result (RA, Dec, roll, matched
  stars, sigma) or why it was not solved; a **legend** at the bottom left.

Small frames are drawn enlarged (an integer factor, to at least
:data:`MIN_WIDTH_PX` wide) so labels stay legible. Text is ASCII (OpenCV's
Hershey font): "deg", "arcsec".
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from tracker.attitude import attitude_error, matrix_from_radec_roll
from tracker.star_names import star_name
from tracker.truth import Truth

__all__ = ["display_stretch", "render_overlay", "write_overlay", "REASON_TEXT",
           "MAX_LABELS", "MIN_WIDTH_PX", "GREEN", "AMBER", "CYAN"]

GREEN = (90, 230, 90)       # BGR: identified
AMBER = (0, 190, 255)       # detected, not identified
CYAN = (255, 230, 0)        # truth
RED = (70, 70, 255)         # not solved
WHITE = (235, 235, 235)
MAX_LABELS = 25
MIN_WIDTH_PX = 1000
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_SKY_LEVEL = 0.05           # display level of the sky (fraction of white)
_SOFTENING_SIGMA = 3.0      # asinh: linear below about this many noise sigmas

# Why a frame has no attitude, in words (solver, pipeline and detector codes).
REASON_TEXT = {
    "too_few_stars": "too few stars",
    "no_match": "no star pattern matched",
    "not_verified": "a match was found but not verified",
    "wrong_fov": "the pattern database does not fit the lens",
    "timeout": "lost in space gave up (identify.max_lis_ms)",
    "bad_input": "unusable star list",
    "frame_size": "the frame is not the configured camera's size",
    "disabled": "identification is off",
}


def display_stretch(image: np.ndarray) -> np.ndarray:
    """8-bit grey rendering of a frame: dark sky, asinh above it (module docstring)."""
    img = image.astype(np.float32)
    sample = img[::4, ::4] if img.size > 250_000 else img
    sky = float(np.median(sample))
    noise = 1.4826 * float(np.median(np.abs(sample - sky)))
    top = float(img.max())
    soft = max(_SOFTENING_SIGMA * noise, 1e-3 * max(top - sky, 1.0), 1e-6)
    span = math.asinh(max(top - sky, soft) / soft)
    np.subtract(img, sky, out=img)
    np.divide(img, soft, out=img)
    np.arcsinh(img, out=img)
    scaled = _SKY_LEVEL + (1.0 - _SKY_LEVEL) * img / span
    return (np.clip(scaled, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


class _Painter:
    """Draws on a canvas ``zoom`` times the frame's size, text scaled to it."""

    def __init__(self, canvas: np.ndarray, zoom: int):
        self.canvas = canvas
        self.zoom = zoom
        self.scale = max(0.55, canvas.shape[1] / 1600.0 * 0.85)
        self.thick = 1 if self.scale < 0.8 else 2

    def xy(self, x: float, y: float) -> tuple[int, int]:
        """Canvas point of frame pixel (x, y) (pixel centres at integers)."""
        z = self.zoom
        return int(round((x + 0.5) * z - 0.5)), int(round((y + 0.5) * z - 0.5))

    def text(self, origin: tuple[int, int], text: str, colour, scale: float = 1.0,
             backing: bool = True) -> tuple[int, int]:
        """Text with its baseline-left at origin on a darkened box; returns its (w, h)."""
        s = self.scale * scale
        (w, h), base = cv2.getTextSize(text, _FONT, s, self.thick)
        x, y = origin
        if backing:
            self.darken(x - 3, y - h - 3, x + w + 3, y + base + 2)
        cv2.putText(self.canvas, text, (x, y), _FONT, s, colour, self.thick, cv2.LINE_AA)
        return w, h + base

    def darken(self, x0: int, y0: int, x1: int, y1: int, keep: float = 0.3) -> None:
        H, W = self.canvas.shape[:2]
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if x1 > x0 and y1 > y0:
            roi = self.canvas[y0:y1, x0:x1]
            roi[:] = (roi * keep).astype(np.uint8)


def _title(result, name: str, size: str, truth: Truth | None) -> tuple[str, str, tuple]:
    """(first line, second line, colour) of the title bar; ``size`` e.g. '1600x1300 px'."""
    sol = result.solution
    n = result.detections.count
    if sol is not None and getattr(sol, "ok", False):
        line1 = (f"{name}   RA {sol.ra_deg:.4f}  Dec {sol.dec_deg:+.4f}  roll "
                 f"{sol.roll_deg:.3f} deg")
        line2 = (f"{sol.matched} of {n} stars identified   sigma {sol.sigma_cross_arcsec:.1f} "
                 f"arcsec across, {sol.sigma_roll_arcsec:.0f} about the boresight   {size}   "
                 f"{result.time_ms:.1f} ms")
        if truth is not None and truth.R is not None:
            centre = matrix_from_radec_roll(*np.radians([sol.ra_deg, sol.dec_deg, sol.roll_deg]))
            cross, roll = attitude_error(centre, truth.R)
            line2 += (f"   vs truth: {math.degrees(cross) * 3600:.1f} arcsec across, "
                      f"{abs(math.degrees(roll)) * 3600:.0f} about")
        return line1, line2, GREEN
    code = (sol.reason if sol is not None else None) or result.solve_reason \
        or result.detections.reason or "unknown"
    why = REASON_TEXT.get(code, code)
    detect = f" (detector: {result.detections.reason})" if result.detections.reason else ""
    return (f"{name}   NOT SOLVED: {why}", f"{n} stars detected{detect}   {size}   "
                                            f"{result.time_ms:.1f} ms", RED)


def _legend(p: _Painter, with_truth: bool) -> None:
    rows = [(GREEN, "circle", "identified (name or HIP number)"),
            (AMBER, "circle", "detected, not identified")]
    if with_truth:
        rows.append((CYAN, "cross", "truth"))
    s = p.scale
    line_h = int(26 * s) + 4
    H = p.canvas.shape[0]
    width = max(cv2.getTextSize(t, _FONT, s * 0.8, p.thick)[0][0] for _, _, t in rows)
    y0 = H - line_h * len(rows) - 12
    p.darken(6, y0 - 6, 6 + int(40 * s) + width + 16, H - 6, keep=0.2)
    for i, (colour, kind, text) in enumerate(rows):
        cy = y0 + i * line_h + line_h // 2
        cx = 10 + int(16 * s)
        r = int(9 * s)
        if kind == "circle":
            cv2.circle(p.canvas, (cx, cy), r, colour, p.thick, cv2.LINE_AA)
        else:
            cv2.drawMarker(p.canvas, (cx, cy), colour, cv2.MARKER_CROSS, 2 * r, p.thick)
        p.text((cx + r + 10, cy + int(8 * s)), text, WHITE, 0.8, backing=False)


def render_overlay(image: np.ndarray, result, name: str,
                   truth: Truth | None = None) -> np.ndarray:
    """The overlay of one frame (``result``: a tracker.pipeline.FrameResult) as BGR uint8."""
    zoom = max(1, math.ceil(MIN_WIDTH_PX / max(image.shape[1], 1)))
    grey = display_stretch(image)
    if zoom > 1:
        grey = cv2.resize(grey, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    p = _Painter(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), zoom)
    stars = result.detections.stars
    hips = getattr(result.solution, "hip", None)
    labelled = 0
    for i, star in enumerate(stars):
        centre = p.xy(star["x"], star["y"])
        radius = int(np.clip(3.0 + np.sqrt(max(int(star["npix"]), 1)), 6, 30) * zoom)
        hip = int(hips[i]) if hips is not None and i < len(hips) else 0
        cv2.circle(p.canvas, centre, radius, GREEN if hip else AMBER, p.thick, cv2.LINE_AA)
        named = star_name(hip) if hip else None
        if hip and (named or labelled < MAX_LABELS):
            labelled += 1
            label = f"{named} {hip}" if named else f"HIP {hip}"
            p.text((centre[0] + radius + 4, centre[1] + int(5 * p.scale)), label, GREEN, 0.75)
    if truth is not None:           # on top: a check must never hide under a label
        for x, y in truth.xy:
            cv2.drawMarker(p.canvas, p.xy(x, y), CYAN, cv2.MARKER_CROSS,
                           int(14 * p.scale) + 2 * zoom, 1, cv2.LINE_AA)
    line1, line2, colour = _title(result, name, f"{image.shape[1]}x{image.shape[0]} px", truth)
    bar = int(64 * p.scale)
    p.darken(0, 0, p.canvas.shape[1], bar, keep=0.15)
    p.text((10, int(26 * p.scale)), line1, colour, 1.0, backing=False)
    p.text((10, int(54 * p.scale)), line2, WHITE, 0.8, backing=False)
    _legend(p, truth is not None)
    return p.canvas


def write_overlay(path: Path, image: np.ndarray, result, name: str,
                  truth: Truth | None = None) -> np.ndarray:
    """Write :func:`render_overlay` as a PNG; returns the picture."""
    canvas = render_overlay(image, result, name, truth)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"{path}: could not write the overlay PNG")
    return canvas
