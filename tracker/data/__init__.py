"""Data files shipped inside the package, found where the package is installed.

This folder holds the Hipparcos catalogue, ``stars.npz``, with
``stars.npz.sha256`` beside it (README.md here says what it holds and how it
was built), and any pattern database a distributor chooses to ship
(``patterns_*.npz``; none by default: they are built into a cache on first
use, :mod:`tracker.identify.cache`). The files are package data, so an
editable install, ``pip install .`` and a wheel all carry them;
:func:`data_dir` finds them through :mod:`importlib.resources`, never
through the source tree.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from tracker.errors import UserError

__all__ = ["data_dir"]


def data_dir() -> Path:
    """The installed folder of the package's data files.

    pip installs packages unpacked, so this is a real folder; a package run
    from a zip file would not have one, which is said in the error.
    """
    folder = resources.files(__name__)
    if not isinstance(folder, Path):
        raise UserError(f"{folder}: tracker's data files must be on disk (install the "
                        "package with pip, not as a zip file)")
    return folder
