"""``tactile-rig bench``: rehearse a bench without hardware, and check a bench's devices.

    tactile-rig bench rehearse --out rehearsal            # serves until Ctrl-C; prints the bench file
    tactile-rig bench check --bench rehearsal/bench.toml  # one row per device; exit 1 if any fails
    tactile-rig bench env --bench rehearsal/bench.toml    # what another program needs to open its cameras
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import sys
import threading
from typing import Any

from tactile_rig.cli.args import DURATION_S, SEED, float_in, int_in, output_dir
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import EXIT_FAILED, EXIT_FAULT, add_command_group, add_json_flag, print_json
from tactile_rig.cli.emulation import BENCH_ENV, bench_emulation
from tactile_rig.devices.camera_models import CAMERA_MODELS
from tactile_rig.rig.bench import load_bench
from tactile_rig.rig.bench_check import check_bench, format_check_table
from tactile_rig.rig.rehearsal import RehearsalBench, RehearsalOptions
from tactile_rig.rig.rehearsal.cameras import DEFAULT_TRANSPORT, FOURCCS, TRANSPORTS


def register(sub: Any) -> None:
    _, bsub = add_command_group(sub, "bench", help="rehearse a bench without hardware; check a bench's devices",
                                description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)

    r = bsub.add_parser("rehearse", help="serve every device from its mock in its own process and write "
                        "bench.toml naming them; runs until Ctrl-C",
                        description="Start the gripper, scale and jig mocks each in its own process on its own "
                        "pty, the GelSight camera rendering the jig's stage and each --camera's footage as emulated "
                        "V4L2 devices (/dev/videoN, opened through OpenCV's V4L2 backend; or MJPEG over HTTP), write "
                        "OUT/bench.toml naming them, and serve until Ctrl-C.")
    r.add_argument("--out", default="rehearsal", metavar="DIR", type=output_dir,
                   help="folder for bench.toml, the device links (dev/) and the calibration (default: rehearsal)")
    r.add_argument("--camera", action="append", default=[], metavar="NAME=SOURCE[@SENSOR]",
                   help="a camera playing recorded footage at its recorded rate: a video file, a folder of "
                        "images, FILE.mcap[#TOPIC], or 'rendered' (a FingerVision press video the rehearsal "
                        "writes); SENSOR fingervision (default) or gelsight; repeat for several")
    r.add_argument("--seed", type=SEED, default=0, help="seed of the mocks' noise (default 0)")
    r.add_argument("--homing", action="store_true",
                   help="GRBL homing enabled: the jig boots locked and $H takes ~20 s, as on a real jig")
    r.add_argument("--gelsight-fps", type=float_in(0.0, 1000.0, "frames/s", low_open=True), default=25.0, help="frame rate of the GelSight camera (default 25)")
    r.add_argument("--gelsight-jpeg-quality", type=int_in(1, 100), default=95, metavar="Q",
                   help="JPEG quality of the GelSight camera's MJPG, 1..100 (default 95)")
    r.add_argument("--gelsight-fourcc", choices=FOURCCS, default="MJPG",
                   help="pixel format the bench asks of the GelSight camera: MJPG (default, as a GelSight Mini "
                        "streams) or YUYV (uncompressed; V4L2 cameras only)")
    r.add_argument("--camera-transport", choices=TRANSPORTS, default=DEFAULT_TRANSPORT,
                   help="v4l2 (default): each camera an emulated V4L2 device /dev/videoN; http: MJPEG over HTTP "
                        "on 127.0.0.1")
    r.add_argument("--camera-model", action="append", default=[], metavar="NAME=MODEL",
                   help=f"the camera model of camera NAME (gelsight, fingervision or a --camera name): "
                        f"{', '.join(CAMERA_MODELS)} (default c310 for every camera); repeat for several")
    r.add_argument("--stage-scene", default="jig_accuracy", metavar="SCENE",
                   help="what lies on the jig's stage under the GelSight camera: jig_accuracy (the object of "
                        "the accuracy run, default) or gelsight_ball_presses (the calibration ball)")
    r.add_argument("--press", action="store_true",
                   help="the gripper presses a FingerVision fingertip (camera_fingervision) on the scale: gripper, "
                        "scale and that camera share one process and world (for calibrate force-map)")
    r.add_argument("--no-calibration", action="store_true",
                   help="do not make the GelSight calibration on the mocks (the bench then names none)")
    r.add_argument("--duration", type=DURATION_S, metavar="S", help="stop after S seconds instead of at Ctrl-C")
    add_json_flag(r)
    r.set_defaults(func=_rehearse)

    c = bsub.add_parser("check", help="open every device and verify its identity; exit 1 if any fails",
                        description="Open every device of the bench on its own and verify it: the Dynamixel's "
                        "model number, the scale sketch's banner and rate, the GRBL version, the camera's format "
                        "and locked controls read back, and frames arriving.")
    add_bench_arguments(c)
    add_json_flag(c)
    c.set_defaults(func=_check)

    e = bsub.add_parser("env", help="the environment a program needs to open a rehearsal's emulated cameras",
                        description="Print, as shell export lines, the environment (LD_PRELOAD, TACTILE_RIG_V4L2_DIR) "
                        "a program must be started with to open the emulated V4L2 cameras the bench names "
                        "(v4l2-ctl, your own OpenCV script); tactile-rig commands load it by themselves. Nothing "
                        "for a bench of real cameras.")
    e.add_argument("--bench", metavar="FILE", help=f"the bench file (default: ${BENCH_ENV})")
    add_json_flag(e)
    e.set_defaults(func=_env, opens_devices=False)  # it reads the bench file, no device: no emulation needed


def parse_camera_option(text: str) -> tuple[str, str, str]:
    """``NAME=SOURCE[@SENSOR]`` → (name, source, sensor)."""
    name, sep, rest = text.partition("=")
    if not sep or not name or not rest:
        raise ValueError(f"--camera {text!r} must look like NAME=SOURCE[@SENSOR], e.g. fingervision=demo.mp4")
    source, at, sensor = rest.rpartition("@")
    if not at or sensor not in ("gelsight", "fingervision"):
        return name, rest, "fingervision"
    return name, source, sensor


def parse_model_option(text: str) -> tuple[str, str]:
    """``NAME=MODEL`` → (name, model)."""
    name, sep, model = text.partition("=")
    if not sep or not name or not model:
        raise ValueError(f"--camera-model {text!r} must look like NAME=MODEL, e.g. fingervision=digit")
    return name, model


def _rehearse(args: argparse.Namespace) -> int:
    cams = [parse_camera_option(c) for c in args.camera]
    opts = RehearsalOptions(cameras={n: s for n, s, _ in cams}, camera_sensors={n: k for n, _, k in cams},
                            seed=args.seed, homing=args.homing, gelsight_fps=args.gelsight_fps,
                            gelsight_jpeg_quality=args.gelsight_jpeg_quality, stage_scene=args.stage_scene,
                            press=args.press, calibration=not args.no_calibration,
                            camera_transport=args.camera_transport, gelsight_fourcc=args.gelsight_fourcc,
                            camera_models=dict(parse_model_option(m) for m in args.camera_model))
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    with RehearsalBench(args.out, opts) as rb:
        if args.json:
            print_json(rb.describe())
        else:
            print(f"rehearsal bench up: {len(rb.processes)} device processes")
            for dev in rb.devices:
                pid = ",".join(str(p) for p in dev.pids)
                print(f"  {dev.table:<20} pid {pid:<8} {_where(dev.keys)}")
            print(f"bench file: {rb.bench_path}")
            print(f"  export {BENCH_ENV}={rb.bench_path.resolve()}")
            if rb.env:
                print("the cameras are emulated V4L2 devices: tactile-rig commands load their library by "
                      "themselves; other programs (v4l2-ctl, your own OpenCV code) need:")
                print("  export " + " ".join(f"{k}={shlex.quote(v)}" for k, v in rb.env.items()))
            print("Ctrl-C stops it.")
            sys.stdout.flush()
        waited = 0.0
        while not stop.wait(0.5):
            waited += 0.5
            broken = rb.problems()
            if broken:
                print("tactile-rig: rehearsal device process stopped: " + "; ".join(broken), file=sys.stderr)
                return EXIT_FAULT
            if args.duration is not None and waited >= args.duration:
                break
    return 0


def _where(keys: dict[str, Any]) -> str:
    port = str(keys["port"])
    if "fourcc" in keys:
        return f"{port}  ({keys['fourcc']} {keys['width']}x{keys['height']} at {keys['fps']:g} fps)"
    return port


def _env(args: argparse.Namespace) -> int:
    path = args.bench or os.environ.get(BENCH_ENV)
    if not path:
        raise ValueError(f"no bench given: pass --bench FILE or set {BENCH_ENV}")
    load_bench(path, check_ports=False, check_files=False)  # a file that is not a bench: its own error
    emu = bench_emulation(path)
    env = {} if emu is None else emu.env()
    if emu is not None:
        emu.check()
    if args.json:
        print_json(env)
    elif env:
        print("export " + " ".join(f"{k}={shlex.quote(v)}" for k, v in env.items()))
    else:
        print(f"# {path}: no emulated cameras (a bench of real devices needs no environment)", file=sys.stderr)
    return 0


def _check(args: argparse.Namespace) -> int:
    bench = bench_from_args(args)
    rows = check_bench(bench)
    if args.json:
        for r in rows:
            print_json(r)
    else:
        print(format_check_table(rows))
    failed = [r.device for r in rows if not r.ok]
    if failed:
        print(f"tactile-rig: bench check failed: {', '.join(failed)}", file=sys.stderr)
        return EXIT_FAILED
    return 0
