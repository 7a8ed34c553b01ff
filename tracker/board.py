"""The board the tracker runs on: SoC temperature and the firmware's throttling state.

Pure reads of sysfs and ``vcgencmd``; on a machine that has neither (a
laptop, a container) they answer None rather than fail.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

__all__ = ["cpu_temperature_c", "throttled", "THROTTLE_BITS"]

_THERMAL = Path("/sys/class/thermal/thermal_zone0/temp")

# vcgencmd get_throttled bits: now (0-3) and since boot (16-19).
THROTTLE_BITS = {0: "under-voltage", 1: "ARM frequency capped", 2: "throttled",
                 3: "soft temperature limit", 16: "under-voltage occurred",
                 17: "frequency capping occurred", 18: "throttling occurred",
                 19: "soft temperature limit occurred"}


def cpu_temperature_c(path: Path = _THERMAL) -> float | None:
    """SoC temperature in degrees C from sysfs, or None where there is none."""
    try:
        return int(path.read_text().strip()) / 1000.0
    except (OSError, ValueError):
        return None


def throttled() -> int | None:
    """``vcgencmd get_throttled`` as an int (bits: :data:`THROTTLE_BITS`), or None.

    Raises OSError or ValueError when vcgencmd exists but its answer cannot be read.
    """
    tool = shutil.which("vcgencmd")
    if tool is None:
        return None
    try:
        out = subprocess.run([tool, "get_throttled"], capture_output=True, text=True,
                             timeout=5, check=True).stdout
    except subprocess.SubprocessError as exc:
        raise OSError(str(exc)) from None
    return int(out.strip().split("=")[-1], 16)
