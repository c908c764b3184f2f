"""``tactile-rig calibrate gelsight|fingervision|scale|gripper``: guided, scriptable calibration sessions.

Registered into ``tactile-rig calibrate`` by :mod:`tactile_rig.cli.calibrate`. Each session connects
only the devices it needs from ``--bench FILE`` (or the built-in mocks with ``--mock``), prompts on a
terminal and never when stdin is not one, and writes a versioned calibration file with its report
(see :mod:`tactile_rig.rig.calibration_sessions`).

    tactile-rig calibrate gelsight --mock --out calib/gelsight
    tactile-rig calibrate scale --bench bench.toml --known-mass-g 500 --out calib/scale.json
    tactile-rig calibrate gripper --bench bench.toml --out calib/gripper.json
    tactile-rig calibrate fingervision --mock --frames 10 --out calib/fingervision
    tactile-rig calibrate gelsight --mock --live     # + what it records, live in Foxglove (ws://127.0.0.1:8765)
"""

from __future__ import annotations

import argparse
from typing import Any, Callable

from tactile_rig.cli.args import EFFORT, SEED, TIMEOUT_S, any_int, finite_float, float_in, int_in, output_file_or
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.bench_live import add_live_arguments, live_from_args
from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.core.clock import VirtualClock
from tactile_rig.devices.scale import STANDARD_GRAVITY_MPS2
from tactile_rig.drivers.dynamixel import DynamixelGripper
from tactile_rig.mocks.registry import device_from_url
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.rig.bench import Bench, connect_bench
from tactile_rig.rig.calibration_sessions import (
    BallPressPlan,
    Guide,
    fingervision_session,
    gelsight_session,
    gripper_session,
    scale_session,
)
from tactile_rig.rig.jig_accuracy import DeviceJigRig, prepare_jig, sim_camera_connector
from tactile_rig.rig.recording import camera_topic
from tactile_rig.sim.scenes import GELSIGHT_BALL_PRESS_SCENE


def register_sessions(csub: Any) -> None:
    """Add the four device calibration sessions to the ``calibrate`` subparsers."""

    def common(p: argparse.ArgumentParser, out: str) -> None:
        add_bench_arguments(p)
        p.add_argument("--out", default=out, type=output_file_or(out), help=f"calibration to write: version N goes to <name>-vN.*, "
                                                  f"<name>.* links to the newest (default {out})")
        p.add_argument("--force", action="store_true",
                       help="overwrite the newest version (or the named -vN file) instead of adding a version")
        p.add_argument("--seed", type=SEED, default=0, help="seed of the mock world (default 0)")
        p.add_argument("--yes", action="store_true", help="never prompt, even on a terminal")
        add_json_flag(p)
        add_live_arguments(p)

    g = csub.add_parser("gelsight", help="GelSight colour→gradient calibration from ball presses moved by the jig",
                        description="Press a ball into the gel at a grid of jig positions, fit the colour-to-"
                                    "gradient model, write <out>.npz + <out>.json and a held-out error report.")
    common(g, "calib/gelsight")
    g.add_argument("--device", help="GelSight camera table of the bench (default: the first)")
    g.add_argument("--ball-radius-mm", type=float_in(0.0, 100.0, "mm", low_open=True), default=2.0, help="radius of the ball (default 2.0 mm)")
    g.add_argument("--press-depth-mm", type=float_in(0.0, 10.0, "mm", low_open=True), default=0.6, help="press depth past first contact (default 0.6)")
    g.add_argument("--grid-x", type=finite_float, nargs=3, default=(-7.5, 7.5, 5), metavar=("START", "STOP", "COUNT"),
                   help="jig x positions in mm (default -7.5 7.5 5)")
    g.add_argument("--grid-y", type=finite_float, nargs=3, default=(-5.0, 5.0, 4), metavar=("START", "STOP", "COUNT"),
                   help="jig y positions in mm (default -5 5 4)")
    g.add_argument("--background-mm", type=finite_float, nargs=2, default=(16.0, 0.0), metavar=("X", "Y"),
                   help="jig position with the ball out of view, for the no-contact frame (default 16 0)")
    g.add_argument("--method", choices=["lut", "poly", "mlp"], default="lut", help="model (default lut, Li 2014)")
    g.set_defaults(func=_gelsight)

    s = csub.add_parser("scale", help="scale tare and known-mass calibration",
                        description="Tare the empty scale, calibrate with a known mass, read it back, write "
                                    "the factor and the report. Off a terminal the session waits for a steady "
                                    "load instead of prompting.")
    common(s, "calib/scale.json")
    s.add_argument("--known-mass-g", type=float_in(0.0, 1e6, "g", low_open=True), required=True, help="the known mass in grams")
    s.add_argument("--samples", type=int_in(1, 100_000), default=20, help="readings averaged per step (default 20)")
    s.add_argument("--wait-timeout", type=TIMEOUT_S, default=60.0,
                   help="seconds to wait for the mass when not on a terminal (default 60)")
    s.set_defaults(func=_scale)

    r = csub.add_parser("gripper", help="gripper closed and open positions",
                        description="Drive the fingers into the closed and the open stop at a low effort; write "
                                    "closed_ticks, open_ticks and max_opening_m.")
    common(r, "calib/gripper.json")
    r.add_argument("--effort", type=EFFORT, default=0.2, help="fraction of the current limit (default 0.2)")
    r.add_argument("--max-opening-m", type=float_in(0.0, 1.0, "m", low_open=True), help="measured opening at the open stop in metres")
    r.add_argument("--closing-sign", type=any_int, choices=[-1, 1], default=-1, help="tick direction that closes")
    r.set_defaults(func=_gripper)

    f = csub.add_parser("fingervision", help="FingerVision marker baseline and proximity-vision histograms",
                        description="Average no-contact frames into the marker baseline and the background "
                                    "histogram; write <out>.npz + <out>.json.")
    common(f, "calib/fingervision")
    f.add_argument("--device", help="FingerVision camera table of the bench (default: the first)")
    f.add_argument("--frames", type=int_in(1, 100_000), default=10, help="no-contact frames to average (default 10)")
    f.set_defaults(func=_fingervision)


