"""The malformed-file soak: every CLI command that reads files, run on 100+ malformed files each.

    python benchmarks/bench_bad_files.py [--quick] [--kinds npy,mcap] [--save]

The files come from ``tests/_bad_files.py`` (deterministic from ``--seed``). Each case runs
``tactile_rig.cli.main(argv)`` in this process (no subprocess: fast), with stdout and stderr captured,
the process's file descriptor 2 included (a C library's warning counts as a line too). The table, per
kind: cases, exit codes, tracebacks, stderr lines > 1, and the goal: every case exit 2 with one line.
The baseline in the same run is the same command on a valid file of each kind (exit 0), with its time
next to the mean time to refuse a malformed one.
``--save`` writes ``benchmarks/results/bad_files.json`` (full runs only; ``--out PATH`` anywhere).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import platform
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _output import add_save_args, parse_args, save_json  # noqa: E402

from tactile_rig.cli import main  # noqa: E402
from tests._bad_files import KINDS, BadCase, generate, good_case  # noqa: E402


@contextlib.contextmanager
def _capture_fd2(sink: Path):
    """Send file descriptor 2 to ``sink`` for the block (what C code writes to stderr)."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(sink, "wb") as f:
        os.dup2(f.fileno(), 2)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


def run_case(case: BadCase, scratch: Path) -> dict:
    """Run one case in process; exit code, stderr lines, whether a traceback was printed."""
    out, err = io.StringIO(), io.StringIO()
    fd2 = scratch / "fd2.txt"
    t0 = time.perf_counter()
    with _capture_fd2(fd2), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(case.argv))
        except SystemExit as exc:  # argparse
            code = exc.code if isinstance(exc.code, int) else 2
        except BaseException as exc:  # noqa: BLE001 - escaped main(): the worst outcome, counted
            code = f"raised {type(exc).__name__}"
            err.write(f"Traceback (escaped main): {type(exc).__name__}: {exc}\n")
    text = err.getvalue() + fd2.read_text(errors="replace")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return {"kind": case.kind, "name": case.name, "argv": list(case.argv), "exit": code,
            "stderr_lines": len(lines), "traceback": "Traceback" in text, "first_line": lines[0][:300] if lines else "",
            "wall_s": round(time.perf_counter() - t0, 4)}


def summarize(rows: list[dict]) -> dict:
    by_kind: dict[str, dict] = {}
    for r in rows:
        k = by_kind.setdefault(r["kind"], {"cases": 0, "exit_codes": Counter(), "tracebacks": 0, "multi_line": 0,
                                            "not_exit_2": 0, "goal_met": 0})
        k["cases"] += 1
        k["exit_codes"][str(r["exit"])] += 1
        k["tracebacks"] += r["traceback"]
        k["multi_line"] += r["stderr_lines"] != 1
        k["not_exit_2"] += r["exit"] != 2
        k["goal_met"] += r["exit"] == 2 and r["stderr_lines"] == 1 and not r["traceback"]
    for k in by_kind.values():
        k["exit_codes"] = dict(sorted(k["exit_codes"].items()))
    return by_kind


def main_bench() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="every 5th case only")
    ap.add_argument("--kinds", help="comma-separated kinds (default: all): " + ", ".join(KINDS))
    ap.add_argument("--seed", type=int, default=0)
    add_save_args(ap, "bad_files.json")
    args = parse_args(ap)
    kinds = args.kinds.split(",") if args.kinds else list(KINDS)
    rows: list[dict] = []
    baseline: list[dict] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bad_files-") as tmp:
        scratch = Path(tmp)
        for kind in kinds:
            cases = generate(kind, scratch, seed=args.seed)
            if args.quick:
                cases = cases[::5]
            for c in cases:
                rows.append(run_case(c, scratch))
            good = good_case(kind, scratch, seed=args.seed)
            if good is not None:
                baseline.append(run_case(good, scratch))
    wall = time.perf_counter() - t0
    table = summarize(rows)
    print(f"{'kind':<20} {'cases':>5} {'goal':>5} {'!=2':>4} {'tb':>3} {'lines!=1':>8}  exit codes")
    for kind, k in table.items():
        print(f"{kind:<20} {k['cases']:>5} {k['goal_met']:>5} {k['not_exit_2']:>4} {k['tracebacks']:>3} "
              f"{k['multi_line']:>8}  {k['exit_codes']}")
    total = len(rows)
    goal = sum(k["goal_met"] for k in table.values())
    print(f"total: {goal}/{total} cases exit 2 with one line; {sum(k['tracebacks'] for k in table.values())} "
          f"tracebacks; {wall:.1f} s")
    print("baseline (valid files, same commands): " + ", ".join(
        f"{b['kind']} exit {b['exit']} in {b['wall_s'] * 1000:.0f} ms" for b in baseline))
    mean_ms = 1000 * sum(r["wall_s"] for r in rows) / max(1, len(rows))
    print(f"mean time to refuse a malformed input: {mean_ms:.0f} ms")
    for r in rows:
        if not (r["exit"] == 2 and r["stderr_lines"] == 1 and not r["traceback"]):
            print(f"  MISS {r['kind']}/{r['name']}: exit {r['exit']}, {r['stderr_lines']} lines: {r['first_line'][:160]}")
    save_json(args, {"benchmark": "bad_files", "seed": args.seed, "quick": args.quick,
                  "python": platform.python_version(), "machine": platform.machine(),
                  "wall_s": round(wall, 2), "total": total, "goal_met": goal, "by_kind": table,
                  "mean_refusal_ms": round(mean_ms, 1),
                  "baseline_valid": [{k: b[k] for k in ("kind", "exit", "wall_s", "first_line")} for b in baseline],
                  "misses": [r for r in rows if not (r["exit"] == 2 and r["stderr_lines"] == 1 and not r["traceback"])]})
    return 0


if __name__ == "__main__":
    sys.exit(main_bench())
