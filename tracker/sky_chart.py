"""A sky chart as SVG: where frames pointed, with their fields of view and the bright stars.

Frames that lie within :data:`ZOOM_LIMIT_DEG` of their mean direction are
drawn in a stereographic projection centred on it (conformal: fields of view
keep their shape), scaled to fit; frames spread wider get the whole sky in a
Hammer-Aitoff projection centred on their mean RA. Either way north is up
and east is left, as the sky is seen from the ground, with an RA/Dec grid,
the catalogue's stars brighter than a limit that suits the scale, and the
IAU names of the brightest (tracker.star_names).

Each frame is a dot at its boresight (class ``boresight``, colour
:data:`BORESIGHT_COLOUR`) and, in order, a line through the boresights; the
fields of view (the directions of the image corners) of up to six of them,
first and last among them, are outlined. The SVG has a fixed size in CSS
pixels, so a screenshot can be checked point by point.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from html import escape

import numpy as np

from tracker.attitude import radec_to_vector, vector_to_radec
from tracker.star_names import STAR_NAMES

__all__ = ["ChartFrame", "SkyProjection", "sky_chart_svg", "ZOOM_LIMIT_DEG",
           "BORESIGHT_COLOUR"]

ZOOM_LIMIT_DEG = 50.0
BORESIGHT_COLOUR = "#ff4fd8"
_FOV_COLOUR = "#5ce65c"
_GRID_COLOUR = "#33415c"
_STAR_COLOUR = "#dfe6ff"
_BACKGROUND = "#0b1020"
_TITLE_H = 34
_OUTLINES = 6           # fields of view outlined at most (evenly spread, first and last)


@dataclass(frozen=True)
class ChartFrame:
    """One solved frame: its name, boresight and field-of-view corners (ICRS unit vectors)."""

    name: str
    boresight: np.ndarray          # (3,)
    corners: np.ndarray            # (4, 3), in order around the image


class SkyProjection:
    """Unit vectors -> chart pixels (x right, y down), north up and east left."""

    def __init__(self, vectors: np.ndarray, width: int, height: int, margin: int = 24):
        self.width, self.height = width, height
        mean = vectors.mean(axis=0)
        self.centre = mean / np.linalg.norm(mean) if np.linalg.norm(mean) > 1e-9 \
            else np.array([1.0, 0.0, 0.0])
        spread = math.degrees(float(np.arccos(np.clip(vectors @ self.centre, -1, 1)).max()))
        self.stereographic = spread <= ZOOM_LIMIT_DEG
        pole = np.array([0.0, 0.0, 1.0])
        east = np.cross(pole, self.centre)
        if np.linalg.norm(east) < 1e-9:             # centred on a pole
            east = np.array([0.0, 1.0, 0.0])
        self.east = east / np.linalg.norm(east)
        self.north = np.cross(self.centre, self.east)
        self.ra0 = float(vector_to_radec(self.centre)[0])
        box_w, box_h = width - 2 * margin, height - _TITLE_H - 2 * margin
        self.cx, self.cy = width / 2.0, _TITLE_H + margin + box_h / 2.0
        if self.stereographic:
            self.radius_deg = max(1.2 * spread, 2.0)
            reach = 2.0 * math.tan(math.radians(self.radius_deg) / 2.0)
            self.scale = min(box_w, box_h) / 2.0 / reach
        else:
            self.radius_deg = 180.0
            self.scale = min(box_w / (4 * math.sqrt(2)), box_h / (2 * math.sqrt(2)))

    def __call__(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, visible) for unit vectors (..., 3)."""
        v = np.asarray(v, dtype=np.float64)
        if self.stereographic:
            cos = v @ self.centre
            k = 2.0 / np.maximum(1.0 + cos, 1e-6)
            x = self.cx - self.scale * k * (v @ self.east)
            y = self.cy - self.scale * k * (v @ self.north)
            visible = cos > math.cos(math.radians(min(1.5 * self.radius_deg, 150.0)))
            return x, y, visible
        ra, dec = vector_to_radec(v)
        lam = np.mod(ra - self.ra0 + math.pi, 2 * math.pi) - math.pi
        z = np.sqrt(1.0 + np.cos(dec) * np.cos(lam / 2.0))
        x = self.cx - self.scale * 2 * math.sqrt(2) * np.cos(dec) * np.sin(lam / 2.0) / z
        y = self.cy - self.scale * math.sqrt(2) * np.sin(dec) / z
        return x, y, np.abs(lam) < math.pi - 1e-3


