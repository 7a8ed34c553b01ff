"""The PNG of ``tracker bench detect``, drawn with OpenCV (no plotting library).

Two stacked panels over the data sets (x axis): recall of detectable stars
(linear, 0..1) and mean Euclidean error in px (log scale, 0.01..10), one
coloured line per method with a legend.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["plot_sets"]

_COLOURS = [(200, 60, 20), (30, 30, 220), (20, 160, 20), (0, 150, 230), (160, 30, 160),
            (120, 120, 0), (90, 90, 90), (0, 0, 0), (200, 120, 200)]
_W, _PANEL, _LEFT, _TOP, _GAP = 1400, 330, 90, 40, 140


def _panel(img, top, title, ticks, to_y, sets, series, methods):
    right = _W - 200
    cv2.putText(img, title, (_LEFT, top - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                cv2.LINE_AA)
    cv2.rectangle(img, (_LEFT, top), (right, top + _PANEL), (0, 0, 0), 1)
    for value, label in ticks:
        y = top + int(round(to_y(value)))
        cv2.line(img, (_LEFT, y), (right, y), (220, 220, 220), 1)
        cv2.putText(img, label, (8, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
    n = len(sets)
    xs = [_LEFT + int((i + 0.5) * (right - _LEFT) / n) for i in range(n)]
    for m, method in enumerate(methods):
        colour = _COLOURS[m % len(_COLOURS)]
        pts = [(x, top + int(round(to_y(v)))) for x, v in zip(xs, series[method], strict=True)
               if v is not None and math.isfinite(v)]
        for a, b in zip(pts[:-1], pts[1:], strict=False):
            cv2.line(img, a, b, colour, 2, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 3, colour, -1, cv2.LINE_AA)
    return xs


def plot_sets(path: str, sets: list[str], methods: list[str], recall: dict,
              error: dict, title: str) -> None:
    """Write the PNG; ``recall``/``error`` map method -> one value (or None) per set."""
    height = _TOP + 2 * _PANEL + _GAP + 240
    img = np.full((height, _W, 3), 255, np.uint8)
    cv2.putText(img, title, (_LEFT, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1,
                cv2.LINE_AA)

    def recall_y(v):
        return (1.0 - min(max(v, 0.0), 1.0)) * _PANEL

    def error_y(v):
        v = min(max(v, 0.01), 10.0)
        return (1.0 - (math.log10(v) + 2.0) / 3.0) * _PANEL

    top1 = _TOP + 20
    _panel(img, top1, "recall of detectable stars", [(t, f"{t:.1f}") for t in
                                                     (0.0, 0.25, 0.5, 0.75, 1.0)],
           recall_y, sets, recall, methods)
    top2 = top1 + _PANEL + 60
    xs = _panel(img, top2, "mean Euclidean error, px (log)",
                [(t, f"{t:g}") for t in (0.01, 0.1, 1.0, 10.0)], error_y, sets, error, methods)
    for x, name in zip(xs, sets, strict=True):
        label = np.full((14, 230, 3), 255, np.uint8)
        cv2.putText(label, name, (0, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (0, 0, 0), 1,
                    cv2.LINE_AA)
        rotated = cv2.rotate(label, cv2.ROTATE_90_COUNTERCLOCKWISE)
        y0 = top2 + _PANEL + 6
        h, w = rotated.shape[:2]
        x0 = max(0, min(_W - w, x - w // 2))
        img[y0:y0 + h, x0:x0 + w] = np.minimum(img[y0:y0 + h, x0:x0 + w], rotated)
    for m, method in enumerate(methods):
        y = top1 + 20 + 22 * m
        cv2.line(img, (_W - 185, y), (_W - 155, y), _COLOURS[m % len(_COLOURS)], 3)
        cv2.putText(img, method, (_W - 148, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1,
                    cv2.LINE_AA)
    cv2.imwrite(path, img)
