"""``tactile-rig trade TOPIC``: measure speed against accuracy per setting, print the Pareto front."""

from __future__ import annotations

import argparse
from pathlib import Path

from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.rig import trade


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "trade",
        help="measure speed against accuracy for every setting of a pipeline; print the Pareto front",
        description="Runs each setting on the same data in one process, so speeds and errors are "
        "comparable; marks the default and whether it is on the front. Topics: "
        + (", ".join(sorted(trade.TOPICS)) or "none installed") + ".",
    )
    p.add_argument("topic", help="what to measure: " + (", ".join(sorted(trade.TOPICS)) or "-"))
    p.add_argument("--quick", action="store_true",
                   help="fewer frames or episodes per setting (never fewer settings): minutes on 2 cores")
    p.add_argument("--seed", type=int, default=0, help="seed for rendered data and episodes (default 0)")
    p.add_argument("--plot", metavar="DIR", help="also draw DIR/trade_<topic>.png (needs the report extra)")
    add_json_flag(p)
    p.set_defaults(func=_trade)


def _trade(args: argparse.Namespace) -> int:
    if args.topic not in trade.TOPICS:
        raise ValueError(f"trade topic {args.topic!r} is unknown; expected one of {sorted(trade.TOPICS)}")
    table = trade.measure(args.topic, quick=args.quick, seed=args.seed)
    plot_path = table.plot(Path(args.plot) / f"trade_{table.topic}.png") if args.plot else None
    if args.json:
        out = table.to_dict()
        out["plot"] = str(plot_path) if plot_path else None
        print_json(out)
    else:
        print(table.format_text())
        if plot_path:
            print(f"plot: {plot_path}")
    return 0