def _step_deg(radius_deg: float) -> float:
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 15.0, 30.0):
        if radius_deg / step <= 4:
            return step
    return 30.0


def _polyline(proj: SkyProjection, vectors: np.ndarray, colour: str, width: float,
              extra: str = "") -> list[str]:
    """SVG polylines through the visible runs of ``vectors`` (breaks at the map's edge)."""
    x, y, ok = proj(vectors)
    runs, current = [], []
    for i in range(len(vectors)):
        jump = current and abs(x[i] - current[-1][0]) > proj.width / 2
        if not ok[i] or jump:
            if len(current) > 1:
                runs.append(current)
            current = [] if not ok[i] else [(x[i], y[i])]
            continue
        current.append((x[i], y[i]))
    if len(current) > 1:
        runs.append(current)
    return [f'<polyline points="{" ".join(f"{a:.1f},{b:.1f}" for a, b in run)}" fill="none" '
            f'stroke="{colour}" stroke-width="{width}"{extra}/>' for run in runs]


def _grid(proj: SkyProjection) -> list[str]:
    step = _step_deg(proj.radius_deg) if proj.stereographic else 30.0
    out: list[str] = []
    ra_c, dec_c = (math.degrees(a) for a in vector_to_radec(proj.centre))
    span = proj.radius_deg * 1.6
    decs = np.arange(math.floor(max(dec_c - span, -90) / step) * step, min(dec_c + span, 90) + 1e-9,
                     step)
    for dec in decs:
        if abs(dec) >= 90:
            continue
        ra = np.radians(np.linspace(0, 360, 721))
        out += _polyline(proj, radec_to_vector(ra, np.full_like(ra, math.radians(dec))),
                         _GRID_COLOUR, 1)
        x, y, ok = proj(radec_to_vector(math.radians(ra_c), math.radians(dec)))
        if ok:
            out.append(f'<text x="{x + 4:.1f}" y="{y - 4:.1f}" class="grid">{dec:+g}&#176;'
                       "</text>")
    ra_step = step if proj.stereographic else 30.0
    if proj.stereographic and abs(dec_c) + proj.radius_deg < 89:
        ra_step = _step_deg(proj.radius_deg / max(math.cos(math.radians(abs(dec_c))), 0.05))
    for ra in np.arange(0.0, 360.0, ra_step):
        dec = np.radians(np.linspace(-89.5, 89.5, 359))
        out += _polyline(proj, radec_to_vector(np.full_like(dec, math.radians(ra)), dec),
                         _GRID_COLOUR, 1)
        x, y, ok = proj(radec_to_vector(math.radians(ra), math.radians(dec_c)))
        if ok:
            out.append(f'<text x="{x + 4:.1f}" y="{y + 14:.1f}" class="grid">{ra:g}&#176;'
                       "</text>")
    return out


