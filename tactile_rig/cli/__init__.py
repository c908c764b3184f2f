"""The ``tactile-rig`` command line: one console script with subcommands.

Each command group lives in its own module under :mod:`tactile_rig.cli` and exposes
``register(subparsers)``. A handler returns the process exit code: 0 done, 1 a failed verdict.
Errors from the rig (:class:`~tactile_rig.core.errors.RigError`) and bad arguments (``ValueError``)
become one line on stderr and exit 2; a device fault exits 3; an unexpected exception (a bug) exits
70 with one line (:func:`tactile_rig.cli.common.run_handler`; the table: :data:`~tactile_rig.cli.common.EXIT_CODES`).

The console script is :func:`console_main`; :func:`main` is the same command line as a function. A
bench whose cameras are emulated V4L2 devices (the rehearsal bench) needs a preload library in the
process: the console script re-executes itself with it, ``main`` runs the command in a child process
started with it (:mod:`tactile_rig.cli.emulation`).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import Sequence

from tactile_rig import __version__
from tactile_rig.cli.common import (
    EXIT_CODES,
    EXIT_ERROR,
    EXIT_FAILED,
    EXIT_FAULT,
    EXIT_INTERNAL,
    EXIT_OK,
    OneLineParser,
    exit_codes_text,
    missing_action,
    run_handler,
)
from tactile_rig.cli import emulation

# Command groups, in the order they appear in --help.
COMMAND_MODULES: tuple[str, ...] = (
    "mock",
    "bench",
    "devices",
    "gripper",
    "scale",
    "jig",
    "gelsight",
    "fingervision",
    "scene",
    "run",
    "record",
    "camera",
    "calibrate",
    "substance",
    "replay",
    "export",
    "sweep",
    "trade",
)

__all__ = ["EXIT_CODES", "EXIT_OK", "EXIT_FAILED", "EXIT_ERROR", "EXIT_FAULT", "EXIT_INTERNAL", "build_parser", "main",
           "console_main"]


def _command_of(argv: Sequence[str]) -> str | None:
    """The command group ``argv`` names (its first word that is not an option or the log level's
    value), or None when it names none of :data:`COMMAND_MODULES`."""
    words = iter(argv)
    for w in words:
        if w == "--log-level":
            next(words, None)
        elif w == "--":
            return None
        elif not w.startswith("-"):
            return w if w in COMMAND_MODULES else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or with ``only`` (a name of :data:`COMMAND_MODULES`) just that group:
    building all ~50 subcommands costs 20-40 ms a call, which a script calling ``main`` per file
    (or per batch) pays for nothing; ``--help`` and a mistyped command still see every group."""
    parser = OneLineParser(
        prog="tactile-rig",
        description="Drivers, faithful mocks, perception and controllers for tactile grippers.",
        epilog=exit_codes_text(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"tactile-rig {__version__}")
    parser.add_argument(
        "--log-level",
        default="WARNING",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging level on stderr (DEBUG logs every byte exchanged); default WARNING",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in (only,) if only is not None else COMMAND_MODULES:
        importlib.import_module(f"tactile_rig.cli.{name}").register(sub)
    parser.set_defaults(func=lambda args: missing_action(parser, sub, "COMMAND"))
    return parser


def _bench_of(args: argparse.Namespace) -> str | None:
    """The bench file a parsed command uses (as :func:`~tactile_rig.cli.bench_args.bench_from_args`
    chooses it), or None for a command without ``--bench``."""
    if not hasattr(args, "bench") or getattr(args, "mock", False) or not getattr(args, "opens_devices", True):
        return None
    return args.bench or os.environ.get(emulation.BENCH_ENV) or None


def _run(words: list[str], *, console: bool) -> int:
    if console:
        try:
            emu = emulation.needed(emulation.bench_in_argv(words))
            if emu is not None:
                emulation.reexec(words, emu)  # does not return
        except emulation.EmulationError as exc:
            print(f"tactile-rig: error: {exc}", file=sys.stderr)
            return EXIT_ERROR
    parser = build_parser(_command_of(words))
    args = parser.parse_args(words)
    logging.basicConfig(
        level=getattr(logging, args.log_level), format="%(asctime)s %(name)s %(levelname)s %(message)s"
    )
    try:
        # After parsing, the bench the command really uses (an abbreviation or an environment the
        # word scan above did not see; every call of main as a function).
        emu = emulation.needed(_bench_of(args))
        if emu is not None:
            if console:
                emulation.reexec(words, emu)
            return emulation.run_in_child(words, emu)
    except emulation.EmulationError as exc:
        print(f"tactile-rig: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    return run_handler(args.func, args)


def main(argv: Sequence[str] | None = None) -> int:
    """The ``tactile-rig`` command line as a function (``argv`` default: ``sys.argv[1:]``); returns the
    exit code. It never replaces the calling process: a command on a bench with emulated cameras
    runs in a child process started with their library (its output relayed to ours)."""
    return _run(sys.argv[1:] if argv is None else list(argv), console=False)


def console_main() -> int:
    """Entry point of the ``tactile-rig`` console script (and ``python -m tactile_rig.cli``): as
    :func:`main`, except that on a bench with emulated cameras the process re-executes itself once
    with their library, before anything is opened."""
    return _run(sys.argv[1:], console=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(console_main())
