"""``tracker replay --report DIR``: one static HTML page about a replay, for people.

``DIR/index.html`` opens from disk in any browser: no script, no external
asset, nothing fetched. At the top, the sky chart of the solved frames'
boresights and fields of view (tracker.sky_chart); under it the run's
summary; then one table row per frame: its overlay as a thumbnail
(``DIR/thumbs/<name>.jpg``, :data:`THUMB_WIDTH_PX` wide, linking to the full
overlay when ``--overlay`` wrote one), the stars found and identified, the
attitude (RA, Dec, roll of the image centre, sigma) or why there is none,
the error against ``<frame>.truth.json`` when there is one, and the
processing time.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from html import escape
from pathlib import Path

import cv2
import numpy as np

from tracker import __version__
from tracker.attitude import attitude_error, matrix_from_radec_roll
from tracker.camera import CameraModel
from tracker.overlay import REASON_TEXT
from tracker.sky_chart import ChartFrame, sky_chart_svg
from tracker.truth import Truth

__all__ = ["ReplayReport", "THUMB_WIDTH_PX"]

THUMB_WIDTH_PX = 360
_STYLE = """
body{margin:0;background:#0b1020;color:#e8ecf8;font:14px/1.4 sans-serif}
#sky{display:block}
main{padding:12px 16px}
table{border-collapse:collapse;margin-top:8px}
th,td{padding:4px 10px;border-bottom:1px solid #26304a;text-align:left;vertical-align:top}
th{color:#8fa0c0;font-weight:normal}
td.num{text-align:right;font-variant-numeric:tabular-nums}
tr.solved td.result{color:#7ee07e}
tr.unsolved td.result{color:#ff8a8a}
tr.unreadable td.result{color:#ffb347}
img{display:block;border:0}
footer{color:#8fa0c0;margin-top:12px}
"""


@dataclass(frozen=True)
class _Row:
    name: str
    status: str              # solved / unsolved / unreadable
    stars: int
    identified: int
    result: str
    truth: str
    ms: str
    thumb: str | None
    link: str | None


class ReplayReport:
    """Collects frames during a replay and writes the page at the end."""

    def __init__(self, folder: Path, camera: CameraModel, catalogue=None,
                 title: str = "tracker replay"):
        self.folder = Path(folder)
        self.thumbs = self.folder / "thumbs"
        self.thumbs.mkdir(parents=True, exist_ok=True)
        self.camera = camera
        self.catalogue = catalogue
        self.title = title
        self.rows: list[_Row] = []
        self.chart: list[ChartFrame] = []

    def _corners(self, R: np.ndarray) -> np.ndarray:
        w, h = self.camera.width, self.camera.height
        pixels = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        return self.camera.pixel_to_vector(pixels) @ R

    def add_frame(self, key: str, name: str, result, overlay: np.ndarray | None,
                  overlay_path: Path | None = None, truth: Truth | None = None) -> None:
        """One processed frame; ``key`` is its unique name (thumbnail file), ``name`` shown."""
        sol = result.solution
        thumb = None
        if overlay is not None:
            thumb = f"thumbs/{key}.jpg"
            height = max(1, round(overlay.shape[0] * THUMB_WIDTH_PX / overlay.shape[1]))
            small = cv2.resize(overlay, (THUMB_WIDTH_PX, height), interpolation=cv2.INTER_AREA)
            if not cv2.imwrite(str(self.folder / thumb), small, [cv2.IMWRITE_JPEG_QUALITY, 85]):
                raise OSError(f"{self.folder / thumb}: could not write the thumbnail")
        link = os.path.relpath(overlay_path, self.folder) if overlay_path is not None else thumb
        stars = result.detections.count
        truth_text = ""
        if sol is not None and sol.ok:
            identified = int(np.count_nonzero(sol.hip))
            text = (f"RA {sol.ra_deg:.4f}&#176; Dec {sol.dec_deg:+.4f}&#176; roll "
                    f"{sol.roll_deg:.3f}&#176;<br>{sol.matched} matched, &#963; "
                    f"{sol.sigma_cross_arcsec:.1f}&#8243; across, "
                    f"{sol.sigma_roll_arcsec:.0f}&#8243; about")
            status = "solved"
            bore = sol.R[2]
            self.chart.append(ChartFrame(name, bore, self._corners(sol.R)))
            if truth is not None and truth.R is not None:
                centre = matrix_from_radec_roll(*np.radians([sol.ra_deg, sol.dec_deg,
                                                             sol.roll_deg]))
                cross, roll = attitude_error(centre, truth.R)
                truth_text = (f"{math.degrees(cross) * 3600:.1f}&#8243; across<br>"
                              f"{abs(math.degrees(roll)) * 3600:.0f}&#8243; about")
        else:
            identified = 0
            code = (sol.reason if sol is not None else None) or result.solve_reason \
                or result.detections.reason or "unknown"
            text = f"not solved: {escape(REASON_TEXT.get(code, code))}"
            status = "unsolved"
        self.rows.append(_Row(name, status, stars, identified, text, truth_text,
                              f"{result.time_ms:.1f}", thumb, link))

    def add_error(self, name: str, reason: str) -> None:
        """A frame that could not be read."""
        self.rows.append(_Row(name, "unreadable", 0, 0, f"unreadable: {escape(reason)}", "",
                              "", None, None))

    def write(self, summary: list[str]) -> Path:
        """Write ``index.html`` with these summary lines; returns its path."""
        chart = sky_chart_svg(self.chart, self.catalogue,
                              title=f"{self.title}: {len(self.chart)} of {len(self.rows)} "
                                    "frames solved")
        rows = []
        for i, r in enumerate(self.rows, 1):
            picture = ""
            if r.thumb:
                picture = (f'<a href="{escape(r.link or r.thumb)}"><img src="{escape(r.thumb)}" '
                           f'width="{THUMB_WIDTH_PX}" alt="overlay of {escape(r.name)}"></a>')
            rows.append(f'<tr class="{r.status}"><td class="num">{i}</td><td>{picture}'
                        f"{escape(r.name)}</td><td class=\"num\">{r.stars}</td>"
                        f'<td class="num">{r.identified}</td><td class="result">{r.result}</td>'
                        f'<td>{r.truth}</td><td class="num">{r.ms}</td></tr>')
        page = "\n".join([
            "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
            f"<title>{escape(self.title)}</title><style>{_STYLE}</style></head><body>",
            chart, "<main>",
            *(f"<p>{escape(line.removeprefix('replay: '))}</p>" for line in summary),
            "<table><thead><tr><th>#</th><th>frame</th><th>stars</th><th>identified</th>"
            "<th>result (image centre)</th><th>vs truth</th><th>ms</th></tr></thead><tbody>",
            *rows, "</tbody></table>",
            f"<footer>tracker {escape(__version__)}; camera {self.camera.width}x"
            f"{self.camera.height} px, {math.degrees(self.camera.fov_diagonal_rad):.2f}&#176; "
            "diagonal</footer>", "</main></body></html>", ""])
        path = self.folder / "index.html"
        path.write_text(page, encoding="utf-8")
        return path
