"""Extract the centroid lists of the real frames beside this script (run once).

Usage: .venv/bin/python tests/data/real/make_centroids.py

Writes ``<source>/<image>.centroids.json`` beside each image: the 60
brightest sources found by SEP (Barbary 2016, the Source Extractor
algorithms; a test-time dependency of this project) after a 32-px mesh
background subtraction, 5-sigma threshold (local noise), at least 4 connected pixels,
keeping only star-like sources (axis ratio a/b <= 1.6, semi-major axis <= 5 px;
tree.jpg's branches are otherwise its brightest "stars"). The
openstartracker optics are sharper (PSF sigma ~0.7 px): SEP's default 3x3
smoothing kernel spreads their stars below its per-pixel threshold, so those
frames are extracted unsmoothed with at least 2 connected pixels (with the
kernel, none of img0's astrometry.net stars is among the 60 brightest
sources; without it, 7 of its 9 are).
Positions are in the project's convention (x = column, y = row, (0, 0) the
centre of the top-left pixel; SEP uses the same). Every image with a
``<image>.truth.json`` beside it gets a list (README.md here gives their
sources and licences).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import sep

from tracker.capture.imagefile import read_image

KEEP = 60
MAX_ELONGATION = 1.6
MAX_AXIS_PX = 5.0
DEFAULT = {"minarea": 4}
# per source: sharp optics are extracted without smoothing (module docstring)
SETTINGS = {"openstartracker": {"minarea": 2, "filter_kernel": None}}


def extract(path: Path, settings: dict) -> list[dict]:
    image = np.ascontiguousarray(read_image(path)[0], dtype=np.float32)
    bkg = sep.Background(image, bw=32, bh=32)
    data = image - bkg
    objects = sep.extract(data, 5.0, err=bkg.rms(), **settings)
    objects = objects[(objects["a"] <= MAX_ELONGATION * objects["b"])
                      & (objects["a"] <= MAX_AXIS_PX)]
    objects = objects[np.argsort(-objects["flux"])][:KEEP]
    return [{"x": round(float(o["x"]), 3), "y": round(float(o["y"]), 3),
             "flux": round(float(o["flux"]), 1)} for o in objects]


def main() -> int:
    for truth in sorted(Path(__file__).parent.glob("*/*.truth.json")):
        image = truth.with_name(truth.name.removesuffix(".truth.json"))
        settings = SETTINGS.get(truth.parent.name, DEFAULT)
        stars = extract(image, settings)
        meta = json.loads(truth.read_text())
        smoothing = "" if "filter_kernel" not in settings else ", no smoothing kernel"
        image.with_name(f"{image.name}.centroids.json").write_text(json.dumps(
            {"image": image.name, "width": meta["width"], "height": meta["height"],
             "method": f"sep 5 local sigma, minarea {settings['minarea']}{smoothing}, 32 px "
                       "background mesh, a/b <= 1.6, a <= 5 px", "stars": stars},
            indent=0) + "\n")
        print(f"{image.name}: {len(stars)} centroids")
    return 0


if __name__ == "__main__":
    sys.exit(main())
