"""``tactile-rig mock``: list the mock devices and serve one on a pty pair, or a UVC camera emulated at
the system-call boundary (``mock serve camera --v4l2``)."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
from typing import Any

from tactile_rig.cli.args import BAUD, SEED, int_in
from tactile_rig.cli.common import EXIT_FAULT, add_command_group, print_json
from tactile_rig.core.clock import RealClock
from tactile_rig.devices.camera_models import CAMERA_MODELS
from tactile_rig.mocks.v4l2 import CameraFaults, V4L2Camera
from tactile_rig.mocks.v4l2.frames import RENDERERS
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.mocks.registry import Params, create_device, kinds
from tactile_rig.mocks.scale_firmware import BoardConfig, SimulatedScaleBoard, build
from tactile_rig.sim.scenes import load_scene


def register(sub: argparse._SubParsersAction) -> None:
    _, msub = add_command_group(sub, "mock", help="serve faithful device mocks on pseudo-terminals")

    ls = msub.add_parser("list", help="list the mock devices")
    ls.add_argument("--json", action="store_true", help="print JSON")
    ls.set_defaults(func=_list)

    serve = msub.add_parser(
        "serve",
        help="serve a mock on a pty; prints one JSON line with the port and runs until SIGINT/SIGTERM",
    )
    serve.add_argument("device", help="device kind: dynamixel, scale, jig, or camera (with --v4l2)")
    serve.add_argument("--protocol", choices=["1", "2"], help="Dynamixel protocol version (default 2)")
    serve.add_argument("--id", dest="ids", type=int_in(0, 252), action="append", help="servo ID (repeat for several)")
    serve.add_argument("--baud", type=BAUD, help="the device's baud rate (default: the device's own)")
    serve.add_argument("--scene", help="scene file or built-in scene name for the world the device sees")
    serve.add_argument("--seed", type=SEED, help="seed of the scene's noise")
    serve.add_argument("--rate", choices=["10", "80"], help="scale samples per second (the HX711 RATE pin)")
    serve.add_argument("--no-timing", action="store_true", help="answer instantly instead of at wire speed")
    serve.add_argument(
        "--firmware",
        action="store_true",
        help="scale only: run the real sketch (firmware/arduino_scale) compiled for the ATmega328P on a "
        "simulated Uno + HX711 instead of the Python mock; the JSON line names the control FIFO that "
        "takes 'force_n <newtons>' lines (needs: " + "apt-get install gcc-avr avr-libc arduino-core-avr "
        "simavr libsimavr-dev libelf-dev)",
    )
    serve.add_argument(
        "--param", action="append", default=[], metavar="KEY=VALUE", help="any other device parameter"
    )
    cam = serve.add_argument_group(
        "camera (--v4l2)",
        "an emulated UVC camera: a /dev/videoN that v4l2-ctl, OpenCV's V4L2 backend and the camera driver "
        "open in any process started with the printed 'env' (LD_PRELOAD and the registry); the JSON line "
        "names the control FIFO that takes 'stall S', 'freeze S', 'unplug [S]' and 'replug' lines "
        "(needs: apt-get install gcc libc6-dev)")
    cam.add_argument("--v4l2", action="store_true", help="serve the camera at the V4L2 system-call boundary")
    cam.add_argument("--camera", choices=sorted(CAMERA_MODELS), default="c310", help="camera model (default c310)")
    cam.add_argument("--model", choices=RENDERERS, help="what the sensor sees: gelsight (default) or fingervision")
    cam.add_argument("--video", metavar="FILE", help="a recorded video as the frame source (looped)")
    cam.add_argument("--fault", metavar="QUERY",
                     help="faults, e.g. 'stall_after=100&stall_s=2' or 'unplug=0.001&away_s=3' "
                     "(keys: stall, freeze, unplug, replug, *_s, *_after, seed)")
    cam.add_argument("--node", type=int, metavar="N", help="the node number (default: the first free from 42)")
    cam.add_argument("--registry", metavar="DIR",
                     help="the registry directory clients read (default $TACTILE_RIG_V4L2_DIR or a per-user "
                     "directory in the temporary directory)")
    cam.add_argument("--kernel", metavar="MAJOR.MINOR",
                     help="answer as uvcvideo of that Linux version (default: the running kernel's)")
    cam.add_argument("--jpeg-quality", type=int, default=90, help="MJPG quality 1..100 (default 90)")
    serve.set_defaults(func=_serve)


def _list(args: argparse.Namespace) -> int:
    rows = [
        {"device": k.name, "default_baud": k.default_baud, "description": k.description}
        for k in kinds().values()
    ]
    if args.json:
        for r in rows:
            print_json(r)
    else:
        for r in rows:
            print(f"{r['device']:<10} {r['default_baud']:>8} baud  {r['description']}")
    return 0


def serve_params(args: argparse.Namespace) -> dict[str, str]:
    """The CLI options as the string parameters a device factory reads (same keys as rigsim:// URLs)."""
    params: dict[str, str] = {}
    if args.protocol:
        params["protocol"] = args.protocol
    if args.ids:
        params["ids"] = ",".join(str(i) for i in args.ids)
    if args.baud:
        params["baud"] = str(args.baud)
    if args.rate:
        params["rate"] = args.rate
    if args.no_timing:
        params["timing"] = "0"
    for kv in args.param:
        key, sep, value = kv.partition("=")
        if not sep or not key:
            raise ValueError(f"--param {kv!r} must look like KEY=VALUE")
        params[key] = value
    return params


def _serve(args: argparse.Namespace) -> int:
    if args.device == "camera" or args.v4l2:
        return _serve_camera(args)
    if args.firmware:
        return _serve_firmware(args)
    clock = RealClock()
    world = None
    if args.scene:

        world = load_scene(args.scene, clock=clock, seed=args.seed).world
    params = Params(serve_params(args), source=f"mock serve {args.device}")
    device = create_device(args.device, params, clock=clock, world=world)
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    with PtyServer(device, clock=clock, name=args.device) as server:
        info = {"device": args.device, "port": server.port, "baud": device.baud, "timing": device.timing}
        info.update(getattr(device, "describe", lambda: {})())
        sys.stdout.write(json.dumps(info) + "\n")
        sys.stdout.flush()
        while not stop.wait(0.2):
            if server.error is not None:
                print(f"tactile-rig: mock {args.device} failed: {server.error}", file=sys.stderr)
                return EXIT_FAULT
    return 0


# Parameters of the simulated board, by the names the Python mock takes (``--param KEY=VALUE``).
_FIRMWARE_PARAMS = {
    "force_n": ("force_n", float), "counts_per_g": ("counts_per_g", float),
    "offset_counts": ("offset_counts", float), "noise_counts": ("noise_counts", float),
    "drift_counts": ("drift_counts", float), "drift_tau_s": ("drift_tau_s", float),
    "spike_prob": ("spike_prob", float), "boot_s": ("bootloader_s", float), "boot_junk": ("boot_junk", int),
}


def firmware_config(args: argparse.Namespace) -> tuple[Any, str | None]:
    """The board's :class:`~tactile_rig.mocks.scale_firmware.BoardConfig` and EEPROM file from the CLI."""

    if args.device != "scale":
        raise ValueError(f"--firmware runs the scale's sketch; {args.device!r} has no firmware here (use 'scale')")
    if args.scene:
        raise ValueError("--firmware: a scene cannot drive the simulated board; set the load through its "
                         "control FIFO ('force_n <newtons>' lines) or --param force_n=...")
    for flag, name in ((args.protocol, "--protocol"), (args.ids, "--id"), (args.no_timing, "--no-timing")):
        if flag:
            raise ValueError(f"--firmware: {name} does not apply to the simulated board")
    if args.baud and args.baud != 57600:
        raise ValueError(f"--firmware: --baud {args.baud}: the sketch talks at 57600 baud")
    kw: dict[str, Any] = {}
    eeprom = None
    if args.rate:
        kw["rate_sps"] = int(args.rate)
    if args.seed is not None:
        kw["seed"] = args.seed
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--param {item!r} must look like KEY=VALUE")
        if key == "eeprom":
            eeprom = value
            continue
        if key not in _FIRMWARE_PARAMS:
            known = ", ".join(sorted([*_FIRMWARE_PARAMS, "eeprom"]))
            raise ValueError(f"--firmware: unknown parameter {key!r}; known: {known}")
        field, cast = _FIRMWARE_PARAMS[key]
        try:
            kw[field] = cast(value)
        except ValueError:
            raise ValueError(f"--param {key}={value!r} is not a{'n integer' if cast is int else ' number'}") from None
    return BoardConfig(**kw), eeprom


def _serve_firmware(args: argparse.Namespace) -> int:

    config, eeprom = firmware_config(args)
    build()  # a missing toolchain or a build error is reported before anything is served
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    with SimulatedScaleBoard(config, eeprom_path=eeprom) as board:
        info = {"device": "scale", "port": board.port, "baud": 57600, "timing": True, **board.describe()}
        sys.stdout.write(json.dumps(info) + "\n")
        sys.stdout.flush()
        while not stop.wait(0.2):
            if board.proc is None or board.proc.poll() is not None:
                print(f"tactile-rig: the simulated scale board stopped: {board.exit_reason()}", file=sys.stderr)
                return EXIT_FAULT
    return 0


def _kernel(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    major, sep, minor = text.partition(".")
    if not (sep and major.isdigit() and minor.isdigit()):
        raise ValueError(f"--kernel {text!r}: expected MAJOR.MINOR, e.g. 6.1")
    return int(major), int(minor)


def camera_from_args(args: argparse.Namespace) -> V4L2Camera:
    """The emulated camera the ``mock serve camera --v4l2`` options describe (not started)."""
    if args.device != "camera":
        raise ValueError(f"--v4l2 serves a camera; {args.device!r} is served on a pty (drop --v4l2)")
    if not args.v4l2:
        raise ValueError("the camera is served as an emulated V4L2 device: add --v4l2")
    for flag, name in ((args.protocol, "--protocol"), (args.ids, "--id"), (args.baud, "--baud"),
                       (args.rate, "--rate"), (args.no_timing, "--no-timing"), (args.firmware, "--firmware"),
                       (args.param, "--param")):
        if flag:
            raise ValueError(f"--v4l2: {name} does not apply to a camera")
    if args.video and (args.model or args.scene):
        raise ValueError("--video is the frame source: it takes no --model or --scene")
    faults = CameraFaults.from_query(args.fault) if args.fault else None
    return V4L2Camera(args.camera, renderer=args.model or "gelsight", video=args.video, scene=args.scene,
                      seed=args.seed or 0, node=args.node, registry=args.registry, faults=faults,
                      control_fifo=True, kernel=_kernel(args.kernel), jpeg_quality=args.jpeg_quality)


def _serve_camera(args: argparse.Namespace) -> int:
    cam = camera_from_args(args)
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    with cam:
        info = {"device": "camera", "port": cam.port, "env": cam.env, **cam.describe()}
        sys.stdout.write(json.dumps(info) + "\n")
        sys.stdout.flush()
        while not stop.wait(0.2):
            if cam.error is not None:
                print(f"tactile-rig: the emulated camera failed: {cam.error}", file=sys.stderr)
                return 1
    return 0
