"""The rehearsal bench's own device processes (the serial mocks run as ``tactile-rig mock serve``).

``python -m tactile_rig.rig.rehearsal.child stage [--scene S] [--seed N] [--homing] [--fps F] CAMERA-OPTIONS``
    The jig and what its camera looks at: the GRBL mock on a pty, moving the stage of the scene's
    world, and the GelSight camera rendering that world. They share one process because they share
    one world (on a real bench the object on the stage is what the fingertip camera sees).

``python -m tactile_rig.rig.rehearsal.child press [--scene S] [--seed N] [--fps F] CAMERA-OPTIONS``
    The gripper pressing its FingerVision fingertip on the scale: the MX-64 mock and the scale's
    mock each on a pty, and the fingertip camera rendering the skin, on one world (the
    ``force_map_press`` scene): the servo's squeeze loads the cell and deforms the skin, which is
    what a force-map collection needs.

``python -m tactile_rig.rig.rehearsal.child camera --source FILE[#TOPIC] [--name NAME] CAMERA-OPTIONS``
    A camera playing recorded footage (:mod:`.frames`) at its recorded rate.

CAMERA-OPTIONS: ``--transport v4l2|http`` (an emulated ``/dev/videoN`` in ``--registry DIR``, node
``--node N``; or MJPEG over HTTP), ``--model KEY`` (the camera model, default c310), ``--fourcc``,
``--jpeg-quality``. Each prints one JSON line (the ports), then serves in real time until
SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Any, Iterator, Sequence

from tactile_rig.core.clock import RealClock
from tactile_rig.core.errors import RigError
from tactile_rig.devices.camera_models import camera_model
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.mocks.registry import Params, create_device
from tactile_rig.rig.rehearsal.cameras import (DEFAULT_MODEL, DEFAULT_TRANSPORT, FOURCCS, TRANSPORTS, ServedCamera,
                                               check_mode, footage_mode, rehearsal_camera, serve_camera)
from tactile_rig.rig.rehearsal.frames import load_footage
from tactile_rig.sim.scenes import FORCE_MAP_PRESS_SCENE, JIG_ACCURACY_SCENE, load_scene

STAGE_SCENE = JIG_ACCURACY_SCENE  # what lies on the jig's stage unless the rehearsal names another
CAMERA_SIZE = (320, 240)  # the GelSight pipeline's frame (gs_sdk's view of a GelSight Mini) and FingerVision's


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


@contextmanager
def _camera(args: argparse.Namespace, source: Any, clock: Any, name: str, width: int, height: int,
            fps: float) -> Iterator[ServedCamera]:
    """``source`` seen by the camera CAMERA-OPTIONS describe, served until the block ends."""
    model = camera_model(args.model)
    if args.transport == "http" and args.fourcc != "MJPG":
        raise ValueError(f"camera {name}: the HTTP camera streams MJPG only, not {args.fourcc}")
    check_mode(model, args.fourcc, width, height, fps, what=f"camera {name}")
    sim = rehearsal_camera(source, model=model, fourcc=args.fourcc, width=width, height=height, fps=fps,
                           transport=args.transport, clock=clock, name=name, seed=args.seed)
    with serve_camera(sim, transport=args.transport, model=model, fourcc=args.fourcc, width=width, height=height,
                      fps=fps, jpeg_quality=args.jpeg_quality, registry=args.registry, node=args.node,
                      serial=args.serial) as served:
        yield served


def serve_stage(args: argparse.Namespace) -> int:
    """The jig on a pty and the GelSight camera, on one world (see the module doc)."""
    clock = RealClock()
    world = load_scene(args.scene, clock=clock, seed=args.seed).world
    jig = create_device("jig", Params({"homing": "1" if args.homing else "0"}, source="rehearsal stage"),
                        clock=clock, world=world)
    width, height = CAMERA_SIZE
    renderer = world.require("gelsight", "the rehearsal's GelSight camera")
    with PtyServer(jig, clock=clock, name="jig") as pty_server, \
            _camera(args, renderer, clock, "gelsight", width, height, args.fps) as cam:
        _emit({"device": "jig", "port": pty_server.port, "baud": jig.baud, "homing": bool(args.homing),
               "scene": args.scene, "camera": {"sensor": "gelsight", **cam.info}})
        return _wait_for_signal(lambda: (f"jig mock failed: {pty_server.error}" if pty_server.error else
                                         f"camera failed: {cam.error}" if cam.error else None))


def serve_press(args: argparse.Namespace) -> int:
    """Gripper and scale on ptys, the FingerVision camera, on one world (see the module doc)."""
    clock = RealClock()
    world = load_scene(args.scene, clock=clock, seed=args.seed).world
    grip = create_device("dynamixel", Params({"protocol": "2", "ids": "1", "baud": "57600"}, source="rehearsal press"),
                         clock=clock, world=world)
    scale = create_device("scale", Params({"rate": str(args.rate), "seed": str(args.seed)}, source="rehearsal press"),
                          clock=clock, world=world)
    width, height = CAMERA_SIZE  # the FingerVision renderer's 320x240 too
    renderer = world.require("fingervision", "the rehearsal's FingerVision camera")
    with PtyServer(grip, clock=clock, name="gripper") as g, PtyServer(scale, clock=clock, name="scale") as sc, \
            _camera(args, renderer, clock, "fingervision", width, height, args.fps) as cam:
        _emit({"device": "press", "gripper": {"port": g.port, "baud": 57600}, "scale": {"port": sc.port, "baud": 57600},
               "scene": args.scene, "camera": {"sensor": "fingervision", **cam.info}})
        return _wait_for_signal(lambda: next((f"{n} failed: {e}" for n, e in (("gripper", g.error),
                                              ("scale", sc.error), ("camera", cam.error)) if e), None))


def serve_footage(args: argparse.Namespace) -> int:
    """Recorded footage as a camera, played at its recorded rate."""
    footage = load_footage(args.source)
    width, height, fps = footage_mode(camera_model(args.model), args.fourcc, *footage.size_px, footage.fps)
    with _camera(args, footage.render, RealClock(), args.name, width, height, fps) as cam:
        _emit({"device": "camera", "name": args.name, "source": args.source, "frames": len(footage.frames),
               "footage": {"width": footage.size_px[0], "height": footage.size_px[1], "fps": round(footage.fps, 3)},
               **cam.info})
        return _wait_for_signal(lambda: f"camera failed: {cam.error}" if cam.error else None)


def _camera_options(p: argparse.ArgumentParser, fps: bool = True) -> None:
    p.add_argument("--seed", type=int, default=0)
    if fps:
        p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--transport", choices=TRANSPORTS, default=DEFAULT_TRANSPORT)
    p.add_argument("--model", default=DEFAULT_MODEL, help="camera model (c310, gelsight-mini, digit)")
    p.add_argument("--fourcc", choices=FOURCCS, default="MJPG")
    p.add_argument("--jpeg-quality", type=int, default=95)
    p.add_argument("--registry", help="the emulated cameras' registry directory (--transport v4l2)")
    p.add_argument("--node", type=int, help="the /dev/videoN number (--transport v4l2; default the first free)")
    p.add_argument("--serial", help="the camera's USB serial number (--transport v4l2; default the model's)")


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m tactile_rig.rig.rehearsal.child", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    st = sub.add_parser("stage")
    st.add_argument("--scene", default=STAGE_SCENE)
    st.add_argument("--homing", action="store_true", help="GRBL homing enabled: the jig boots in Alarm, $H homes")
    _camera_options(st)
    st.set_defaults(func=serve_stage)
    pr = sub.add_parser("press")
    pr.add_argument("--scene", default=FORCE_MAP_PRESS_SCENE)
    _camera_options(pr)
    pr.add_argument("--rate", type=int, default=80, help="scale samples per second (10 or 80)")
    pr.set_defaults(func=serve_press)
    cam = sub.add_parser("camera")
    cam.add_argument("--source", required=True)
    cam.add_argument("--name", default="camera")
    _camera_options(cam, fps=False)
    cam.set_defaults(func=serve_footage)
    args = p.parse_args(argv)
    try:
        return int(args.func(args))
    except (RigError, ValueError, OSError) as exc:  # bad options, footage, a busy node: one line
        print(f"tactile-rig rehearsal: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover - run as a process by the rehearsal bench
    sys.exit(main())