def session_guide(args: argparse.Namespace) -> Any:
    # Nobody needs to place a ball or a mass on a mock: the session scripts the simulated operator.
    return Guide(False if args.yes or args.mock else None, quiet=bool(args.json))


def connect_session_rig(args: argparse.Namespace, names: list[str], *, scene: str | None = None,
             connectors: dict[str, Callable[..., Any]] | None = None, bench_too: bool = False) -> Any:
    """Connect only ``names`` of the chosen bench (mocks: on ``scene``); ``connectors`` apply to
    mocks only unless ``bench_too``."""

    bench = bench_from_args(args, check_files=False)
    missing = [n for n in names if n not in bench.devices]
    if missing:
        raise ValueError(f"{bench.source} has no [{'], ['.join(missing)}] device(s) for this session")
    sub = Bench(name=bench.name, devices={n: bench.devices[n] for n in names}, source=bench.source,
                path=bench.path, text=bench.text, scene=scene if bench.is_mock else bench.scene,
                seed=args.seed if bench.is_mock else bench.seed)
    clock = VirtualClock() if bench.is_mock else None
    return connect_bench(sub, connectors=connectors if bench.is_mock or bench_too else None, clock=clock)


def _camera_name(args: argparse.Namespace, sensor: str) -> str:
    bench = bench_from_args(args, check_files=False)
    if args.mock:
        return "camera"
    cams = [n for n, c in bench.cameras.items() if c.sensor == sensor]
    name = args.device or (cams[0] if cams else None)
    if name is None or name not in bench.devices:
        raise ValueError(f"{bench.source}: no camera with sensor = \"{sensor}\" (tables: {', '.join(bench.devices)})")
    return name


def session_topics(kind: str, camera: str | None = None) -> dict[str, str]:
    """The topics (-> schema) a calibration session records and, with ``--live``, serves: advertised
    before the session starts, so a viewer subscribed with ``--live-wait`` sees it from its first message."""
    log = {"/log": "foxglove.Log"}
    if kind == "gelsight":
        return {camera_topic(camera or "camera", compressed=True): "foxglove.CompressedImage",
                "/tf": "foxglove.FrameTransforms", "/jig/pose": "tactile_rig.JigPose",
                "/command/jig": "tactile_rig.Command", **log}
    if kind == "fingervision":
        name = camera or "camera"
        return {camera_topic(name, compressed=True): "foxglove.CompressedImage",
                f"/perception/{name}": "tactile_rig.Perception"}
    if kind == "scale":
        return {"/scale/force": "tactile_rig.ScaleReading", "/command/scale": "tactile_rig.Command", **log}
    if kind == "gripper":
        return {"/gripper/joint_states": "foxglove.JointStates", "/state/gripper": "tactile_rig.GripperState",
                "/command/gripper": "tactile_rig.Command", **log}
    raise ValueError(f"session kind {kind!r}: expected gelsight, fingervision, scale or gripper")


def _run(args: argparse.Namespace, rig: Any, session: Callable[[Any, Any], Any], summary: Callable[[dict], str],
         topics: dict[str, str]) -> int:
    """Run ``session(rig, live)`` (``live``: the server ``--live`` asks for, advertising ``topics``, or
    None), always close the rig and the server, print the outcome (one line + files, or JSON)."""
    try:
        live = live_from_args(args, topics=topics)
    except BaseException:
        rig.close()
        raise
    try:
        outcome = session(rig, live)
    finally:
        rig.close()
        if live is not None:
            live.close()
    if args.json:
        print_json(outcome.as_dict())
    else:
        print(summary(outcome.report))
        print(f"calibration: {outcome.calibration_path}   report: {outcome.report_path}")
        if outcome.files.get("recording"):
            print(f"recording: {outcome.files['recording']}")
    return 0


