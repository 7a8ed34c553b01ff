"""The truth beside a frame: ``<image file name>.truth.json``, as pictures and reports use it.

Two writers: ``tracker simulate`` (tracker.sim.io: ``q`` in our convention
and every rendered star with ``x``, ``y``, ``in_frame``, ``peak_snr``) and
the real frames' astrometry.net solutions (tests/data/real: ``ra_deg``,
``dec_deg``, ``roll_deg`` and the matched stars' ``x``, ``y``).
:func:`read_truth` gives both the same shape: the attitude of the image
centre as a rotation (v_cam = R v_icrs; both give RA, Dec and roll of the
image centre, which a calibrated principal point moves off the boresight)
and the pixel positions of the stars a detector should find (simulated ones
in the frame with peak SNR >= :data:`MIN_PEAK_SNR`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracker.attitude import matrix_from_quat, matrix_from_radec_roll
from tracker.errors import UserError
from tracker.regular_file import FileRefused, read_regular_file
from tracker.sim.io import truth_path

__all__ = ["Truth", "read_truth", "read_truth_json", "MIN_PEAK_SNR"]

MIN_PEAK_SNR = 5.0           # simulated stars fainter than this are not marked
_MAX_TRUTH_BYTES = 16 << 20


@dataclass(frozen=True)
class Truth:
    """``R``: the true attitude of the image centre (v_cam = R v_icrs; None if the file has
    none), as :func:`tracker.attitude.matrix_from_radec_roll` of its RA, Dec and roll;
    ``xy``: (n, 2) star pixels."""

    R: np.ndarray | None
    xy: np.ndarray


def _attitude(data: dict) -> np.ndarray | None:
    """Of the image centre (RA, Dec, roll) when given, else the boresight's ``q``."""
    angles = [data.get(k) for k in ("ra_deg", "dec_deg", "roll_deg")]
    if all(isinstance(a, (int, float)) for a in angles):
        return matrix_from_radec_roll(*(math.radians(a) for a in angles))
    if isinstance(data.get("q"), list) and len(data["q"]) == 4:
        return matrix_from_quat(np.asarray(data["q"], dtype=np.float64))
    return None


def read_truth_json(path: str | Path) -> dict:
    """The object of a truth file (UserError naming it if unreadable or not such an object)."""
    path = Path(path)
    try:
        data = json.loads(read_regular_file(path, _MAX_TRUTH_BYTES))
    except FileRefused as exc:
        raise UserError(f"{path}: {exc}") from None
    except ValueError as exc:
        raise UserError(f"{path}: not JSON ({str(exc)[:60]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("stars", []), list):
        raise UserError(f"{path}: not a truth file (expected an object with a list of stars)")
    return data


def read_truth(image_path: str | Path) -> Truth | None:
    """The truth beside ``image_path``, None if there is none; UserError if it is unusable."""
    path = truth_path(image_path)
    if not path.exists():
        return None
    data = read_truth_json(path)
    try:
        stars = [s for s in data.get("stars", [])
                 if s.get("in_frame", True) and s.get("peak_snr", math.inf) >= MIN_PEAK_SNR]
        xy = np.array([(float(s["x"]), float(s["y"])) for s in stars], dtype=np.float64)
        return Truth(_attitude(data), xy.reshape(-1, 2))
    except (ValueError, TypeError, KeyError, AttributeError) as exc:
        raise UserError(f"{path}: not a truth file ({type(exc).__name__}: "
                        f"{str(exc)[:60]})") from None