def _stars(proj: SkyProjection, catalogue) -> list[str]:
    if catalogue is None:
        return []
    limit = 3.5 if not proj.stereographic else (6.0 if proj.radius_deg < 10 else 5.0)
    keep = np.asarray(catalogue.mag) <= limit
    vectors, mags, hips = catalogue.vectors[keep], catalogue.mag[keep], catalogue.hip[keep]
    x, y, ok = proj(vectors)
    inside = ok & (x > 0) & (x < proj.width) & (y > _TITLE_H) & (y < proj.height)
    out, named = [], 0
    for i in np.flatnonzero(inside):
        r = max(0.7, 3.4 - 0.55 * float(mags[i]))
        out.append(f'<circle cx="{x[i]:.1f}" cy="{y[i]:.1f}" r="{r:.1f}" fill="{_STAR_COLOUR}"/>')
        name = STAR_NAMES.get(int(hips[i]))
        if name and named < 30:
            named += 1
            out.append(f'<text x="{x[i] + r + 3:.1f}" y="{y[i] + 4:.1f}" class="star">'
                       f"{escape(name)}</text>")
    return out


def sky_chart_svg(frames: list[ChartFrame], catalogue=None, width: int = 900,
                  height: int = 560, title: str = "") -> str:
    """The chart of the module docstring as an SVG element (an empty sky if no frame)."""
    if frames:
        vectors = np.vstack([np.vstack([f.boresight[None], f.corners]) for f in frames])
    else:
        vectors = np.array([[1.0, 0.0, 0.0]])
    proj = SkyProjection(vectors, width, height)
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" id="sky" width="{width}" '
             f'height="{height}" viewBox="0 0 {width} {height}">',
             "<style>text{font:12px sans-serif;fill:#8fa0c0}.star{fill:#c9d3f0}"
             ".frame{fill:#ffd0f4}.title{font:bold 15px sans-serif;fill:#e8ecf8}</style>",
             f'<rect width="{width}" height="{height}" fill="{_BACKGROUND}"/>',
             f'<clipPath id="map"><rect x="0" y="{_TITLE_H}" width="{width}" '
             f'height="{height - _TITLE_H}"/></clipPath>', '<g clip-path="url(#map)">']
    parts += _grid(proj)
    parts += _stars(proj, catalogue)
    outlined = sorted({round(k) for k in np.linspace(0, len(frames) - 1, _OUTLINES)}) \
        if len(frames) > _OUTLINES else range(len(frames))
    for f in (frames[k] for k in outlined):
        ring = np.vstack([f.corners, f.corners[:1]])
        edges = np.vstack([ring[i] + (ring[i + 1] - ring[i]) * t[:, None]
                           for i in range(4) for t in [np.linspace(0, 1, 12)]])
        parts += _polyline(proj, edges / np.linalg.norm(edges, axis=1)[:, None], _FOV_COLOUR,
                           1.2, ' stroke-opacity="0.8"')
    if frames:
        bores = np.array([f.boresight for f in frames])
        parts += _polyline(proj, bores, BORESIGHT_COLOUR, 1, ' stroke-opacity="0.6"')
        x, y, ok = proj(bores)
        for i, f in enumerate(frames):
            if ok[i]:
                parts.append(f'<circle class="boresight" cx="{x[i]:.1f}" cy="{y[i]:.1f}" r="4" '
                             f'fill="{BORESIGHT_COLOUR}"><title>{escape(f.name)}</title>'
                             "</circle>")
        for i in sorted({0, len(frames) - 1}):
            if ok[i]:
                parts.append(f'<text x="{x[i] + 7:.1f}" y="{y[i] - 7:.1f}" class="frame">'
                             f"{escape(frames[i].name)}</text>")
    parts.append("</g>")
    kind = (f"stereographic, {proj.radius_deg:.1f} deg around RA "
            f"{math.degrees(proj.ra0):.1f}, Dec "
            f"{math.degrees(float(vector_to_radec(proj.centre)[1])):+.1f}"
            if proj.stereographic else "whole sky, Hammer-Aitoff")
    parts.append(f'<text x="12" y="22" class="title">{escape(title)}</text>')
    parts.append(f'<text x="{width - 12}" y="22" text-anchor="end">{kind}; north up, east '
                 "left</text>")
    parts.append("</svg>")
    return "\n".join(parts)
