"""``tactile-rig scene``: list the controller scenes and run randomised episodes of one.

``tactile-rig scene run NAME --episodes K --json`` prints one JSON object per episode (``ok``:
whether the episode met the controller's property, ``outcome``, key figures) and a summary object
last. Exit code 0 when every episode was ok, 1 otherwise; a speed above the collision-stop cap is
refused (exit 2) before anything moves.
"""

from __future__ import annotations

import argparse

from tactile_rig.cli.args import COUNT, SEED, float_in
from tactile_rig.cli import bench_live
from tactile_rig.cli.common import EXIT_FAILED, add_command_group, add_json_flag, print_json
from tactile_rig.rig.scene_runner import list_scenes, run_episodes


def register(sub: argparse._SubParsersAction) -> None:
    _, ssub = add_command_group(sub, "scene", help="run the closed-loop controllers in simulated scenes")

    ls = ssub.add_parser("list", help="list the built-in controller scenes")
    add_json_flag(ls)
    ls.set_defaults(func=_list)

    run = ssub.add_parser("run", help="run randomised episodes of a scene in virtual time")
    run.add_argument("name", help="built-in scene name or path to a scene .toml")
    run.add_argument("--seed", type=SEED, default=0, help="seed of the first episode (episode i: seed+i)")
    run.add_argument("--episodes", type=COUNT, default=1, help="number of episodes (default 1)")
    run.add_argument("--speed-mps", type=float_in(0.0, 100.0, "m/s", low_open=True), default=None,
                     help="approach speed in m/s (collision scenes; above the cap is refused)")
    add_json_flag(run)
    bench_live.add_live_arguments(run)
    run.set_defaults(func=_run)


def _list(args: argparse.Namespace) -> int:
    rows = list_scenes()
    for r in rows:
        if args.json:
            print_json(r)
        else:
            models = ", ".join(f"{k}:{v}" for k, v in r["models"].items())
            print(f"{r['name']:<28} {r['controller']:<16} {r['description']}  [{models}]")
    return 0


def _run(args: argparse.Namespace) -> int:
    def show(r) -> None:  # noqa: ANN001
        if args.json:
            print_json(r.to_json())
        else:
            figs = " ".join(f"{k}={v:.4g}" for k, v in r.figures.items() if isinstance(v, float))
            print(f"episode {r.episode:>4} seed {r.seed:>6} {'ok ' if r.ok else 'BAD'} {r.outcome:<10} {figs}")

    if args.live:
        summary = bench_live.scene_live(args, show)
    else:
        summary = run_episodes(args.name, args.seed, args.episodes, speed_mps=args.speed_mps, on_episode=show)
    if args.json:
        print_json(summary)
    else:
        print(f"{summary['ok']}/{summary['episodes']} episodes ok; outcomes {summary['outcomes']}; "
              f"{summary['sim_s']} s simulated in {summary['wall_s']} s wall "
              f"({summary['sim_per_wall']}x real time)")
    return 0 if summary["ok"] == summary["episodes"] else EXIT_FAILED
