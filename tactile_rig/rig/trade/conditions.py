"""The conditions a trade table was measured under: machine, cores, load, library versions.

Speeds are only comparable under like conditions; a table carries them so a reader (and the docs
page) can tell a quiet 2-core run from a loaded one.
"""

from __future__ import annotations

import os
import platform
import sys
from datetime import datetime, timezone
from typing import Any


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for mod in ("numpy", "scipy", "cv2"):
        m = sys.modules.get(mod)
        if m is None:
            try:
                m = __import__(mod)
            except ImportError:
                continue
        out[mod] = str(getattr(m, "__version__", "?"))
    return out


def _opencv_threads() -> int | None:
    cv2 = sys.modules.get("cv2")
    return int(cv2.getNumThreads()) if cv2 is not None else None


def measure_conditions() -> dict[str, Any]:
    """Machine, cores (present and usable), 1-minute load average, versions and a UTC time stamp."""
    try:
        load = round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        load = None
    return {
        "machine": f"{_cpu_model()} ({platform.system()} {platform.machine()})",
        "cores": os.cpu_count() or 1,
        "usable_cores": _usable_cores(),
        "load_1min": load,
        "opencv_threads": _opencv_threads(),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "versions": _versions(),
        "utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }


def conditions_text(c: dict[str, Any]) -> str:
    """One line: machine, cores, load before/after, quick or full, wall time."""
    parts = [str(c.get("machine", "?")), f"{c.get('usable_cores', '?')}/{c.get('cores', '?')} cores usable"]
    if c.get("load_1min") is not None:
        load = f"load {c['load_1min']}"
        if c.get("load_1min_after") is not None:
            load += f" → {c['load_1min_after']}"
        parts.append(load)
    if c.get("keep_freed_memory"):
        parts.append("freed memory kept (as the CLI runs)")
    if "quick" in c:
        parts.append("--quick" if c["quick"] else "full run")
    if "seed" in c:
        parts.append(f"seed {c['seed']}")
    if c.get("wall_s") is not None:
        parts.append(f"{c['wall_s']} s wall")
    if c.get("utc"):
        parts.append(str(c["utc"]))
    return "; ".join(parts)
