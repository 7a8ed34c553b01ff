"""The one rule for turning the files and folders a user names into a list of input files.

Used by ``tracker replay``, ``run --replay``, ``record --replay``,
``validate`` and ``calibrate``, so they all treat paths the same way:

* a file named is taken as it is, in the order given, whatever its suffix
  (reading it says what is wrong with it);
* a folder named gives the regular files directly inside it whose names end
  with one of ``suffixes`` (case-insensitive), sorted by name; subfolders,
  named pipes and devices inside it are passed over;
* with ``companion`` (e.g. ``".centroids.json"``), ``X`` is left out when
  ``X`` + companion is among the inputs too: one frame, once;
* a file reached twice (named, and inside a folder named) is listed once,
  where it first came;
* a path that does not exist, a named pipe, a device, or a folder with no
  matching file is a :class:`~tracker.errors.UserError` naming it (one line,
  exit status 2), before any file is read.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from tracker.errors import UserError
from tracker.regular_file import describe_kind

__all__ = ["expand_inputs"]


def _matches(name: str, suffixes: Sequence[str]) -> bool:
    lowered = name.lower()
    return any(lowered.endswith(s) for s in suffixes)


def _folder_files(folder: Path, suffixes: Sequence[str]) -> list[Path]:
    return sorted(f for f in folder.iterdir() if f.is_file() and _matches(f.name, suffixes))


def expand_inputs(paths: Sequence[str | os.PathLike], suffixes: Sequence[str], *,
                  what: str = "image files", companion: str | None = None) -> list[Path]:
    """Files named, plus the matching files inside folders named; see the module docstring."""
    if not paths:
        raise UserError(f"no {what} given")
    out: list[Path] = []
    for path in map(Path, paths):
        try:
            mode = path.stat().st_mode
        except FileNotFoundError:
            raise UserError(f"{path}: no such file or folder") from None
        except OSError as exc:
            raise UserError(f"{path}: cannot look at it ({exc.strerror or exc})") from None
        if path.is_dir():
            try:
                found = _folder_files(path, suffixes)
            except OSError as exc:
                raise UserError(f"{path}: cannot list the folder ({exc.strerror or exc})") \
                    from None
            if not found:
                raise UserError(f"{path}: no {what} ({', '.join(suffixes)}) in this folder")
            out.extend(found)
        elif path.is_file():
            out.append(path)
        else:
            raise UserError(f"{path}: {describe_kind(mode)}, expected one of the {what} "
                            f"({', '.join(suffixes)}) or a folder of them")
    return _once(out, companion)


def _once(files: list[Path], companion: str | None) -> list[Path]:
    """``files`` without repeats, and without the X whose X + companion is listed."""
    listed = {str(f.resolve()) for f in files}
    seen: set[str] = set()
    out = []
    for f in files:
        key = str(f.resolve())
        if key in seen or (companion and key + companion in listed):
            continue
        seen.add(key)
        out.append(f)
    return out
