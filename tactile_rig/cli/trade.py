"""``tactile-rig trade TOPIC``: measure speed against accuracy per setting, print the Pareto front."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

from tactile_rig.cli.args import SEED, output_dir
from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.rig import trade


def register(sub: argparse._SubParsersAction) -> None:
    topics = ", ".join(sorted(trade.TOPICS))
    p = sub.add_parser(
        "trade",
        help="measure speed against accuracy for every setting of a pipeline; print the Pareto front",
        description="Runs each setting on the same data in one process, so speeds and errors are "
        "comparable; prints the table sorted by speed with the Pareto front (*) and the default (D) "
        f"marked, and the conditions (machine, cores, load). Topics: {topics}.",
    )
    p.add_argument("topic", nargs="?", help=f"what to measure: {topics}")
    p.add_argument("--list", action="store_true", help="list the topics installed here and exit")
    p.add_argument("--quick", action="store_true",
                   help="fewer frames or episodes per setting (never fewer settings): minutes on 2 cores")
    p.add_argument("--seed", type=SEED, default=0, help="seed for rendered data and episodes (default 0)")
    p.add_argument("--plot", metavar="DIR", type=output_dir,
                   help="also draw DIR/trade_<topic>.png, error against speed (needs the report extra)")
    add_json_flag(p)
    p.set_defaults(func=_trade)


def _trade(args: argparse.Namespace) -> int:
    if args.list:
        rows = [{"topic": t, "summary": trade.summary(t)} for t in trade.available_topics()]
        if args.json:
            print_json({"topics": rows})
        else:
            for r in rows:
                print(f"{r['topic']:<14} {r['summary']}")
        return 0
    if not args.topic:
        raise ValueError(f"trade needs a TOPIC; expected one of {trade.available_topics()}")
    trade.topic_module(args.topic)  # an unknown or absent topic fails before anything runs
    if args.plot and importlib.util.find_spec("matplotlib") is None:
        raise ValueError("--plot needs matplotlib: pip install 'tactile-rig[report]'")
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
