"""``tactile-rig jig status|home|move|unlock``: the GRBL x-y-θ jig from the shell.

The jig is the bench's ``[jig]`` (``--bench FILE``, ``--mock`` or ``$TACTILE_RIG_BENCH``), or a bare
``--port``. Either way every target is checked against the travel limits before anything is sent
(the bench's ``x_limits_mm``, ``y_limits_mm``, ``theta_limits_deg``; with a bare port the defaults of
:class:`~tactile_rig.rig.bench.JigConfig`: ±20 mm, θ ±180°): ``jig move --x 50`` is a LimitError
(exit 2) naming the axis, the value and the limit, never a hard-limit alarm.
"""

from __future__ import annotations

import argparse
import os

from tactile_rig.cli.args import any_int, finite_float
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import print_json
from tactile_rig.drivers.grbl import Jig, read_window
from tactile_rig.rig.bench import JigConfig


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("jig", help="the GRBL x-y-theta jig: status, home, move, unlock")
    jsub = p.add_subparsers(dest="jig_command", metavar="ACTION")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--port", help="device path or URL (/dev/ttyUSB0, rigsim://jig); default: the bench's [jig]")
        add_bench_arguments(sp)
        sp.add_argument("--baud", type=any_int, help="baud rate (default: the bench's, else 115200)")
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
    mv.add_argument("--home", action="store_true", help="run the homing cycle ($H) first")
    mv.set_defaults(func=_move)

    un = jsub.add_parser("unlock", help="clear the alarm lock ($X) without homing")
    common(un)
    un.set_defaults(func=_unlock)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _config(args: argparse.Namespace) -> tuple[JigConfig, str]:
    """The jig's config (port, baud, limits) and where its limits come from."""
    if args.mock or args.bench or os.environ.get("TACTILE_RIG_BENCH"):
        bench = bench_from_args(args, check_files=False)
        cfg = bench.device("jig")
        if not isinstance(cfg, JigConfig):
            raise ValueError(f"{bench.source}: [jig] is not a jig table")
        source = bench.source
    else:
        if not args.port:
            raise ValueError("jig: pass --port DEVICE, or --bench FILE / --mock to use the bench's [jig]")
        cfg, source = JigConfig(name="jig", port=args.port), "the default jig limits (no bench given)"
    if args.port:
        cfg = JigConfig(**{**vars(cfg), "port": args.port})
    if args.baud:
        cfg = JigConfig(**{**vars(cfg), "baud": args.baud})
    return cfg, source


def _open(args: argparse.Namespace):
    cfg, _ = _config(args)
    return Jig(cfg.port, baudrate=cfg.baud, theta_axis=args.theta_axis, x_range_mm=cfg.x_limits_mm,
               y_range_mm=cfg.y_limits_mm, theta_range_deg=cfg.theta_limits_deg, device=cfg.name)


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
    cfg, source = _config(args)
    # Before the port is even opened: a target outside the limits never reaches the firmware.
    cfg.check_target(x_mm=args.x_mm, y_mm=args.y_mm, theta_deg=args.theta_deg, source=source)
    with _open(args) as jig:
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
