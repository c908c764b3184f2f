"""The rehearsal bench's own device processes (the serial mocks run as ``tactile-rig mock serve``).

``python -m tactile_rig.rig.rehearsal.child stage [--scene S] [--seed N] [--homing] [--fps F]``
    The jig and what its camera looks at: the GRBL mock on a pty, moving the stage of the scene's
    world, and the GelSight camera rendering that world, served as MJPEG over HTTP. They share one
    process because they share one world (on a real bench the object on the stage is what the
    fingertip camera sees).

``python -m tactile_rig.rig.rehearsal.child press [--scene S] [--seed N] [--fps F]``
    The gripper pressing its FingerVision fingertip on the scale: the MX-64 mock and the scale's
    mock each on a pty, and the fingertip camera rendering the skin as MJPEG over HTTP, on one world
    (the ``force_map_press`` scene): the servo's squeeze loads the cell and deforms the skin, which
    is what a force-map collection needs.

``python -m tactile_rig.rig.rehearsal.child camera --source FILE[#TOPIC] [--name NAME]``
    A camera playing recorded footage (:mod:`.frames`) at its recorded rate, as MJPEG over HTTP.

Each prints one JSON line (the ports), then serves in real time until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from typing import Any, Sequence

from tactile_rig.core.clock import RealClock
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.mocks.registry import Params, create_device
from tactile_rig.rig.rehearsal.camera_server import CameraServer
from tactile_rig.rig.rehearsal.frames import load_footage
from tactile_rig.sim.scenes import FORCE_MAP_PRESS_SCENE, JIG_ACCURACY_SCENE, load_scene

STAGE_SCENE = JIG_ACCURACY_SCENE  # what lies on the jig's stage unless the rehearsal names another
GELSIGHT_FORMAT = ("MJPG", 320, 240)  # GelSight Mini's 320x240 mode, the mock bench's camera


def _wait_for_signal(check: Any) -> int:
    stop = threading.Event()

    def _on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    parent = os.getppid()
    while not stop.wait(0.2):
        if os.getppid() != parent:  # the rehearsal that started us is gone: a device without a bench
            return 0
        problem = check()
        if problem:
            print(f"tactile-rig rehearsal: {problem}", file=sys.stderr)
            return 1
    return 0


def _emit(info: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(info) + "\n")
    sys.stdout.flush()


def serve_stage(args: argparse.Namespace) -> int:
    """The jig on a pty and the GelSight camera over HTTP, on one world (see the module doc)."""
    clock = RealClock()
    world = load_scene(args.scene, clock=clock, seed=args.seed).world
    jig = create_device("jig", Params({"homing": "1" if args.homing else "0"}, source="rehearsal stage"),
                        clock=clock, world=world)
    fourcc, width, height = GELSIGHT_FORMAT
    cam = SimulatedCamera(world.require("gelsight", "the rehearsal's GelSight camera"), clock=clock,
                          name="gelsight", fourcc=fourcc, width=width, height=height, fps=args.fps,
                          modes={GELSIGHT_FORMAT: args.fps}, seed=args.seed)
    with PtyServer(jig, clock=clock, name="jig") as pty_server, CameraServer(cam, jpeg_quality=args.jpeg_quality) as cams:
        _emit({"device": "jig", "port": pty_server.port, "baud": jig.baud, "homing": bool(args.homing),
               "scene": args.scene, "camera": {"url": cams.url, "sensor": "gelsight", "fourcc": fourcc,
                                               "width": width, "height": height, "fps": args.fps}})
        return _wait_for_signal(lambda: (f"jig mock failed: {pty_server.error}" if pty_server.error else
                                         f"camera failed: {cams.error}" if cams.error else None))


def serve_press(args: argparse.Namespace) -> int:
    """Gripper and scale on ptys, the FingerVision camera over HTTP, on one world (see the module doc)."""
    clock = RealClock()
    world = load_scene(args.scene, clock=clock, seed=args.seed).world
    grip = create_device("dynamixel", Params({"protocol": "2", "ids": "1", "baud": "57600"}, source="rehearsal press"),
                         clock=clock, world=world)
    scale = create_device("scale", Params({"rate": str(args.rate), "seed": str(args.seed)}, source="rehearsal press"),
                          clock=clock, world=world)
    fourcc, width, height = GELSIGHT_FORMAT  # the FingerVision renderer's 320x240 too
    cam = SimulatedCamera(world.require("fingervision", "the rehearsal's FingerVision camera"), clock=clock,
                          name="fingervision", fourcc=fourcc, width=width, height=height, fps=args.fps,
                          modes={GELSIGHT_FORMAT: args.fps}, seed=args.seed)
    with PtyServer(grip, clock=clock, name="gripper") as g, PtyServer(scale, clock=clock, name="scale") as sc, \
            CameraServer(cam) as cams:
        _emit({"device": "press", "gripper": {"port": g.port, "baud": 57600}, "scale": {"port": sc.port, "baud": 57600},
               "scene": args.scene, "camera": {"url": cams.url, "sensor": "fingervision", "fourcc": fourcc,
                                               "width": width, "height": height, "fps": args.fps}})
        return _wait_for_signal(lambda: next((f"{n} failed: {e}" for n, e in (("gripper", g.error),
                                              ("scale", sc.error), ("camera", cams.error)) if e), None))


def serve_camera(args: argparse.Namespace) -> int:
    """Recorded footage as a camera over HTTP."""
    footage = load_footage(args.source)
    width, height = footage.size_px
    fps = round(footage.fps, 3)
    cam = SimulatedCamera(footage.render, clock=RealClock(), name=args.name, fourcc="MJPG", width=width,
                          height=height, fps=fps, modes={("MJPG", width, height): fps}, seed=args.seed)
    with CameraServer(cam) as cams:
        _emit({"device": "camera", "name": args.name, "url": cams.url, "source": args.source, "fourcc": "MJPG",
               "width": width, "height": height, "fps": fps, "frames": len(footage.frames)})
        return _wait_for_signal(lambda: f"camera failed: {cams.error}" if cams.error else None)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tactile_rig.rig.rehearsal.child", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    st = sub.add_parser("stage")
    st.add_argument("--scene", default=STAGE_SCENE)
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--homing", action="store_true", help="GRBL homing enabled: the jig boots in Alarm, $H homes")
    st.add_argument("--fps", type=float, default=25.0)
    st.add_argument("--jpeg-quality", type=int, default=95)
    st.set_defaults(func=serve_stage)
    pr = sub.add_parser("press")
    pr.add_argument("--scene", default=FORCE_MAP_PRESS_SCENE)
    pr.add_argument("--seed", type=int, default=0)
    pr.add_argument("--fps", type=float, default=25.0)
    pr.add_argument("--rate", type=int, default=80, help="scale samples per second (10 or 80)")
    pr.set_defaults(func=serve_press)
    cam = sub.add_parser("camera")
    cam.add_argument("--source", required=True)
    cam.add_argument("--name", default="camera")
    cam.add_argument("--seed", type=int, default=0)
    cam.set_defaults(func=serve_camera)
    args = p.parse_args(argv)
    try:
        return int(args.func(args))
    except (ValueError, FileNotFoundError) as exc:
        print(f"tactile-rig rehearsal: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover - run as a process by the rehearsal bench
    sys.exit(main())
