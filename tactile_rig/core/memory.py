"""The process keeps the memory it frees: per-frame buffers are not faulted in afresh each frame.

A 240x320 height map is 0.3 MB; NumPy and OpenCV allocate a few of them per frame or per
registration. glibc hands blocks that large back to the system when they are freed (mmap, or a trim
of the heap top) and the next frame faults every page in again: measured here, a third of a fresh
registration's map preparation and a quarter of ``gelsight height``'s per-frame time. Raising the
trim and mmap thresholds keeps them in the heap. A process-wide setting: the CLI's per-frame
commands and the speed measurements turn it on; a library user may call :func:`keep_freed_memory`
(or set ``MALLOC_TRIM_THRESHOLD_`` / ``MALLOC_MMAP_THRESHOLD_``) in their own process.
"""

from __future__ import annotations

import ctypes
import platform

__all__ = ["keep_freed_memory", "TRIM_THRESHOLD_BYTES", "MMAP_THRESHOLD_BYTES"]

# Keep up to 64 MB of freed heap; blocks below 16 MB come from that heap (glibc mallopt).
TRIM_THRESHOLD_BYTES = 64 << 20
MMAP_THRESHOLD_BYTES = 16 << 20
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_applied = False


def keep_freed_memory() -> bool:
    """Set glibc's trim and mmap thresholds for this process (once); True when they are set, False on
    another C library or OS (nothing to do there)."""
    global _applied
    if _applied:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(None)
        ok = libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1
        ok = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1 and ok
    except (OSError, AttributeError):
        return False
    _applied = ok
    return ok
