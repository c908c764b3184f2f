"""Run a function in a fresh Python process started with a given environment, and get its result.

A preload library has to be in the environment when a process starts, so a client of an emulated
camera (OpenCV, :class:`~tactile_rig.drivers.camera.OpenCVSource`) runs in a child process started
with :attr:`~tactile_rig.mocks.v4l2.server.V4L2Camera.env`::

    value = run_in_child(read_frames, cam.port, 30, env=cam.env)

``fn`` and its arguments are pickled (``fn`` by reference: a module-level function the child can
import; the parent's ``sys.path`` is handed over first), the child's return value is pickled back.
An exception raised in the child is raised again in the parent with the child's traceback as a
note; one that cannot be pickled, a child that dies, or one that outlives ``timeout_s`` raises
:class:`ChildFailed` with the end of the child's standard error.
"""

from __future__ import annotations

import os
import pickle
import select
import subprocess
import sys
import time
import traceback
from typing import Any, Callable, Mapping

_STDERR_TAIL = 4000


class ChildFailed(RuntimeError):
    """The child process died, timed out, or raised something that could not come back."""


def run_in_child(fn: Callable[..., Any], *args: Any, env: Mapping[str, str] | None = None,
                 timeout_s: float = 120.0, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` in a new interpreter whose environment is ours updated with ``env``."""
    request = pickle.dumps((list(sys.path), pickle.dumps((fn, args, kwargs))))
    child_env = dict(os.environ)
    child_env.update(env or {})
    r, w = os.pipe()
    try:
        proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(w)], stdin=subprocess.PIPE,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=child_env,
                                pass_fds=(w,))
    except BaseException:
        os.close(r)
        raise
    finally:
        os.close(w)
    try:
        return _collect(proc, r, request, timeout_s, getattr(fn, "__qualname__", repr(fn)))
    finally:
        os.close(r)
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def _collect(proc: subprocess.Popen[bytes], r: int, request: bytes, timeout_s: float, name: str) -> Any:
    assert proc.stdin is not None and proc.stderr is not None
    try:
        proc.stdin.write(request)
        proc.stdin.close()
    except BrokenPipeError:
        pass
    deadline = time.monotonic() + timeout_s
    chunks: list[bytes] = []
    err: list[bytes] = []
    open_fds = {r: chunks, proc.stderr.fileno(): err}
    while open_fds:
        left = deadline - time.monotonic()
        if left <= 0:
            proc.kill()
            raise ChildFailed(f"{name} did not finish within {timeout_s:g} s in the child process; "
                              f"its stderr ends:\n{_tail(err)}")
        ready, _, _ = select.select(list(open_fds), [], [], left)
        for fd in ready:
            data = os.read(fd, 1 << 16)
            if data:
                open_fds[fd].append(data)
            else:
                del open_fds[fd]
    proc.wait()
    payload = b"".join(chunks)
    if not payload:
        raise ChildFailed(f"{name}: the child process exited with {proc.returncode} without a result; "
                          f"its stderr ends:\n{_tail(err)}")
    status, body = pickle.loads(payload)
    if status == "ok":
        return body
    exc_bytes, kind, message, tb = body
    exc: BaseException | None = None
    if exc_bytes is not None:
        try:
            exc = pickle.loads(exc_bytes)
        except Exception:  # noqa: BLE001  (an exception type the parent cannot rebuild)
            exc = None
    if exc is None:
        raise ChildFailed(f"{name} raised {kind}: {message}\n{tb}")
    exc.add_note(f"raised in the child process:\n{tb}")
    raise exc


def _tail(err: list[bytes]) -> str:
    return b"".join(err)[-_STDERR_TAIL:].decode("utf-8", "replace")


# The child's whole program: the standard library only, so that the child imports nothing but what
# ``fn`` needs (this package's own import would cost the child half a second).
_CHILD = """
import os, pickle, sys, traceback
out = os.fdopen(int(sys.argv[1]), "wb")
try:
    path, inner = pickle.loads(sys.stdin.buffer.read())
    sys.path[:] = path
    fn, args, kwargs = pickle.loads(inner)
    data = pickle.dumps(("ok", fn(*args, **kwargs)))
except BaseException as exc:
    tb = traceback.format_exc()
    try:
        exc_bytes = pickle.dumps(exc)
        pickle.loads(exc_bytes)
    except Exception:
        exc_bytes = None
    data = pickle.dumps(("error", (exc_bytes, type(exc).__qualname__, str(exc), tb)))
out.write(data)
out.close()
"""
