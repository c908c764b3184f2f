"""How a ``tactile-rig`` process reaches a bench's emulated V4L2 cameras.

A bench whose cameras are emulated (the rehearsal bench) says so in its ``[bench]`` table::

    v4l2_registry = "v4l2"                                   # TACTILE_RIG_V4L2_DIR, relative to the file
    v4l2_preload = "/.../v4l2/<key>/libtactile_rig_v4l2.so"  # LD_PRELOAD

The library answers ``open``/``ioctl``/``mmap``/... for the registry's ``/dev/videoN`` nodes (see
:mod:`tactile_rig.mocks.v4l2`); it must be in a process's environment when the process starts. So:

* the console script (``tactile-rig``, ``python -m tactile_rig.cli``) re-executes itself once, before
  anything is opened, with that environment when the bench it is given (``--bench FILE`` or
  ``$TACTILE_RIG_BENCH``) names it and the process was not started with it: same process id, same
  terminal, same arguments (:func:`reexec`);
* :func:`tactile_rig.cli.main` called as a function (a test, another program) never replaces its
  caller: it runs the command in a child process started with the environment, relays its output
  and returns its exit code (:func:`run_in_child`).

A bench without these keys (every bench of real cameras) is untouched: no preload, no re-execution.
:data:`GUARD` marks a process started this way, so a library that did not load is an error, not a loop.

Only the standard library is imported here: this runs before the command's own (heavy) imports.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Mapping, NoReturn, Sequence

#: The variable the preload library reads its registry from (``tactile_rig.mocks.v4l2.server.ENV_DIR``).
ENV_DIR = "TACTILE_RIG_V4L2_DIR"
#: Set in a process the CLI started with a bench's emulation (re-executed, or a child of ``main``).
GUARD = "TACTILE_RIG_V4L2_STARTED"
BENCH_ENV = "TACTILE_RIG_BENCH"
REGISTRY_KEY = "v4l2_registry"
PRELOAD_KEY = "v4l2_preload"
MAX_BENCH_BYTES = 1 << 20  # the loader's limit: a larger file is the loader's error to report
#: Commands that open no bench's devices: neither ``--bench`` nor ``$TACTILE_RIG_BENCH`` makes them re-execute.
NO_DEVICES = (("mock",), ("bench", "rehearse"), ("bench", "env"))


class EmulationError(RuntimeError):
    """The bench's emulation cannot be loaded (a missing library, a library that did not load)."""


@dataclass(frozen=True)
class Emulation:
    """A bench's emulated cameras: its registry directory and the preload library that serves it."""

    bench: Path
    registry: Path
    library: Path

    def env(self, environ: Mapping[str, str] | None = None) -> dict[str, str]:
        """``LD_PRELOAD`` (the library first, then what ``environ`` preloads) and the registry."""
        current = (os.environ if environ is None else environ).get("LD_PRELOAD", "")
        lib = str(self.library)
        parts = [lib] + [p for p in current.replace(":", " ").split() if p and p != lib]
        return {"LD_PRELOAD": " ".join(parts), ENV_DIR: str(self.registry)}

    def active(self) -> bool:
        """This process was started with this emulation: the library is mapped and names the registry."""
        try:
            maps = Path("/proc/self/maps").read_text(encoding="utf-8", errors="replace")
        except OSError:
            return False
        lib = os.path.realpath(self.library)
        if not any(line.endswith(" " + lib) or line.endswith("\t" + lib) for line in maps.splitlines()):
            return False
        here = os.environ.get(ENV_DIR)
        return here is not None and os.path.realpath(here) == os.path.realpath(self.registry)

    def check(self) -> None:
        """EmulationError naming the bench when the library it names is not there."""
        if not self.library.is_file():
            raise EmulationError(f"{self.bench}: [bench] {PRELOAD_KEY} = '{self.library}' does not exist; the "
                                 "emulated cameras' library is built when the rehearsal starts: restart it "
                                 "(tactile-rig bench rehearse)")


def _value(environ: Mapping[str, str], head: Mapping[str, object], key: str) -> object:
    var = f"TACTILE_RIG_BENCH__{key.upper()}"  # the loader's override of a [bench] key
    if var in environ:
        raw = environ[var]
        try:
            return tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            return raw
    return head.get(key)


