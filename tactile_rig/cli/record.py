"""``tactile-rig record``: every device's stream of a bench into one MCAP, optionally live.

    tactile-rig record --bench bench.toml --duration 10 --out session.mcap
    tactile-rig record --bench bench.toml --duration 60 --live       # + Foxglove WebSocket on 127.0.0.1:8765

What is recorded and served: docs/foxglove_and_ros2.md (frames, the jig's frame tree, the gripper's
joint, the scale; live, the services tare_scale and stop_motion). ``dropped`` counts the frames the
host captured that the recording did not get; ``camera_dropped`` the gaps in a camera's own frame
numbers (frames lost in the camera or its link, before the host saw them).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from tactile_rig.cli.args import DURATION_S, output_file
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.bench_live import add_live_arguments, live_from_args
from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.rig.bench_record import record_bench, record_topics


def register(sub: Any) -> None:
    p = sub.add_parser("record", help="record every device of a bench to one MCAP (optionally live)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_bench_arguments(p)
    p.add_argument("--duration", type=DURATION_S, required=True, metavar="S", help="how long to record (s)")
    p.add_argument("--out", metavar="FILE.mcap", type=output_file(".mcap"), help="output file (default: recordings/session-<time>.mcap)")
    p.add_argument("--png", action="store_true", help="store frames as PNG (lossless) instead of JPEG")
    add_live_arguments(p)
    add_json_flag(p)
    p.set_defaults(func=_record)


def _record(args: argparse.Namespace) -> int:
    bench = bench_from_args(args)
    out = args.out or f"recordings/session-{time.strftime('%Y%m%d-%H%M%S')}.mcap"
    if not out.endswith(".mcap"):
        raise ValueError(f"--out {out!r} must name an .mcap file")
    live = live_from_args(args, topics=record_topics(bench))
    tty = getattr(sys.stderr, "isatty", lambda: False)()

    def tick(o: Any) -> None:
        if tty and not args.json:
            fps = " ".join(f"{k} {v:.1f} fps" for k, v in o.camera_fps.items())
            print(f"\r{sum(o.counts.values())} messages  {fps}   ", end="", file=sys.stderr, flush=True)

    try:
        outcome = record_bench(bench, args.duration, out, live=live, jpeg=not args.png, on_tick=tick)
    finally:
        if live is not None:
            live.close()
    if tty and not args.json:
        print(file=sys.stderr)
    summary = {"out": str(outcome.path), "duration_s": round(outcome.duration_s, 3), "topics": outcome.counts,
               "camera_fps": outcome.camera_fps, "dropped": outcome.dropped,
               "camera_dropped": outcome.camera_dropped, "missed": outcome.missed}
    if args.json:
        print_json(summary)
    else:
        print(f"recorded {sum(outcome.counts.values())} messages in {outcome.duration_s:.1f} s to {outcome.path}")
        for topic, n in sorted(outcome.counts.items()):
            print(f"  {topic:<40} {n:>7}")
        for device, n in sorted(outcome.missed.items()):
            print(f"  {device}: {n} poll(s) unanswered and skipped")
        for camera, n in sorted(outcome.dropped.items()):
            print(f"  {camera}: {n} frame(s) captured but not recorded")
        for camera, n in sorted(outcome.camera_dropped.items()):
            print(f"  {camera}: {n} frame(s) missing from the camera's own sequence (lost before the host)")
    return 0
