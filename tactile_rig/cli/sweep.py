"""``tactile-rig sweep TARGET --param NAME=VALUES ... [--episodes N] [--plot PNG]``: a resumable
parameter sweep of simulated runs, answered as one table (success rate, median and worst per point)."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

from tactile_rig.cli.args import COUNT, int_in, output_dir, output_file
from tactile_rig.cli.common import EXIT_FAILED, add_json_flag, print_json
from tactile_rig.rig.progress import Progress
from tactile_rig.rig.sweep import _scalar, grid, make_executor, parse_axis, run_sweep
from tactile_rig.rig.sweep_report import format_table, plot_table, sweep_table, table_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help="run a parameter sweep (processes locally, Dask with --executor dask); resumable",
        description="Each point is keyed by its parameters, seeded from its key, skipped when "
        "OUT/<key>/result.json exists. TARGET is 'module:function' or 'scene:<name>'.",
    )
    p.add_argument("target", help="what to run per point: module:function or scene:<name>")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUES",
                   help="a swept axis: name=1,2,3 or name=start:stop:step (stop inclusive); repeat")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter fixed for every point; repeat")
    p.add_argument("--episodes", type=COUNT, default=1, metavar="N",
                   help="episodes per point, each with its own seed (default 1); the table gives the "
                   "success rate and the median and worst of each figure per point")
    p.add_argument("--figure", action="append", default=[], metavar="NAME",
                   help="show only these result figures in the table and plot (repeat; default all)")
    p.add_argument("--higher-is-better", action="append", default=[], metavar="NAME",
                   help="a figure whose worst value is its smallest (e.g. cap_mps); others' worst is the largest")
    p.add_argument("--plot", metavar="PNG", type=output_file(".png"), help="also draw the table against the first swept parameter "
                   "(needs the report extra)")
    p.add_argument("--out", default="sweep-out", type=output_dir, help="output folder (default ./sweep-out)")
    p.add_argument("--executor", choices=["process", "thread", "dask"], default="process")
    p.add_argument("--workers", type=int_in(1, 4096), help="number of workers (default: the CPU count)")
    p.add_argument("--address", help="Dask scheduler address (tcp://host:8786) for --executor dask")
    p.add_argument("--progress", choices=["auto", "bar", "json", "off"], default="auto",
                   help="progress on stderr: a bar on a terminal, JSON lines otherwise (auto)")
    add_json_flag(p)
    p.set_defaults(func=_sweep)


def _sweep(args: argparse.Namespace) -> int:
    if args.plot and importlib.util.find_spec("matplotlib") is None:
        raise ValueError("--plot needs matplotlib: pip install 'tactile-rig[report]'")
    axes = dict(parse_axis(s) for s in args.param)
    fixed = {}
    for kv in args.set:
        k, sep, v = kv.partition("=")
        if not sep or not k:
            raise ValueError(f"--set {kv!r} must look like NAME=VALUE")
        fixed[k.strip()] = _scalar(v.strip())
    points = grid(axes, fixed) if axes else [fixed]
    ex = make_executor(args.executor, workers=args.workers, address=args.address)
    with Progress(len(points) * args.episodes, label=f"sweep {args.target}", mode=args.progress) as prog:
        try:
            summary = run_sweep(args.target, points, args.out, episodes=args.episodes, executor=ex,
                                progress=prog)
        finally:
            ex.shutdown(wait=True)
    counts = summary.counts
    rows = sweep_table(summary, figures=args.figure or None, higher_is_better=args.higher_is_better)
    plot = plot_table(rows, Path(args.plot), figures=args.figure or None) if args.plot else None
    if args.json:
        print_json({"out": summary.out_dir, "counts": counts, "episodes": args.episodes, "table": table_json(rows),
                    "plot": plot,
                    "points": [{"key": p.key, "point": p.point, "episode": p.episode, "params": p.params,
                                "seed": p.seed, "status": p.status, "result": p.result, "error": p.error}
                               for p in summary.points]})
    else:
        print(format_table(rows, higher_is_better=args.higher_is_better))
        print(f"{len(points)} points x {args.episodes} episodes: {counts['ok']} ran, {counts['skipped']} already "
              f"done, {counts['failed']} failed; results in {summary.out_dir}/<key>/result.json")
        for p in summary.points:
            if p.status == "failed":
                print(f"  FAILED {p.key} {p.params} episode {p.episode}: {p.error}")
        if plot:
            print(f"plot: {plot}")
    return EXIT_FAILED if counts["failed"] else 0
