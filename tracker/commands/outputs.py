"""Where commands write: folders and files named by options, checked before any work starts.

A folder option naming an existing file (``--overlay out.png``), a file
option naming a folder (``--jsonl results/``) or a place that cannot be
created is a :class:`~tracker.errors.UserError` naming the option, said
before the first frame rather than as a traceback after it.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import IO

from tracker.errors import UserError

__all__ = ["output_folder", "open_output", "close_output"]


def output_folder(path: str | Path, option: str) -> Path:
    """The folder ``path`` (created with its parents if missing) for ``option``'s output."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{option} {folder}: is a file, expected a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{option} {folder}: cannot create the folder "
                        f"({exc.strerror or exc})") from None
    return folder


def open_output(path: str | Path, option: str, mode: str = "w") -> IO:
    """A file opened for writing, ``mode`` "w", "a" or "ab" (``-``: standard output).

    Missing folders on the way are created, as for folder options. Standard
    output is returned as is and must not be closed by the caller.
    """
    if str(path) == "-":
        return sys.stdout.buffer if "b" in mode else sys.stdout
    target = Path(path)
    if target.is_dir():
        raise UserError(f"{option} {target}: is a folder, expected a file name")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        if "b" in mode:
            return open(target, mode)
        return open(target, mode, encoding="utf-8")
    except OSError as exc:
        raise UserError(f"{option} {target}: cannot write ({exc.strerror or exc})") from None


def close_output(fh: IO | None) -> None:
    """Close what :func:`open_output` opened (never standard output)."""
    if fh is not None and fh not in (sys.stdout, sys.stdout.buffer):
        fh.close()
