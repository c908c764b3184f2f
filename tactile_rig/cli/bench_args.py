"""The ``--bench FILE`` / ``--mock`` arguments every bench command takes, and the bench they select."""

from __future__ import annotations

import argparse
import os

from tactile_rig.rig.bench import Bench, load_bench, mock_bench_path


def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--bench FILE`` / ``--mock`` (mutually exclusive) to a subcommand's parser."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--bench", metavar="FILE",
                   help="bench.toml describing the devices (default: $TACTILE_RIG_BENCH)")
    g.add_argument("--mock", action="store_true",
                   help="use the built-in bench of mocks (one virtual clock and world)")


def bench_from_args(args: argparse.Namespace, *, check_files: bool = True) -> Bench:
    """The :class:`Bench` chosen by ``--bench``/``--mock`` (or ``$TACTILE_RIG_BENCH``)."""
    if getattr(args, "mock", False):
        return load_bench(mock_bench_path(), check_files=check_files)
    path = getattr(args, "bench", None) or os.environ.get("TACTILE_RIG_BENCH")
    if not path:
        raise ValueError("no bench given: pass --bench FILE, --mock, or set TACTILE_RIG_BENCH")
    return load_bench(path, check_files=check_files)
