"""Device processes of the rehearsal bench: start one, read the JSON line it prints, stop it."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from tactile_rig.core.errors import NotConnected
from tactile_rig.mocks.v4l2 import build as v4l2_build
from tactile_rig.mocks.v4l2.server import ENV_DIR

START_TIMEOUT_S = 60.0  # a cold start imports numpy, OpenCV and the scene under a loaded machine

# Runs a module as ``python -m`` would, after asking Linux to send it SIGTERM when the process that
# started it dies (prctl PR_SET_PDEATHSIG), so a rehearsal killed outright (SIGKILL, a test timeout)
# leaves no device behind. Best effort: elsewhere the module just runs.
_LAUNCHER = (
    "import ctypes, runpy, signal, sys\n"
    "try:\n"
    "    ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGTERM), 0, 0, 0)\n"
    "except (OSError, AttributeError):\n"
    "    pass\n"
    "module = sys.argv[1]\n"
    "sys.argv = [module] + sys.argv[2:]\n"
    "runpy.run_module(module, run_name='__main__', alter_sys=True)\n"
)


@dataclass
class DeviceProcess:
    """One device served by its own process; ``info`` is the JSON line it printed (ports, format)."""

    name: str
    argv: list[str]
    proc: subprocess.Popen | None = None
    info: dict[str, Any] = field(default_factory=dict)
    log_path: Path | None = None  # the process's stderr (a pipe nobody reads would fill and stall it)

    def start(self, log_dir: str | Path | None = None) -> "DeviceProcess":
        """Launch the process (does not wait for it: see :meth:`wait_ready`); its stderr goes to
        ``log_dir/<name>.log`` (default: discarded)."""
        env = without_camera_emulation(os.environ)
        # The child must import the same tactile_rig as this process (a worktree run with PYTHONPATH).
        here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
        env["PYTHONPATH"] = os.pathsep.join([here, *filter(None, [env.get("PYTHONPATH")])])
        if log_dir is not None:
            Path(log_dir).mkdir(parents=True, exist_ok=True)
            self.log_path = Path(log_dir) / f"{self.name}.log"
            err: Any = open(self.log_path, "wb")
        else:
            err = subprocess.DEVNULL
        try:
            self.proc = subprocess.Popen([sys.executable, *self.argv], stdout=subprocess.PIPE, stderr=err,
                                         stdin=subprocess.DEVNULL, env=env)
        finally:
            if err is not subprocess.DEVNULL:
                err.close()  # the child holds its own descriptor
        return self

    def wait_ready(self, timeout_s: float = START_TIMEOUT_S) -> dict[str, Any]:
        """Read the JSON line; NotConnected naming the device and its stderr if none comes."""
        assert self.proc is not None and self.proc.stdout is not None
        deadline = time.monotonic() + timeout_s
        line = b""
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                break
            ready, _, _ = select.select([self.proc.stdout], [], [], min(left, 0.5))
            if ready:
                chunk = os.read(self.proc.stdout.fileno(), 4096)
                if not chunk:
                    break
                line += chunk
        try:
            self.info = json.loads(line.decode().splitlines()[0]) if line.strip() else {}
        except ValueError:
            self.info = {}
        if not self.info:
            err = self._stderr_tail()
            self.stop()
            raise NotConnected(f"the {self.name} process did not start within {timeout_s:.0f} s "
                               f"(exit {self.proc.returncode}): {err or 'no output'}", device=self.name)
        return self.info

    def _stderr_tail(self) -> str:
        if self.log_path is None or not self.log_path.is_file():
            return ""
        try:
            return self.log_path.read_bytes().decode(errors="replace").strip()[-500:]
        except OSError:
            return ""

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def stop(self, timeout_s: float = 5.0) -> None:
        """SIGTERM, then SIGKILL after ``timeout_s`` (idempotent)."""
        p = self.proc
        if p is None:
            return
        if p.poll() is None:
            p.terminate()
            try:
                p.wait(timeout_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout_s)
        if p.stdout is not None:
            p.stdout.close()


def without_camera_emulation(environ: Mapping[str, str]) -> dict[str, str]:
    """``environ`` without the emulated cameras' library and registry (a shell that exported another
    rehearsal's): a device process serves cameras, it does not open another bench's."""
    env = dict(environ)
    env.pop(ENV_DIR, None)
    kept = [p for p in env.get("LD_PRELOAD", "").replace(":", " ").split()
            if Path(p).name != v4l2_build.LIBRARY_NAME]
    if kept:
        env["LD_PRELOAD"] = " ".join(kept)
    else:
        env.pop("LD_PRELOAD", None)
    return env


def mock_serve_argv(kind: str, options: Sequence[str]) -> list[str]:
    """``tactile-rig mock serve KIND OPTIONS`` as a module run (the same interpreter and package)."""
    return ["-c", _LAUNCHER, "tactile_rig.cli", "mock", "serve", kind, *options]


def child_argv(what: str, options: Sequence[str]) -> list[str]:
    """One of the rehearsal's own device processes (:mod:`tactile_rig.rig.rehearsal.child`)."""
    return ["-c", _LAUNCHER, "tactile_rig.rig.rehearsal.child", what, *options]
