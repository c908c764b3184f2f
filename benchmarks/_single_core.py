"""One core for a benchmark that measures time per frame: import this first (before numpy loads) and
BLAS and OpenMP run one thread; :func:`pin_one_core` pins the process and its children to one CPU.

Usage in a benchmark::

    import _single_core  # noqa: F401  (first: one BLAS/OpenMP thread before numpy loads)
    ...
    from _single_core import pin_one_core
    cpu = None if args.no_pin else pin_one_core()
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")


def pin_one_core() -> int | None:
    """Pin this process (and the children it starts) to the first CPU it may use; that CPU, or None
    where the system cannot pin."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu
