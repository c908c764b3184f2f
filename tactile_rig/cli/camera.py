"""``tactile-rig camera``: the bench's fingertip cameras.

    tactile-rig camera list  [--bench B]                 # the bench's cameras, and this machine's V4L2 nodes
    tactile-rig camera check --bench B [--camera NAME]   # configured from its model: format, locked controls
                                                         # read back, the SDK view, frames arrive
    tactile-rig camera grab  --bench B [--camera NAME] [--count N] [--out DIR]
    tactile-rig camera fps   --bench B [--camera NAME] [--duration S]
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from tactile_rig.cli.args import float_in, int_in, output_dir
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import EXIT_FAILED, add_command_group, add_json_flag, print_json
from tactile_rig.rig.bench_camera import camera_name, grab_frames, measure_fps, open_camera, video_devices
from tactile_rig.rig.bench_check import check_device, format_check_table


def register(sub: Any) -> None:
    _, csub = add_command_group(sub, "camera", help="list, check, grab from and time the bench's cameras",
                                description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)

    ls = csub.add_parser("list", help="the bench's cameras and this machine's V4L2 devices")
    add_bench_arguments(ls)
    add_json_flag(ls)
    ls.set_defaults(func=_list)

    for name, helptext, func in (("check", "format and locked controls read back, frames arrive", _check),
                                 ("grab", "save frames as PNG", _grab),
                                 ("fps", "measure the frame rate, duplicates and dropped frames", _fps)):
        c = csub.add_parser(name, help=helptext)
        add_bench_arguments(c)
        c.add_argument("--camera", metavar="NAME", help="which camera of the bench (default: the first)")
        if name == "grab":
            c.add_argument("--count", type=int_in(1, 100_000), default=1, help="frames to save (default 1)")
            c.add_argument("--out", default=".", metavar="DIR", type=output_dir, help="folder for the PNG files (default .)")
        if name == "fps":
            c.add_argument("--duration", type=float_in(0.0, 3600.0, "s", low_open=True), default=3.0, metavar="S", help="measuring window (default 3 s)")
        add_json_flag(c)
        c.set_defaults(func=func)


def _list(args: argparse.Namespace) -> int:
    rows = []
    if args.bench or args.mock or os.environ.get("TACTILE_RIG_BENCH"):
        bench = bench_from_args(args)
        rows = [{"camera": k, "port": c.port, "sensor": c.sensor, "model": c.model,
                 "format": f"{c.fourcc} {c.width}x{c.height}", "fps": c.fps,
                 "calibration": str(c.calibration) if c.calibration else None}
                for k, c in bench.cameras.items()]
    nodes = video_devices()
    if args.json:
        for r in rows:
            print_json(r)
        for n in nodes:
            print_json({"v4l2": n["device"], "links": n["links"]})
        return 0
    for r in rows:
        print(f"{r['camera']:<22} {r['sensor']:<13} {r['model'] or '-':<14} {r['format']:<16} {r['fps']:>6g} fps  "
              f"{r['port']}")
    if not rows:
        print("(no bench given: pass --bench FILE to list its cameras)")
    for n in nodes:
        print(f"v4l2 {n['device']:<14} " + (" ".join(n["links"]) or "(no stable link: check udev)"))
    if not nodes:
        print("(no V4L2 devices on this machine)")
    return 0


def _check(args: argparse.Namespace) -> int:
    bench = bench_from_args(args)
    row = check_device(bench, camera_name(bench, args.camera))
    if args.json:
        print_json(row)
    else:
        print(format_check_table([row]))
        d = row.details
        if d.get("model"):
            print(f"  {'model':<28} {d['model']} ({d['title']})")
        if "format" in d:
            print(f"  {'format':<28} {d['format'][0]} {d['format'][1]}x{d['format'][2]} @ {d['format'][3]:g} fps")
        for k, v in d.get("controls", {}).items():
            want = d["locked"][k]
            if v is None:
                print(f"  {k:<28} not readable (locked at {want:g})")
            else:
                print(f"  {k:<28} {v:g}" + ("" if abs(v - want) <= 0.5 else f"  (locked at {want:g})"))
        if d.get("mains_hz") is None and "controls" in d:
            print(f"  {'power_line_frequency':<28} not locked: give mains_hz = 50 or 60 in the bench's camera table")
        if "frame_shape" in d:
            view = d.get("view") or "the raw frame"
            print(f"  {'frames':<28} {d['frame_shape'][1]}x{d['frame_shape'][0]} px ({view}), "
                  f"{d['measured_fps']:g} fps measured")
    return 0 if row.ok else EXIT_FAILED


def _grab(args: argparse.Namespace) -> int:
    bench = bench_from_args(args)
    name = camera_name(bench, args.camera)
    with open_camera(bench, name) as rig:
        paths = grab_frames(rig[name], args.count, args.out, name=name)
    if args.json:
        print_json({"camera": name, "files": [str(p) for p in paths]})
    else:
        for p in paths:
            print(p)
    return 0


def _fps(args: argparse.Namespace) -> int:
    bench = bench_from_args(args)
    name = camera_name(bench, args.camera)
    with open_camera(bench, name) as rig:
        m = measure_fps(rig[name], args.duration, name=name)
    if args.json:
        print_json(m)
    else:
        dev = f", device clock {m.device_fps:g} fps" if m.device_fps is not None else ""
        print(f"{name}: {m.frames} frames in {m.duration_s:.2f} s = {m.host_fps:g} fps on arrival{dev} "
              f"(configured {m.configured_fps:g}); {m.duplicates} duplicates, {m.dropped} dropped, "
              f"longest gap {m.max_gap_s * 1000:.0f} ms")
    if m.dropped or m.host_fps < 0.8 * m.configured_fps:
        print(f"tactile-rig: {name} delivers {m.host_fps:g} fps, configured {m.configured_fps:g}", file=sys.stderr)
        return EXIT_FAILED
    return 0
