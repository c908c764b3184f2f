"""``tactile-rig replay FILE``: summarise or dump a session recording (MCAP)."""

from __future__ import annotations

import argparse

from tactile_rig.cli.common import add_json_flag, extras_as_errors, print_json
from tactile_rig.rig import replay as recordings


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="summarise or dump an MCAP session recording (truncated files too)")
    p.add_argument("file", help="the .mcap recording")
    p.add_argument("--topic", help="dump the messages of this topic (e.g. /scale/force)")
    p.add_argument("--dump", action="store_true", help="dump every message (one JSON line each with --json)")
    p.add_argument("--images", action="store_true", help="include image payloads (base64) in dumps")
    add_json_flag(p)
    p.set_defaults(func=_replay)


@extras_as_errors
def _replay(args: argparse.Namespace) -> int:
    if args.topic or args.dump:
        n = 0
        try:
            for row in recordings.dump(args.file, topic=args.topic, include_images=args.images):
                n += 1
                if args.json:
                    print_json(row)
                else:
                    print(f"{row['t_s']:12.6f}  {row['topic']:<28} {_short(row['data'])}")
        except BrokenPipeError:  # `| head`: the reader has seen enough
            return 0
        if n == 0 and args.topic:
            topics = recordings.summarize(args.file)["topics"]
            raise ValueError(f"{args.file}: no messages on topic {args.topic!r}; topics: "
                             f"{', '.join(topics) or '(none)'}")
        return 0
    s = recordings.summarize(args.file)
    if args.json:
        print_json(s)
        return 0
    state = f"TRUNCATED ({s['truncation']}); complete chunks shown" if s["truncated"] else "complete"
    print(f"{s['path']}: {s['messages']} messages over {s['duration_s']:.3f} s, {state}")
    for topic, t in s["topics"].items():
        print(f"  {topic:<32} {t['count']:>7}  {t['schema']:<26} {t['first_t_s']:.3f} .. {t['last_t_s']:.3f} s")
    if s["metadata"]:
        print(f"  metadata: {', '.join(s['metadata'])}")
    if s["attachments"]:
        print("  attachments: " + ", ".join(f"{k} ({v} B)" for k, v in s["attachments"].items()))
    return 0


def _short(data: dict, limit: int = 100) -> str:
    import json

    text = json.dumps({k: v for k, v in data.items() if k != "t_s"}, separators=(",", ":"))
    return text if len(text) <= limit else text[: limit - 3] + "..."
