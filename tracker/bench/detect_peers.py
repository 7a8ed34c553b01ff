"""The two peers of ``tracker bench detect``, imported lazily, in our pixel convention.

* ``sep`` (Source Extractor as a library), as its tutorial runs it:
  ``Background``, subtract, ``extract``, then windowed positions ``winpos``
  with sigma = 2 / 2.35 x the half-flux radius; but extracting at
  ``SEP_THRESHOLD`` = 5 x the global RMS, not the tutorial's 1.5 (which on
  these frames returns thousands of noise peaks and takes seconds per
  frame, mostly in ``winpos``). SEP's coordinates already put 0 at the
  centre of the first pixel.
* ``tetra3``: cedar-solve's ``get_centroids_from_image`` with its defaults.
  It returns (y, x) with 0.5 at the centre of the top-left pixel; we swap
  and subtract 0.5.

Each returns (x, y) arrays; a peer that fails on a frame returns nothing
for it and the error is counted.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PEERS", "SEP_THRESHOLD", "peer_available"]

SEP_THRESHOLD = 5.0


def _sep(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import sep

    data = np.ascontiguousarray(image, dtype=np.float64)
    bkg = sep.Background(data)
    bkg.subfrom(data)
    objects = sep.extract(data, SEP_THRESHOLD, err=bkg.globalrms)
    if len(objects) == 0:
        return np.zeros(0), np.zeros(0)
    radius, _ = sep.flux_radius(data, objects["x"], objects["y"], 6.0 * objects["a"], 0.5,
                                subpix=5)
    sig = 2.0 / 2.35 * np.maximum(radius, 0.3)
    x, y, _ = sep.winpos(data, objects["x"], objects["y"], sig)
    return np.asarray(x), np.asarray(y)


def _tetra3(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import tetra3

    centroids = np.asarray(tetra3.get_centroids_from_image(image)).reshape(-1, 2)
    return centroids[:, 1] - 0.5, centroids[:, 0] - 0.5


PEERS = {"sep": _sep, "tetra3": _tetra3}


def peer_available(name: str) -> bool:
    """Whether the peer's package imports here."""
    try:
        __import__({"sep": "sep", "tetra3": "tetra3"}[name])
    except ImportError:
        return False
    return True
