"""Pictures for people: a frame with its detections marked.

The frame is stretched for display (background at 1st percentile to black,
99.9th percentile to white, square-root scale); identified stars are circled
green with their HIP number, unidentified detections yellow.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

__all__ = ["display_stretch", "write_overlay"]

_GREEN = (80, 220, 80)
_YELLOW = (0, 220, 255)


def display_stretch(image: np.ndarray) -> np.ndarray:
    """8-bit grey rendering of a uint8/uint16 frame for display."""
    img = image.astype(np.float32)
    lo, hi = np.percentile(img, (1.0, 99.9))
    scaled = np.clip((img - lo) / max(hi - lo, 1.0), 0.0, 1.0)
    return (np.sqrt(scaled) * 255.0).astype(np.uint8)


def write_overlay(path: Path, image: np.ndarray, bit_depth: int, result) -> None:
    """Write ``image`` as a colour PNG with ``result``'s detections circled."""
    canvas = cv2.cvtColor(display_stretch(image), cv2.COLOR_GRAY2BGR)
    stars = result.detections.stars
    hips = getattr(result.solution, "hip", None)
    for i, star in enumerate(stars):
        centre = (int(round(star["x"])), int(round(star["y"])))
        radius = int(np.clip(2.0 + np.sqrt(max(star["npix"], 1)), 4, 30))
        hip = int(hips[i]) if hips is not None else 0
        colour = _GREEN if hip else _YELLOW
        cv2.circle(canvas, centre, radius, colour, 1, lineType=cv2.LINE_AA)
        if hip:
            cv2.putText(canvas, str(hip), (centre[0] + radius + 2, centre[1]),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.4, colour, 1, cv2.LINE_AA)
    sol = result.solution
    if sol is not None and getattr(sol, "ok", False):
        text = (f"RA {sol.ra_deg:.4f}  Dec {sol.dec_deg:.4f}  roll {sol.roll_deg:.3f} deg  "
                f"{sol.matched} matched")
        cv2.putText(canvas, text, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, _GREEN, 1,
                    cv2.LINE_AA)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"{path}: could not write the overlay PNG")
