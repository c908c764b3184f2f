"""``tactile-rig run``: long rig runs. ``run jig-accuracy`` reproduces Li 2014 Fig. 7 (see docs/jig_accuracy.md).

    tactile-rig run jig-accuracy --mock                      # the README's first command
    tactile-rig run jig-accuracy --bench bench.toml --sweep rotation --out runs/r1
    tactile-rig run jig-accuracy --mock --json | jq .        # one object per point, then a summary

A run interrupted at point k continues at k when started again with the same options and ``--out``
(``--resume`` insists on it; ``--overwrite`` starts afresh).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from tactile_rig.cli.args import SEED, finite_float, float_in, output_dir
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.bench_live import JIG_ACCURACY_TOPICS, add_live_arguments, live_from_args
from tactile_rig.cli.common import EXIT_FAILED, add_command_group, add_json_flag, print_json
from tactile_rig.rig.jig_accuracy import (
    JigAccuracyConfig,
    execute_jig_accuracy,
    format_table,
    plan_points,
)
from tactile_rig.rig.progress import Progress

DEFAULT_OUT_ROOT = "runs/jig-accuracy"


def register(subparsers: Any) -> None:
    _, sub = add_command_group(subparsers, "run", metavar="RUN", help="long rig runs (jig accuracy)",
                               description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p = sub.add_parser("jig-accuracy", help="Li 2014 Fig. 7: localization accuracy over jig rotations and shifts",
                       description="Build a tactile map of the object, step the jig through rotations and "
                                   "shifts, localize each touch and print estimated vs true with MAE and std.")
    add_bench_arguments(p)
    p.add_argument("--sweep", choices=["rotation", "translation", "both"], default="both",
                   help="which sweep(s) to run (default: both)")
    p.add_argument("--out", metavar="DIR", type=output_dir,
                   help=f"output folder: points.jsonl, summary.json, run.mcap, figures, report.md (default: "
                        f"{DEFAULT_OUT_ROOT}/<mock|bench>-<sweep>-<config fingerprint>, so the same command resumes)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the mock world (default 0)")
    p.add_argument("--resume", action="store_true",
                   help="continue the partial run in --out (automatic when the options match)")
    p.add_argument("--overwrite", action="store_true", help="discard any run in --out and start again")
    p.add_argument("--rotations", type=finite_float, nargs=3, default=(-90.0, 90.0, 10.0),
                   metavar=("START", "STOP", "STEP"), help="rotation sweep in degrees, stop included "
                   "(default -90 90 10)")
    p.add_argument("--shifts", type=finite_float, nargs=3, default=(-6.0, 6.0, 1.0), metavar=("START", "STOP", "STEP"),
                   help="translation sweep in mm, stop included (default -6 6 1)")
    p.add_argument("--shift-axis", choices=["x", "y"], default="x", help="jig axis of the shifts (default x)")
    p.add_argument("--calibration", metavar="FILE",
                   help="GelSight calibration (.json/.npz); default: the bench camera's, or on --mock one "
                        "made by the ball-press calibration session")
    p.add_argument("--camera", metavar="NAME", help="which GelSight camera of the bench (default: the first)")
    p.add_argument("--no-record", action="store_true", help="do not write run.mcap")
    p.add_argument("--no-report", action="store_true", help="do not write figures and report.md")
    p.add_argument("--max-rotation-mae-deg", type=float_in(0.0, 360.0, "deg"), metavar="DEG",
                   help="exit 1 when the rotation MAE exceeds this")
    p.add_argument("--max-translation-mae-mm", type=float_in(0.0, 1000.0, "mm"), metavar="MM",
                   help="exit 1 when the translation MAE exceeds this")
    add_live_arguments(p)
    add_json_flag(p)
    p.set_defaults(func=_jig_accuracy)


def _jig_accuracy(args: argparse.Namespace) -> int:
    cfg = JigAccuracyConfig(sweep=args.sweep, rotations_deg=tuple(args.rotations), shifts_mm=tuple(args.shifts),
                            shift_axis=args.shift_axis, seed=args.seed)
    bench = None if args.mock else bench_from_args(args)
    kind = "mock" if bench is None else "bench"
    out_dir = args.out or str(Path(DEFAULT_OUT_ROOT) / f"{kind}-{cfg.sweep}-{cfg.fingerprint()[:8]}")
    total = len(plan_points(cfg))
    progress = None
    if not args.json:

        isatty = getattr(sys.stderr, "isatty", None)
        progress = Progress(total, label="jig accuracy", mode="bar" if callable(isatty) and isatty() else "off")

    def on_point(result: Any, done: int, n: int) -> None:
        if args.json:
            print_json(result.to_json())
        elif progress is not None:
            progress.update(1)

    live = live_from_args(args, topics=JIG_ACCURACY_TOPICS)
    try:
        outcome = execute_jig_accuracy(cfg, out_dir, bench=bench, calibration=args.calibration, camera=args.camera,
                                       resume=True if args.resume else None, overwrite=args.overwrite,
                                       record=not args.no_record, report=not args.no_report, on_point=on_point,
                                       live=live)
    finally:
        if progress is not None:
            progress.close()
        if live is not None:
            live.close()
    s = outcome.summary
    if args.json:
        print_json({**s, "out": str(outcome.out_dir), "resumed_from": outcome.resumed_from, "files": outcome.files})
    else:
        print(format_table(outcome.results, s))
        if outcome.resumed_from >= s["n_points"]:
            print("(this run was already complete: nothing was measured again; --overwrite to repeat it)")
        elif outcome.resumed_from:
            print(f"(resumed: points 0..{outcome.resumed_from - 1} come from the interrupted run)")
        written = sorted(Path(v).name for v in outcome.files.values() if not v.startswith("skipped"))
        print(f"results in {outcome.out_dir}/: " + ", ".join(written))
        for k, v in outcome.files.items():
            if v.startswith("skipped"):
                print(f"{k} {v}")
    failed = []
    if args.max_rotation_mae_deg is not None and not _within(s.get("rotation_mae_deg"), args.max_rotation_mae_deg):
        failed.append(f"rotation MAE {s.get('rotation_mae_deg')} deg > {args.max_rotation_mae_deg}")
    if args.max_translation_mae_mm is not None and not _within(s.get("translation_mae_mm"),
                                                                args.max_translation_mae_mm):
        failed.append(f"translation MAE {s.get('translation_mae_mm')} mm > {args.max_translation_mae_mm}")
    if failed:
        print("tactile-rig: accuracy check failed: " + "; ".join(failed), file=sys.stderr)
        return EXIT_FAILED
    return 0


def _within(value: float | None, limit: float) -> bool:
    return value is not None and value <= limit