def bench_emulation(path: str | Path, environ: Mapping[str, str] | None = None) -> Emulation | None:
    """The emulation ``path``'s ``[bench]`` names, or None: a bench without one, or a file that cannot
    be read as a bench (the bench loader reports that, with its line)."""
    env = os.environ if environ is None else environ
    p = Path(path)
    try:
        if p.stat().st_size > MAX_BENCH_BYTES:
            return None
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return None
    head = data.get("bench")
    head = head if isinstance(head, dict) else {}
    registry, library = _value(env, head, REGISTRY_KEY), _value(env, head, PRELOAD_KEY)
    if not (isinstance(registry, str) and registry and isinstance(library, str) and library):
        return None
    base = p.resolve().parent
    return Emulation(p, base / Path(registry).expanduser(), base / Path(library).expanduser())


def bench_in_argv(argv: Sequence[str], environ: Mapping[str, str] | None = None) -> str | None:
    """The bench file a command line opens devices of, read from the words alone (before parsing):
    none for a command of :data:`NO_DEVICES`; ``--bench FILE`` (or an abbreviation argparse accepts,
    ``--ben FILE``, ``--bench=FILE``); else, unless the line says ``--mock``, ``$TACTILE_RIG_BENCH``."""
    env = os.environ if environ is None else environ
    words = list(argv)
    commands = tuple(w for k, w in enumerate(words)
                     if not w.startswith("-") and (k == 0 or words[k - 1] != "--log-level"))
    if any(commands[:len(c)] == c for c in NO_DEVICES):
        return None
    for i, w in enumerate(words):
        if w == "--":
            break
        name, eq, value = w.partition("=")
        if len(name) >= 4 and "--bench".startswith(name):
            if eq:
                return value or None
            return words[i + 1] if i + 1 < len(words) else None
    if "--mock" in words:
        return None
    return env.get(BENCH_ENV) or None


def needed(bench: str | Path | None) -> Emulation | None:
    """The emulation ``bench`` names when this process lacks it (None: nothing to do)."""
    if not bench:
        return None
    emu = bench_emulation(bench)
    if emu is None or emu.active():
        return None
    return emu


def _started_env(emu: Emulation) -> dict[str, str]:
    emu.check()
    if os.environ.get(GUARD):
        raise EmulationError(f"{emu.bench}: this process was started with the emulated cameras' library "
                             f"({emu.library}) but it is not loaded (is LD_PRELOAD ignored here?)")
    env = dict(os.environ)
    env.update(emu.env())
    env[GUARD] = "1"
    # The child imports this very package (a run from a source tree with PYTHONPATH, or none).
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join([root, *filter(None, [env.get("PYTHONPATH")])])
    return env


def _command(argv: Sequence[str]) -> list[str]:
    return [sys.executable, "-m", "tactile_rig.cli", *argv]


def reexec(argv: Sequence[str], emu: Emulation) -> NoReturn:
    """Replace this process by the same command started with ``emu``'s environment."""
    env = _started_env(emu)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, _command(argv), env)


def _relay(src: IO[bytes], dst: IO[str]) -> None:
    # Line by line as it comes, so a caller reading the output while the command runs sees it live.
    for line in iter(src.readline, b""):
        dst.write(line.decode("utf-8", "replace"))
        dst.flush()
    src.close()


def _stdin() -> int | IO[str]:
    try:
        sys.stdin.fileno()
    except (AttributeError, OSError, ValueError):
        return subprocess.DEVNULL  # a captured or closed stdin (pytest): the command gets none
    return sys.stdin


def run_in_child(argv: Sequence[str], emu: Emulation) -> int:
    """Run the command in a child process started with ``emu``'s environment; its standard output
    and error go to ours (``sys.stdout``/``sys.stderr``, line by line); its exit code is returned.
    An interrupt here interrupts the child and waits for it."""
    env = _started_env(emu)
    proc = subprocess.Popen(_command(argv), env=env, stdin=_stdin(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    relays = [threading.Thread(target=_relay, args=(proc.stdout, sys.stdout), daemon=True),
              threading.Thread(target=_relay, args=(proc.stderr, sys.stderr), daemon=True)]
    for t in relays:
        t.start()
    try:
        code = proc.wait()
    except KeyboardInterrupt:
        proc.send_signal(2)  # SIGINT: the command ends as it does on Ctrl-C
        code = proc.wait()
    for t in relays:
        t.join()
    return code
