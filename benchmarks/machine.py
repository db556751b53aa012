"""The machine a benchmark ran on, as its results file records it: the CPU model (hosts of the
same size differ by as much as the changes measured), core count, Python and platform."""
from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_info(field: str) -> str | None:
    """The first value of ``field`` in ``/proc/cpuinfo`` (None where there is no such file
    or field)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(field):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; ``platform.processor()`` elsewhere)."""
    return cpu_info("model name") or platform.processor() or "unknown"


def machine() -> dict:
    return {"cpu": cpu_model(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform()}
