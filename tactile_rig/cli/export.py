"""``tactile-rig export``: a session recording in another ecosystem's format.

    tactile-rig export ros2 SESSION.mcap OUT [--force] [--json]   # a ROS 2 bag (MCAP storage, CDR)
    ros2 bag play OUT                                             # then, on a ROS 2 system
    tactile-rig export layout OUT.json [--camera NAME ...]        # a Foxglove layout for these cameras

The bag holds the session's frames, tactile point clouds, wrenches, joint states, frames (tf), poses,
markers and log in the standard ROS 2 types (docs/foxglove_and_ros2.md lists them). A file that is
not a tactile-rig recording, is damaged or was cut off is refused (exit 2) and nothing is written; an
OUT that exists is refused unless ``--force``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from tactile_rig.cli.args import output_file
from tactile_rig.cli.common import add_command_group, add_json_flag, extras_as_errors, print_json
from tactile_rig.rig.messages.layout import DEFAULT_CAMERAS, session_layout
from tactile_rig.rig.ros2_export import export_ros2


def register(sub: Any) -> None:
    _, esub = add_command_group(sub, "export", metavar="FORMAT", help="export a session recording (ROS 2 bag)",
                                description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    r = esub.add_parser("ros2", help="a ROS 2 bag (rosbag2, MCAP storage, CDR) with the standard message types")
    r.add_argument("session", metavar="SESSION.mcap", help="the session recording (.mcap)")
    r.add_argument("out", metavar="OUT", help="the bag folder to write (must not exist, unless --force)")
    r.add_argument("--force", action="store_true", help="replace OUT if it is a ROS 2 bag folder")
    add_json_flag(r)
    r.set_defaults(func=_ros2)
    lay = esub.add_parser("layout", help="a Foxglove layout (image, 3-D, plots, log, services) for a bench's cameras")
    lay.add_argument("out", metavar="OUT.json", type=output_file(".json"), help="the layout file to write")
    lay.add_argument("--camera", action="append", metavar="NAME",
                     help=f"a camera's name (repeat; the first fills the Image panel; default: {', '.join(DEFAULT_CAMERAS)})")
    lay.set_defaults(func=_layout)


@extras_as_errors
def _layout(args: argparse.Namespace) -> int:
    Path(args.out).write_text(session_layout(args.camera or DEFAULT_CAMERAS), encoding="utf-8")
    print(f"wrote {args.out} (Foxglove: Layouts -> Import from file)")
    return 0


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
