"""What machine a benchmark ran on, for the head of every report."""

from __future__ import annotations

import os
import platform

__all__ = ["describe_machine"]


def _cpu_model() -> str:
    """The CPU's name: x86 'model name', else the Arm board's 'Model' / 'Hardware'."""
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                fields.setdefault(key.strip().lower(), value.strip())
    except OSError:
        pass
    for key in ("model name", "model", "hardware"):
        if fields.get(key) and not fields[key].isdigit():
            return fields[key]
    return platform.processor() or platform.machine()


def describe_machine() -> dict:
    """CPU model, core count, memory, OS and Python, as a flat dict of strings."""
    try:
        mem_gib = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        mem_gib = float("nan")
    return {
        "cpu": _cpu_model(),
        "cores": str(os.cpu_count()),
        "memory_gib": f"{mem_gib:.1f}",
        "machine": platform.machine(),
        "os": platform.platform(),
        "python": platform.python_version(),
    }