def _gelsight(args: argparse.Namespace) -> int:
    plan = BallPressPlan(ball_radius_mm=args.ball_radius_mm, press_depth_mm=args.press_depth_mm,
                         grid_x_mm=(args.grid_x[0], args.grid_x[1], int(args.grid_x[2])),
                         grid_y_mm=(args.grid_y[0], args.grid_y[1], int(args.grid_y[2])),
                         background_mm=tuple(args.background_mm), method=args.method)
    cam = _camera_name(args, "gelsight")
    rig = connect_session_rig(args, ["jig", cam], scene=GELSIGHT_BALL_PRESS_SCENE,
                              connectors={"camera": sim_camera_connector("gelsight")})

    def session(rig: Any, live: Any) -> Any:
        prepare_jig(rig.jig)
        press_rig = DeviceJigRig(rig.jig, rig.devices[cam], rig.clock, world=rig.world, settle_s=0.05)
        return gelsight_session(press_rig, plan, float(rig.bench.devices[cam].mm_per_px_x), args.out,
                                guide=session_guide(args), force=args.force, bench=rig.bench, clock=rig.clock,
                                camera=cam, live=live)

    return _run(args, rig, session, lambda r: (
        f"GelSight: {r['presses']} presses, held-out normal error {r['heldout_mean_normal_deg']:.2f} deg, "
        f"height RMS {r['heldout_mean_height_rms_mm']:.4f} mm"), session_topics("gelsight", cam))


def _scale(args: argparse.Namespace) -> int:
    rig = connect_session_rig(args, ["scale"])
    place = _mock_mass_placer(rig) if rig.bench.is_mock else None
    return _run(args, rig, lambda rig, live: scale_session(
        rig.scale, args.known_mass_g, args.out, place_mass=place, guide=session_guide(args), samples=args.samples,
        wait_timeout_s=args.wait_timeout, force=args.force, bench=rig.bench, live=live), lambda r: (
        f"scale: {r['cal_factor_counts_per_g']:.5g} counts/g; {args.known_mass_g:g} g reads "
        f"{r['loaded_mean_g']:.3f} g ({r['verify_error_g']:+.3f} g), empty noise {r['empty_noise_g']:.3f} g"),
        session_topics("scale"))


def _mock_mass_placer(rig: Any) -> Callable[[float], None]:
    """On the mock bench: put a mass on the simulated load cell (the operator's hand, simulated)."""

    name = next(n for n in rig.mock_instances if n.endswith(".scale"))
    device, _ = device_from_url(f"rigsim://@{name}")
    if not isinstance(device, ScaleMock):
        raise TypeError(f"mock bench instance {name!r} is a {type(device).__name__}; expected the scale mock")
    cell = device.load_cell

    def place(grams: float) -> None:
        cell.set_force_source(None)
        cell.applied_force_n = float(grams) / 1000.0 * STANDARD_GRAVITY_MPS2

    return place


def _gripper(args: argparse.Namespace) -> int:
    def connect_gripper(cfg: Any, ctx: Any) -> Any:

        return DynamixelGripper(cfg.port, dxl_id=cfg.ids[0], protocol=cfg.protocol, baudrate=cfg.baud)

    rig = connect_session_rig(args, ["gripper"], connectors={"gripper": connect_gripper}, bench_too=True)
    return _run(args, rig, lambda rig, live: gripper_session(
        rig.gripper, args.out, effort=args.effort, max_opening_m=args.max_opening_m,
        closing_sign=args.closing_sign, guide=session_guide(args), force=args.force, bench=rig.bench,
        live=live), lambda r: (
        f"gripper: closed {r['closed_ticks']} ticks, open {r['open_ticks']} ticks "
        f"({r['span_ticks']} ticks for {r['max_opening_m']} m)"), session_topics("gripper"))


def _fingervision(args: argparse.Namespace) -> int:
    cam = _camera_name(args, "fingervision")
    rig = connect_session_rig(args, [cam], scene="fingervision_rest",
                              connectors={"camera": sim_camera_connector("fingervision")})
    return _run(args, rig, lambda rig, live: fingervision_session(rig.devices[cam], args.out, frames=args.frames,
                                                                  guide=session_guide(args), force=args.force,
                                                                  bench=rig.bench, live=live), lambda r: (
        f"FingerVision: {r['valid_markers']}/{r['markers']} stable markers, median jitter "
        f"{'n/a' if r['median_marker_jitter_px'] is None else format(r['median_marker_jitter_px'], '.3f')} px"),
        session_topics("fingervision", cam))
