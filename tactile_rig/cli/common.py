"""Helpers shared by the command modules: JSON output, common arguments, and the exit codes (one
line on stderr per error; a traceback only with ``--log-level DEBUG``)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
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
EXIT_INTERRUPTED = 130

_log = logging.getLogger("tactile_rig.cli")


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line on stderr (exit 2), naming the command and
    pointing at its ``--help``, instead of the usage block followed by the error."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_ERROR, f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)\n")


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
