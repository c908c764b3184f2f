"""``tactile-rig jig status|home|move|unlock``: the GRBL x-y-θ jig from the shell.

The jig is the bench's ``[jig]`` (``--bench FILE``, ``--mock`` or ``$TACTILE_RIG_BENCH``), or a bare
``--port`` (:mod:`tactile_rig.cli.device_args`). Either way every target is checked against the
travel limits before anything is sent (the bench's ``x_limits_mm``, ``y_limits_mm``,
``theta_limits_deg``; with a bare port the defaults of :class:`~tactile_rig.rig.bench.JigConfig`:
±20 mm, θ ±180°): ``jig move --x 50`` is a LimitError (exit 2) naming the axis, the value and the
limit, never a hard-limit alarm.
"""

from __future__ import annotations

import argparse

from tactile_rig.cli.args import TIMEOUT_S, finite_float, float_in
from tactile_rig.cli.common import add_command_group, print_json
from tactile_rig.cli.device_args import DeviceTarget, add_device_arguments, device_target, open_device
from tactile_rig.drivers.grbl import Jig, read_window
from tactile_rig.rig.bench import JigConfig


def register(sub: argparse._SubParsersAction) -> None:
    _, jsub = add_command_group(sub, "jig", help="the GRBL x-y-theta jig: status, home, move, unlock")

    def common(sp: argparse.ArgumentParser) -> None:
        add_device_arguments(sp, "jig", port_example="/dev/ttyUSB0, rigsim://jig", baud_default="115200")
        sp.add_argument("--theta-axis", default="Z", choices=["Z", "A"],
                        help="GRBL channel that drives theta: Z on stock GRBL 1.1, A on grblHAL (default Z)")

    st = jsub.add_parser("status", help="print the parsed status report")
    common(st)
    st.set_defaults(func=_status)

    ho = jsub.add_parser("home", help="run the homing cycle ($H)")
    common(ho)
    ho.add_argument("--timeout", type=TIMEOUT_S, default=60.0, help="seconds allowed for homing (default 60)")
    ho.set_defaults(func=_home)

    mv = jsub.add_parser("move", help="move to a pose in work coordinates and wait until Idle")
    common(mv)
    mv.add_argument("--x", dest="x_mm", type=finite_float, help="x in mm")
    mv.add_argument("--y", dest="y_mm", type=finite_float, help="y in mm")
    mv.add_argument("--theta", dest="theta_deg", type=finite_float, help="theta in degrees")
    mv.add_argument("--feed", type=float_in(0.0, 1e6, "mm/min", low_open=True),
                    help="feed in mm/min (default: rapid, each axis at its max rate)")
    mv.add_argument("--timeout", type=TIMEOUT_S, default=60.0, help="seconds allowed for the move (default 60)")
    mv.add_argument("--unlock", action="store_true", help="clear an alarm lock ($X) first")
    mv.add_argument("--home", action="store_true", help="run the homing cycle ($H) first")
    mv.set_defaults(func=_move)

    un = jsub.add_parser("unlock", help="clear the alarm lock ($X) without homing")
    common(un)
    un.set_defaults(func=_unlock)


def _open(args: argparse.Namespace, device: DeviceTarget[JigConfig] | None = None):
    target = device or device_target(args, JigConfig)

    def build(cfg: JigConfig) -> Jig:  # named by its bench table, or by its port
        return Jig(cfg.port, baudrate=cfg.baud, theta_axis=args.theta_axis, x_range_mm=cfg.x_limits_mm,
                   y_range_mm=cfg.y_limits_mm, theta_range_deg=cfg.theta_limits_deg,
                   device=cfg.name if target.bench else None)

    return open_device(target, build)


def _report(args: argparse.Namespace, jig, st, **extra) -> None:
    pose = jig.pose_from_status(st)
    if args.json:
        print_json({"state": st.state, "substate": st.substate, "x_mm": pose.x_mm, "y_mm": pose.y_mm,
                    "theta_deg": pose.theta_deg, "mpos": st.mpos, "wpos": st.wpos, "feed_mm_per_min": st.feed_mm_per_min,
                    "pins": st.pins, "alarm_on_boot": jig.alarm_on_boot, "raw": st.raw, **extra})
    else:
        sub = f":{st.substate}" if st.substate is not None else ""
        print(f"{st.state}{sub}  x {pose.x_mm:.3f} mm  y {pose.y_mm:.3f} mm  theta {pose.theta_deg:.3f} deg"
              + (f"  pins {st.pins}" if st.pins else ""))
        for k, v in extra.items():
            print(f"{k}: {v}")


def _status(args: argparse.Namespace) -> int:
    with _open(args) as jig:
        _report(args, jig, jig.status())
    return 0


def _home(args: argparse.Namespace) -> int:
    with _open(args) as jig:
        jig.home(timeout_s=args.timeout)
        _report(args, jig, jig.wait_idle(5.0), homed=True)
    return 0


def _move(args: argparse.Namespace) -> int:
    if args.x_mm is None and args.y_mm is None and args.theta_deg is None:
        raise ValueError("jig move needs at least one of --x, --y, --theta")
    device = device_target(args, JigConfig)
    # Before the port is even opened: a target outside the limits never reaches the firmware.
    device.config.check_target(x_mm=args.x_mm, y_mm=args.y_mm, theta_deg=args.theta_deg, source=device.source)
    with _open(args, device) as jig:
        if args.home:
            jig.home(timeout_s=args.timeout)
        elif args.unlock:
            jig.unlock()
        # The firmware's own soft limits, in work coordinates: a LimitError here, not an ALARM:2 lock.
        window = read_window(jig)
        target = {"x_mm": args.x_mm, "y_mm": args.y_mm, "theta_deg": args.theta_deg}
        if window is not None:
            target = window.fit(**target)
        jig.move_to(target["x_mm"], target["y_mm"], target["theta_deg"], args.feed, wait=True,
                    timeout_s=args.timeout)
        _report(args, jig, jig.status())
    return 0


def _unlock(args: argparse.Namespace) -> int:
    with _open(args) as jig:
        jig.unlock()
        _report(args, jig, jig.status(), unlocked=True)
    return 0
