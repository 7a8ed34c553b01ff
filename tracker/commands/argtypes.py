"""Number arguments checked where argparse reads them: a bad one is a usage error, exit 2.

``type=float`` alone lets ``nan``, ``inf`` and negative values through to
code that divides by them or sleeps for them. Each function here is an
argparse ``type``: it returns the value or raises
:class:`argparse.ArgumentTypeError` with what was expected.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["count", "positive_count", "non_negative", "positive", "finite"]


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"found {text!r}, expected a whole number") from None


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"found {text!r}, expected a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"found {text!r}, expected a finite number")
    return value


def _at_least(parse, low: float, strict: bool, expected: str):
    """An argparse type: ``parse`` then require value >= low (> low if ``strict``)."""
    def check(text: str):
        value = parse(text)
        if value < low or (strict and value == low):
            raise argparse.ArgumentTypeError(f"found {text}, expected {expected}")
        return value
    return check


count = _at_least(_int, 0, False, "0 or more")                  # a whole number >= 0
positive_count = _at_least(_int, 1, False, "1 or more")         # a whole number >= 1
non_negative = _at_least(_float, 0.0, False, "0 or more")       # a finite number >= 0
positive = _at_least(_float, 0.0, True, "more than 0")          # a finite number > 0
finite = _float                                                  # any finite number
