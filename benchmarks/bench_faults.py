"""Benchmark: the fault soak, every serial device × every fault, in process and over a pty relay.

For each device (Dynamixel P2, Dynamixel P1, the scale, the jig) and fault (drop, flip, duplicate,
garbage, split, late, stall, unplug, replug, reboot), N operations through the real driver with the
fault injected (``rigfault://`` in virtual time; :class:`tactile_rig.mocks.relay.PtyRelay` in real
time), each checked against the mock's true state. The table: operations, typed errors,
recoveries, untyped exceptions, hangs and silently wrong values (see ``docs/faults.md``).

    python benchmarks/bench_faults.py [--quick] [--save] [--devices scale,jig] [--faults drop,late]
                                      [--transports in_process,relay] [-n 500] [--n-relay 100] [--seed 0]

``--quick``: 100 operations in process and 40 over the relay. ``--save`` writes
``benchmarks/results/faults.json``. The exit code is 1 when any row has an untyped exception, a
hang or a wrong value.
"""

from __future__ import annotations

import argparse
import logging
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

from tactile_rig.testing.faultsoak import (  # noqa: E402
    DEVICES,
    FAULT_QUERIES,
    KINDS,
    TRANSPORTS,
    format_table,
    moving_reports,
    soak,
    totals,
)


def _names(text: str | None, allowed: tuple[str, ...], what: str) -> tuple[str, ...]:
    if not text:
        return allowed
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [n for n in names if n not in allowed]
    if bad:
        raise SystemExit(f"--{what}: unknown {', '.join(bad)}; expected some of {', '.join(allowed)}")
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 operations in process, 40 over the relay")
    ap.add_argument("--devices", help=f"comma-separated subset of {','.join(DEVICES)}")
    ap.add_argument("--faults", help=f"comma-separated subset of {','.join(KINDS)}")
    ap.add_argument("--transports", help=f"comma-separated subset of {','.join(TRANSPORTS)}")
    ap.add_argument("-n", type=int, default=None, help="operations per row in process (default 500)")
    ap.add_argument("--n-relay", type=int, default=None, help="operations per row over the relay (default 150)")
    ap.add_argument("--seed", type=int, default=0)
    add_save_args(ap, "faults.json")
    args = parse_args(ap, argv)
    if args.save and (args.devices or args.faults or args.transports):
        ap.error("--save with a subset (--devices/--faults/--transports) would replace the full table in "
                 "benchmarks/results/faults.json; use --out PATH")
    n = args.n or (100 if args.quick else 500)
    n_relay = args.n_relay or (40 if args.quick else 150)
    devices = _names(args.devices, DEVICES, "devices")
    faults = _names(args.faults, KINDS, "faults")
    transports = _names(args.transports, TRANSPORTS, "transports")
    logging.disable(logging.WARNING)  # the drivers log every fault they see; the table says it all

    print(format_table([]).splitlines()[0], flush=True)
    t0 = time.monotonic()
    rows = soak(devices, faults, transports, n=n, n_relay=n_relay, seed=args.seed,
                on_row=lambda r: print(format_table([r]).splitlines()[-1], flush=True))
    took = time.monotonic() - t0
    tot = totals(rows)
    print(f"\ntotal: {tot}  ({took:.0f} s wall, under whatever load the machine had)")
    for r in rows:
        for e in r.examples:
            print(f"  {r.device}/{r.fault}/{r.transport}: {e}")
    moving = []
    if "jig" in devices and "in_process" in transports:
        # The residual the jig's checks cannot remove: reports read while it moves (no checksum).
        print("\njig reports read while moving (in process): fault, reports, typed, wrong (GRBL never printed it)")
        for fault in (f for f in ("drop", "flip", "duplicate", "garbage") if f in faults):
            m = moving_reports(fault, moves=30 if args.quick else 100, seed=args.seed)
            moving.append(m)
            print(f"  {fault:<10} {m.reports:>5} {m.typed:>5} {m.wrong:>4}  ({100 * m.wrong_rate:.2f} %)  {m.examples[:2]}")
    save_json(args, {
            "benchmark": "faults",
            "command": "python benchmarks/bench_faults.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "operations_in_process": n, "operations_relay": n_relay, "seed": args.seed,
            "fault_queries": FAULT_QUERIES, "wall_s": round(took, 1), "python": platform.python_version(),
            "totals": tot, "rows": [r.to_dict() for r in rows],
            "jig_moving_reports": [m.to_dict() for m in moving],
        })
    return 1 if tot["untyped"] or tot["hangs"] or tot["wrong"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
