"""``tactile-rig jig status|home|move|unlock``: the GRBL x-y-θ jig from the shell."""

from __future__ import annotations

import argparse

from tactile_rig.cli.args import any_int, finite_float
from tactile_rig.cli.common import print_json
from tactile_rig.drivers.jig import Jig


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("jig", help="the GRBL x-y-theta jig: status, home, move, unlock")
    jsub = p.add_subparsers(dest="jig_command", metavar="ACTION")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--port", required=True, help="device path or URL (/dev/ttyUSB0, rigsim://jig)")
        sp.add_argument("--baud", type=any_int, default=115200, help="baud rate (default 115200)")
        sp.add_argument("--theta-axis", default="Z", choices=["Z", "A"],
                        help="GRBL channel that drives theta: Z on stock GRBL 1.1, A on grblHAL (default Z)")
        sp.add_argument("--json", action="store_true", help="print JSON")

    st = jsub.add_parser("status", help="print the parsed status report")
    common(st)
    st.set_defaults(func=_status)

    ho = jsub.add_parser("home", help="run the homing cycle ($H)")
    common(ho)
    ho.add_argument("--timeout", type=finite_float, default=60.0, help="seconds allowed for homing (default 60)")
    ho.set_defaults(func=_home)

    mv = jsub.add_parser("move", help="move to a pose in work coordinates and wait until Idle")
    common(mv)
    mv.add_argument("--x", dest="x_mm", type=finite_float, help="x in mm")
    mv.add_argument("--y", dest="y_mm", type=finite_float, help="y in mm")
    mv.add_argument("--theta", dest="theta_deg", type=finite_float, help="theta in degrees")
    mv.add_argument("--feed", type=finite_float, help="feed in mm/min (default: rapid, each axis at its max rate)")
    mv.add_argument("--timeout", type=finite_float, default=60.0, help="seconds allowed for the move (default 60)")
    mv.add_argument("--unlock", action="store_true", help="clear an alarm lock ($X) first")
    mv.set_defaults(func=_move)

    un = jsub.add_parser("unlock", help="clear the alarm lock ($X) without homing")
    common(un)
    un.set_defaults(func=_unlock)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _open(args: argparse.Namespace):
    return Jig(args.port, baudrate=args.baud, theta_axis=args.theta_axis)


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
    with _open(args) as jig:
        if args.unlock:
            jig.unlock()
        jig.move_to(args.x_mm, args.y_mm, args.theta_deg, args.feed, wait=True, timeout_s=args.timeout)
        _report(args, jig, jig.status())
    return 0


def _unlock(args: argparse.Namespace) -> int:
    with _open(args) as jig:
        jig.unlock()
        _report(args, jig, jig.status(), unlocked=True)
    return 0
