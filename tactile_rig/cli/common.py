"""Helpers shared by the command modules: JSON output, command groups, and the exit codes (one line
on stderr per error; a traceback only with ``--log-level DEBUG``).

The exit codes are :data:`EXIT_CODES`; README.md and docs/files_and_recordings.md quote that table and
``tests/cli/test_exit_codes.py`` holds them to it.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import textwrap
import traceback
from typing import Any, Callable, NoReturn

from tactile_rig.core.errors import DeviceFault, RigError
from tactile_rig.core.jsonable import to_jsonable


def print_json(obj: Any, *, stream=None) -> None:
    """Print one JSON object on one line and flush (one line per record: easy to stream and parse)."""
    stream = stream or sys.stdout
    stream.write(json.dumps(to_jsonable(obj), separators=(",", ":")) + "\n")
    stream.flush()


def add_json_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON")


# -- exit codes -------------------------------------------------------------------------------
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_ERROR = 2
EXIT_FAULT = 3
EXIT_INTERNAL = 70  # sysexits' EX_SOFTWARE: a bug of ours, not the user's input
EXIT_INTERRUPTED = 130  # the shell's code for SIGINT (128 + 2)

EXIT_CODES: dict[int, tuple[str, str]] = {
    EXIT_OK: ("done", "the command did what it was asked"),
    EXIT_FAILED: ("a failed verdict", "the command ran and its answer is no: a touch the registration refused, "
                  "a device check that failed, an accuracy beyond --max-*, an episode that missed its property"),
    EXIT_ERROR: ("bad input or usage", "one line on stderr naming the file or argument, the problem and what "
                 "was expected: a malformed file, an argument out of range, a target outside the limits, a "
                 "command the device refused, a device that does not answer on that port"),
    EXIT_FAULT: ("a device fault", "the device latched an error of its own (an overload, a GRBL alarm, an unasked "
                 "reset) and motion stopped"),
    EXIT_INTERNAL: ("a bug in tactile-rig", "one line; rerun with --log-level DEBUG for the traceback"),
    EXIT_INTERRUPTED: ("interrupted", "Ctrl-C"),
}
"""Every exit code of the ``tactile-rig`` command: (what it means in a few words, the detail)."""


def exit_codes_text() -> str:
    """:data:`EXIT_CODES` as the lines ``--help`` ends with."""
    rows = (textwrap.fill(f"{label}: {detail}", 94, initial_indent=f"  {code:<4} ", subsequent_indent=" " * 7)
            for code, (label, detail) in EXIT_CODES.items())
    return "exit codes:\n" + "\n".join(rows)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr (exit 2), naming the command and
    pointing at its ``--help``, instead of the usage block followed by the error."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


def add_command_group(sub: Any, name: str, *, metavar: str = "ACTION", **parser_kw: Any) -> tuple[Any, Any]:
    """Add the command group ``name`` (``tactile-rig NAME ACTION ...``) to ``sub``; return its parser
    and the subparsers its actions join. ``tactile-rig NAME`` without an action is a usage error
    (exit 2, one line) naming the actions."""
    parser = sub.add_parser(name, **parser_kw)
    actions = parser.add_subparsers(dest=f"{name.replace('-', '_')}_command", metavar=metavar)
    parser.set_defaults(func=functools.partial(missing_action, parser, actions, metavar))
    return parser, actions


def missing_action(parser: argparse.ArgumentParser, actions: Any, metavar: str,
                   args: argparse.Namespace | None = None) -> NoReturn:
    """The usage error of a command group called without one of its ``actions``."""
    parser.error(f"expected {metavar}: one of {', '.join(actions.choices)}")


def extras_as_errors(handler: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Decorate a handler so that a missing optional extra (mcap, scikit-learn, matplotlib) is one
    line naming the pip extra (exit 2) rather than an internal error."""

    @functools.wraps(handler)
    def run(args: argparse.Namespace) -> int:
        try:
            return handler(args)
        except ModuleNotFoundError as exc:
            raise ValueError(str(exc) if "pip install" in str(exc) else
                             f"{exc}: pip install 'tactile-rig[all]' for the optional extras") from None

    return run


def one_line(text: object) -> str:
    """``text`` on one line: a multi-line message (a bench file with several problems) joined by '; '."""
    parts = [ln.strip() for ln in str(text).splitlines() if ln.strip()]
    return "; ".join(parts) if parts else ""


def run_handler(func: Callable[[argparse.Namespace], Any], args: argparse.Namespace, *,
                stderr: Any = None) -> int:
    """Run a command handler and map what it raises to an exit code and one line on stderr.

    0/1 are the handler's own (done / failed verdict); a bad input (``RigError``, ``ValueError``, an
    ``OSError`` such as a missing or unreadable file) is 2; a device fault 3; an exception of any
    other type is a bug of ours: 70 with a hint to rerun with ``--log-level DEBUG``, which prints
    the traceback (for every error, not only bugs)."""
    err = stderr if stderr is not None else sys.stderr
    debug = getattr(args, "log_level", "WARNING") == "DEBUG"

    def say(prefix: str, exc: BaseException, code: int) -> int:
        if debug:
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=err)
        text = one_line(exc) or type(exc).__name__
        print(f"tactile-rig: {prefix}{text}", file=err)
        return code

    try:
        return int(func(args) or 0)
    except DeviceFault as exc:
        return say("device fault: ", exc, EXIT_FAULT)
    except (RigError, ValueError, OSError) as exc:
        if isinstance(exc, OSError) and not isinstance(exc, RigError) and exc.filename is not None \
                and str(exc.filename) not in str(exc):
            exc = OSError(f"{exc.filename}: {exc.strerror or exc}")
        return say("error: ", exc, EXIT_ERROR)
    except KeyboardInterrupt:
        print("tactile-rig: interrupted", file=err)
        return EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - the last line of defence: one line, not a traceback
        if debug:
            traceback.print_exception(type(exc), exc, exc.__traceback__, file=err)
        detail = one_line(exc)
        print(f"tactile-rig: internal error: {type(exc).__name__}{': ' + detail[:200] if detail else ''} "
              "(a bug in tactile-rig; rerun with --log-level DEBUG for the traceback and report it)", file=err)
        return EXIT_INTERNAL
