"""Write a simulated frame: PNG image plus its truth JSON.

``write_frame(frame, folder, "f0001")`` writes ``folder/f0001.png`` (16-bit
PNG holding the ADC counts for bit depths above 8, 8-bit otherwise) and
``folder/f0001.png.truth.json`` (the image file name plus ``.truth.json``,
as in data/real/), whose ``"frame"`` key is ``"f0001.png"``.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2

from tracker.sim.frame import SimFrame

__all__ = ["write_frame", "truth_path"]


def truth_path(image_path: str | Path) -> Path:
    """Where the truth of an image file lives: ``<image file name>.truth.json``."""
    image_path = Path(image_path)
    return image_path.with_name(image_path.name + ".truth.json")


def write_frame(frame: SimFrame, folder: str | Path, name: str) -> Path:
    """Write ``<folder>/<name>.png`` and its truth JSON; returns the PNG's path.

    The folder is created if needed. ``frame.truth["frame"]`` is set to the
    PNG's file name.
    """
    folder = Path(folder)
    if not name or Path(name).name != name:
        raise ValueError(f"frame name must be a plain file name; got {name!r}")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.png"
    if not cv2.imwrite(str(path), frame.image):
        raise OSError(f"{path}: could not write the PNG")
    frame.truth["frame"] = path.name
    truth_path(path).write_text(json.dumps(frame.truth, indent=1, allow_nan=False) + "\n",
                                encoding="utf-8")
    return path
