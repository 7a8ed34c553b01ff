"""The FC's C code (tools/fc) built as the ICD promises, and its decoder's output from Python.

:func:`build` compiles with gcc: C99, every warning an error. :func:`python_lines`
prints what ``st_dump`` prints for a byte stream, from the Python decoder's values,
and :func:`same_word` compares one ``field=value`` word of each (binary32 fields
as binary32).
"""

from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tracker.protocol.decoder import StreamDecoder

FC = Path(__file__).resolve().parents[1] / "tools" / "fc"
GCC = shutil.which("gcc")
FLAGS = ("-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2")
needs_gcc = pytest.mark.skipif(GCC is None, reason="gcc not found: the FC's C code cannot be "
                                                   "compiled here")


def build(folder: Path, name: str, *sources: Path) -> Path:
    """``folder/name`` compiled from ``sources`` (and tools/fc's headers)."""
    exe = folder / name
    subprocess.run([GCC, *FLAGS, "-I", str(FC), "-o", str(exe), *map(str, sources)],
                   check=True, capture_output=True, text=True)
    return exe


def python_lines(data: bytes) -> list[list[str]]:
    """st_dump's lines (as words) for the telemetry in ``data``, from the Python decoder."""
    lines = []
    for p in StreamDecoder().feed(data):
        words = [str(p.seq), p.name]
        for f in p.msg.fields:
            words.append(f"{f.name}={p.values[f.name]!r}")
        if p.items is not None:
            for k, row in enumerate(p.items):
                words += [f"{f.name}[{k}]={row[f.name].item()!r}" for f in p.msg.item]
        lines.append(words)
    return lines


def same_word(c_word: str, py_word: str, f32: bool) -> bool:
    """The two ``name=value`` words agree (binary32 values compared as binary32)."""
    name, c_val = c_word.split("=")
    py_name, py_val = py_word.split("=")
    if name != py_name:
        return False
    if not f32:
        return int(c_val) == int(py_val)
    a, b = float(c_val), float(py_val)
    # %.9g round-trips a binary32 exactly, so compare as float32.
    return (np.float32(a) == np.float32(b) and math.copysign(1, a) == math.copysign(1, b)) or \
        (math.isnan(a) and math.isnan(b))
