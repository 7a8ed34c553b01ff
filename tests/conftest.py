"""Shared pytest set-up: the ``hardware`` marker and the pattern-database cache.

Tests marked ``@pytest.mark.hardware`` need the Raspberry Pi (camera, UART).
They are skipped unless pytest is given ``--hardware`` or the environment has
``TRACKER_HARDWARE=1``; on the Pi run ``pytest --hardware -m hardware`` on the files
that hold them (README, "On-device checks"): the Pi's venv has pytest but not the
peers (sep, cedar-solve) other test files import.

Pattern databases the tests need are built on first use into
``build/test-cache/startracker`` (not the user's cache), and reused by later
runs; the tests and the commands they start find it through XDG_CACHE_HOME.
"""

import os
from pathlib import Path

import pytest

os.environ["XDG_CACHE_HOME"] = str(Path(__file__).resolve().parents[1] / "build" / "test-cache")
os.environ.pop("STATE_DIRECTORY", None)


def pytest_addoption(parser):
    parser.addoption("--hardware", action="store_true",
                     help="run tests marked hardware (on the Raspberry Pi)")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--hardware") or os.environ.get("TRACKER_HARDWARE") == "1":
        return
    skip = pytest.mark.skip(reason="needs the Raspberry Pi: give --hardware or "
                                   "TRACKER_HARDWARE=1")
    for item in items:
        if "hardware" in item.keywords:
            item.add_marker(skip)
