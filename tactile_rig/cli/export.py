"""``tactile-rig export``: a session recording in another ecosystem's format.

    tactile-rig export ros2 SESSION.mcap OUT [--force] [--json]   # a ROS 2 bag (MCAP storage, CDR)
    ros2 bag play OUT                                             # then, on a ROS 2 system

The bag holds the session's frames, tactile point clouds, wrenches, joint states, frames (tf), poses,
markers and log in the standard ROS 2 types (docs/foxglove_and_ros2.md lists them). A file that is
not a tactile-rig recording, is damaged or was cut off is refused (exit 2) and nothing is written; an
OUT that exists is refused unless ``--force``.
"""

from __future__ import annotations

import argparse
from typing import Any

from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.cli.replay import extras_as_errors
from tactile_rig.rig.ros2_export import export_ros2


def register(sub: Any) -> None:
    p = sub.add_parser("export", help="export a session recording (ROS 2 bag)", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    esub = p.add_subparsers(dest="format", metavar="FORMAT", required=True)
    r = esub.add_parser("ros2", help="a ROS 2 bag (rosbag2, MCAP storage, CDR) with the standard message types")
    r.add_argument("session", metavar="SESSION.mcap", help="the session recording (.mcap)")
    r.add_argument("out", metavar="OUT", help="the bag folder to write (must not exist, unless --force)")
    r.add_argument("--force", action="store_true", help="replace OUT if it is a ROS 2 bag folder")
    add_json_flag(r)
    r.set_defaults(func=_ros2)


@extras_as_errors
def _ros2(args: argparse.Namespace) -> int:
    outcome = export_ros2(args.session, args.out, force=args.force)
    summary = {"out": str(outcome.path), "messages": sum(t["count"] for t in outcome.topics.values()),
               "topics": outcome.topics, "skipped": outcome.skipped}
    if args.json:
        print_json(summary)
        return 0
    print(f"wrote {summary['messages']} messages on {len(outcome.topics)} topics to {outcome.path}")
    for topic, t in sorted(outcome.topics.items()):
        print(f"  {topic:<36} {t['count']:>7}  {t['type']}")
    if outcome.skipped:
        print("  left out (no standard ROS 2 type): " + ", ".join(f"{k} ({n})" for k, n in sorted(outcome.skipped.items())))
    print(f"play it: ros2 bag play {outcome.path}")
    return 0
