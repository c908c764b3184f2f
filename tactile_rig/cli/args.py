"""argparse types that bound every number and check every path at parse time.

A value out of range is a usage error (one line, exit 2) naming the option, the value and the
allowed range: ``--ransac-iters 1e9``, ``--mm-per-px 1e300``, ``--fps nan`` never reach the code.
This is the one place a single argument is checked; a handler checks only what needs several
arguments together (``jig move`` needs one of ``--x``/``--y``/``--theta``; a jig target against
the bench's limits) and raises ``ValueError`` naming them.

Output paths (``-o``/``--out``): the *parent* folder must exist; only the leaf (the file, or the
output folder itself) is created. A typo in a path (``runs/r1`` for ``run/r1``) is then an error
rather than a silently created tree of folders.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Callable

__all__ = [
    "BAUD", "COUNT", "DURATION_S", "EFFORT", "SEED", "TIMEOUT_S", "any_int", "finite_float", "float_in", "input_path",
    "int_in", "output_dir", "output_dir_or", "output_file", "output_file_or",
]


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def int_in(low: int, high: int, unit: str = "") -> Callable[[str], int]:
    """An integer in ``[low, high]`` (``1e3`` is accepted when it is a whole number)."""
    u = f" {unit}" if unit else ""

    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            f = _number(text)
            if not math.isfinite(f) or f != int(f):
                raise argparse.ArgumentTypeError(f"{text!r} is not a whole number; expected an integer in "
                                                 f"[{low}, {high}]{u}") from None
            value = int(f)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{text}{u} is outside the allowed range [{low}, {high}]{u}")
        return value

    parse.__name__ = f"integer in [{low}, {high}]"
    return parse


def float_in(low: float, high: float, unit: str = "", *, low_open: bool = False) -> Callable[[str], float]:
    """A finite float in ``[low, high]`` (``(low, high]`` with ``low_open``); NaN and inf are refused."""
    u = f" {unit}" if unit else ""
    span = f"{'(' if low_open else '['}{low:g}, {high:g}]{u}"

    def parse(text: str) -> float:
        value = _number(text)
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not finite; expected a number in {span}")
        if value > high or value < low or (low_open and value == low):
            raise argparse.ArgumentTypeError(f"{text}{u} is outside the allowed range {span}")
        return value

    parse.__name__ = f"number in {span}"
    return parse


def output_file(*suffixes: str) -> Callable[[str], str]:
    """An output file: its folder must exist and it must not be a folder itself."""

    def parse(text: str) -> str:
        if not text:
            raise argparse.ArgumentTypeError("an empty path; expected an output file")
        p = Path(text)
        if p.is_dir():
            raise argparse.ArgumentTypeError(f"{text} is a folder; expected an output file")
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir():
            raise argparse.ArgumentTypeError(f"{text}: the folder {str(parent)!r} does not exist (create it first; "
                                             "only the file is written)")
        if suffixes and p.suffix and p.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"{text}: suffix {p.suffix!r}; expected {' or '.join(suffixes)}")
        return text

    parse.__name__ = "output file"
    return parse


def output_dir(text: str) -> str:
    """An output folder: it may be created, but its parent must exist; an existing file is refused."""
    if not text:
        raise argparse.ArgumentTypeError("an empty path; expected an output folder")
    p = Path(text)
    if p.exists() and not p.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a file; expected an output folder")
    parent = p.parent if str(p.parent) else Path(".")
    if not p.exists() and not parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: the folder {str(parent)!r} does not exist (create it first; "
                                         "only the last folder is created)")
    return text


def input_path(text: str) -> str:
    """A path argument that must at least be non-empty (the loaders check what it holds)."""
    if not text or "\x00" in text:
        raise argparse.ArgumentTypeError(f"{text!r} is not a usable path")
    return text


MAX_MAGNITUDE = 1e12  # no setting of this rig is a trillion of its unit: beyond it, a typo


def finite_float(text: str) -> float:
    """Any finite number of magnitude at most 1e12 (NaN, inf and 1e300 are refused); the command
    checks its own range."""
    value = _number(text)
    if not math.isfinite(value) or abs(value) > MAX_MAGNITUDE:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a finite number of magnitude at most {MAX_MAGNITUDE:g}")
    return value


finite_float.__name__ = "finite number"


def any_int(text: str) -> int:
    """Any whole number of magnitude at most 2**53 (``1e3`` is accepted); the command checks its range."""
    return int_in(-(2**53), 2**53)(text)


any_int.__name__ = "integer"

SEED = int_in(0, 2**32 - 1)  # NumPy seeds are non-negative
SEED.__name__ = "seed"

BAUD = int_in(300, 4_500_000, "baud")  # what the bench file accepts; a driver narrows it to its device's rates
COUNT = int_in(1, 1_000_000_000)  # readings, frames, episodes, trials: at least one
TIMEOUT_S = float_in(0.0, 86_400.0, "s", low_open=True)  # a wait: more than zero, at most a day
DURATION_S = float_in(0.0, 30 * 86_400.0, "s", low_open=True)  # a session: more than zero, at most a month
EFFORT = float_in(0.0, 1.0, low_open=True)  # a fraction of the servo's current limit


def output_dir_or(default: str) -> Callable[[str], str]:
    """:func:`output_dir`, except that the command's own ``default`` (e.g. ``calib/force_map``) may
    create its missing parents: only a path the user typed must have an existing parent."""

    def parse(text: str) -> str:
        return text if text == default else output_dir(text)

    parse.__name__ = "output folder"
    return parse


def output_file_or(default: str | None, *suffixes: str) -> Callable[[str], str]:
    """:func:`output_file` for a path the user typed; the command's own ``default`` passes."""
    check = output_file(*suffixes)

    def parse(text: str) -> str:
        return text if default is not None and text == default else check(text)

    parse.__name__ = "output file"
    return parse
