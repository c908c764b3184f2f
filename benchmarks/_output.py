"""Where a benchmark's JSON goes: nowhere unless asked.

``benchmarks/results/`` holds the committed figures the docs quote. A benchmark writes there only
with ``--save``, and never from a ``--quick`` run (reduced runs must not replace full ones);
``--out PATH`` writes anywhere else (a quick run's JSON included). Without either, the benchmark
prints its tables and writes nothing, so trying a benchmark never dirties the working tree.

Usage in a benchmark::

    from _output import add_save_args, parse_args, save_json
    ap = argparse.ArgumentParser(...)
    ap.add_argument("--quick", ...)
    add_save_args(ap, "render.json")
    args = parse_args(ap)            # --save with --quick: exit 2 before anything runs
    ...
    save_json(args, results)         # prints where it wrote, or that it wrote nothing
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def add_save_args(ap: argparse.ArgumentParser, filename: str) -> None:
    """Add ``--save`` (write ``benchmarks/results/<filename>``) and ``--out PATH``."""
    ap.add_argument("--save", action="store_true",
                    help=f"write the committed results, benchmarks/results/{filename} (full runs only)")
    ap.add_argument("--out", metavar="PATH", help="write the JSON to PATH instead (any run, --quick included)")
    ap.set_defaults(result_file=filename)


def parse_args(ap: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Parse, refusing ``--save`` with ``--quick`` (exit 2, before anything is measured)."""
    args = ap.parse_args(argv)
    if getattr(args, "save", False) and getattr(args, "quick", False):
        ap.error(f"--save with --quick would replace the full-run figures in benchmarks/results/"
                 f"{args.result_file} with reduced ones; save a full run, or use --out PATH")
    if getattr(args, "save", False) and getattr(args, "out", None):
        ap.error("--save and --out both name where to write; give one")
    return args


def result_path(args: argparse.Namespace, filename: str | None = None) -> Path | None:
    """Where :func:`save_json` would write (``None``: nowhere)."""
    if getattr(args, "out", None):
        return Path(args.out)
    if getattr(args, "save", False):
        return RESULTS_DIR / (filename or args.result_file)
    return None


def save_json(args: argparse.Namespace, obj: Any, filename: str | None = None, *, indent: int = 1,
              default: Any = None) -> Path | None:
    """Write ``obj`` as JSON where the flags say; say so on stderr either way."""
    path = result_path(args, filename)
    if path is None:
        print(f"not saved (--save writes benchmarks/results/{filename or args.result_file}, "
              "--out PATH anywhere)", file=sys.stderr)
        return None
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=indent, default=default) + "\n", encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)
    return path


def saved_results(filename: str) -> dict[str, Any] | None:
    """The committed results ``benchmarks/results/<filename>`` (for partial reruns that merge)."""
    path = RESULTS_DIR / filename
    if not path.is_file():
        return None
    return json.loads(path.read_text(encoding="utf-8"))
