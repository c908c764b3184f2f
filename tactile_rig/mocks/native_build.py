"""Native code a mock needs, built on demand into a cache keyed by a hash of its sources.

The scale's firmware and its simulated board (:mod:`tactile_rig.mocks.scale_firmware`) and the V4L2
preload library (:mod:`tactile_rig.mocks.v4l2.build`) are compiled on this machine, never committed:
each build goes to ``<cache>/<kind>/<key>``, where ``<cache>`` is ``$TACTILE_RIG_CACHE``, else
``$XDG_CACHE_HOME/tactile-rig``, else ``~/.cache/tactile-rig``, and ``<key>`` hashes what the product
depends on (sources, flags, compiler versions), so a changed source builds anew and an unchanged one
is reused. A build runs in a temporary folder beside its final place and is renamed into place, so a
half-finished build is never used and two processes building the same key at once both end up with
one complete copy.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Callable, Iterable, Sequence

from tactile_rig.core.errors import RigError

__all__ = ["build_key", "cache_root", "cached_build", "run_build_command", "tool_version"]

KEY_LENGTH = 16  # hex digits of the SHA-256 that name a build's folder
_TAIL_LINES = 15  # compiler output kept in a build error

_locks: dict[str, threading.Lock] = {}
_locks_guard = threading.Lock()


def cache_root() -> Path:
    """Where native builds go: ``$TACTILE_RIG_CACHE``, else ``$XDG_CACHE_HOME/tactile-rig``, else
    ``~/.cache/tactile-rig``."""
    env = os.environ.get("TACTILE_RIG_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "tactile-rig"


def tool_version(cmd: str) -> str:
    """The first line ``cmd --version`` prints (``?`` when it cannot run): part of a build key, so a
    compiler upgrade rebuilds."""
    try:
        return subprocess.run([cmd, "--version"], capture_output=True, text=True, timeout=30).stdout.split("\n")[0]
    except (OSError, subprocess.SubprocessError):
        return "?"


def build_key(files: Iterable[Path], extras: Iterable[str] = ()) -> str:
    """The cache key of a build: the hash of each file's name and bytes, then of each extra text
    (flags, tool versions, directories)."""
    h = hashlib.sha256()
    for path in files:
        h.update(path.name.encode())
        h.update(path.read_bytes())
    for text in extras:
        h.update(text.encode())
    return h.hexdigest()[:KEY_LENGTH]


def run_build_command(cmd: Sequence[str], *, timeout_s: float, error: type[RigError], device: str) -> str:
    """Run one build command; its stdout, or ``error`` (a :class:`RigError` subclass) naming the
    command and the last lines it printed, or that it ran over ``timeout_s``."""
    line = " ".join(cmd)
    try:
        done = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise error(f"'{line}' took over {timeout_s:g} s", device=device) from None
    if done.returncode != 0:
        tail = "\n".join((done.stdout + done.stderr).strip().splitlines()[-_TAIL_LINES:])
        raise error(f"'{line}' failed:\n{tail}", device=device)
    return done.stdout


def _lock_for(kind: str) -> threading.Lock:
    with _locks_guard:
        return _locks.setdefault(kind, threading.Lock())


def cached_build(kind: str, key: str, make: Callable[[Path], None], *, complete: str,
                 force: bool = False) -> Path:
    """The folder ``<cache>/<kind>/<key>``, built by ``make(folder)`` unless the file ``complete``
    (relative to it) says an earlier build finished there. ``force`` deletes and rebuilds it. One
    build per kind at a time in this process; across processes the rename decides."""
    with _lock_for(kind):
        out = cache_root() / kind / key
        if force and out.exists():
            shutil.rmtree(out)
        if (out / complete).is_file():
            return out
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=out.parent))
        try:
            make(tmp)
            try:
                os.rename(tmp, out)  # atomic: a concurrent build of the same key loses the race cleanly
            except OSError:
                shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return out
