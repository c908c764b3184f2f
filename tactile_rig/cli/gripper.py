"""``tactile-rig gripper state|go|calibrate|reboot``: the MX-64 gripper from the shell."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tactile_rig.cli.args import any_int, finite_float, output_file
from tactile_rig.cli.common import print_json
from tactile_rig.control.protocols import GripperOutcome
from tactile_rig.devices.dynamixel.error_codes import decode_hardware_error
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper
from tactile_rig.rig.loaders import load_gripper_calibration


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("gripper", help="the Dynamixel MX-64 gripper: state, go, calibrate, reboot")
    gsub = p.add_subparsers(dest="gripper_command", metavar="ACTION")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--port", required=True, help="device path or URL (e.g. /dev/ttyUSB0, rigsim://dynamixel)")
        sp.add_argument("--id", dest="dxl_id", type=any_int, default=1, help="servo ID (default 1)")
        sp.add_argument("--protocol", type=any_int, choices=[1, 2], default=2, help="Dynamixel protocol (default 2)")
        sp.add_argument("--baud", type=any_int, help="baud rate (default 1000000 for P2, 57600 for P1)")
        sp.add_argument("--calibration", type=Path, help="JSON file of closed_ticks/open_ticks/max_opening_m")
        sp.add_argument("--json", action="store_true", help="print JSON")

    st = gsub.add_parser("state", help="print position, velocity, current, temperature, error bits")
    common(st)
    st.set_defaults(func=_state)

    go = gsub.add_parser("go", help="activate and move to an opening with an effort cap (torque stays on)",
                         description="Outcome: reached (within the position tolerance and slower than 2 mm/s: "
                                     "settled), stalled (on an object at the effort cap), timeout or fault.")
    common(go)
    go.add_argument("position", type=finite_float, help="opening in metres (or 0-1 with --normalized)")
    go.add_argument("--effort", type=finite_float, default=0.3, help="fraction of the current limit, 0-1 (default 0.3)")
    go.add_argument("--normalized", action="store_true", help="position is 0 (closed) - 1 (open)")
    go.add_argument("--timeout", type=finite_float, default=5.0, help="seconds to wait for the move (default 5)")
    go.add_argument("--no-wait", action="store_true", help="start the move and return")
    go.set_defaults(func=_go)

    cal = gsub.add_parser("calibrate", help="find the closed and open stops (moves the fingers!)")
    common(cal)
    cal.add_argument("--effort", type=finite_float, default=0.2, help="effort used to find the stops (default 0.2)")
    cal.add_argument("--max-opening-m", type=finite_float, help="measured opening at the open stop, metres")
    cal.add_argument("--closing-sign", type=any_int, choices=[-1, 1], default=-1, help="tick direction that closes")
    cal.add_argument("--save", type=lambda t: Path(output_file(".json")(t)),
                     help="write the calibration to this JSON file (its folder must exist)")
    cal.set_defaults(func=_calibrate)

    rb = gsub.add_parser("reboot", help="reboot the servo (clears a latched overload/overheating error)")
    common(rb)
    rb.set_defaults(func=_reboot)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _open(args: argparse.Namespace, **kw):
    cal = None
    if args.calibration:
        cal = load_gripper_calibration(args.calibration)
    return DynamixelGripper(args.port, dxl_id=args.dxl_id, protocol=args.protocol, baudrate=args.baud,
                            calibration=cal, **kw)


def _print_state(args: argparse.Namespace, state, extra: dict | None = None) -> None:
    if args.json:
        d = {"state": state, "hardware_errors": decode_hardware_error(state.hardware_error)}
        d.update(extra or {})
        print_json(d)
        return
    for k, v in (extra or {}).items():
        print(f"{k:<16} {v}")
    print(f"opening_m        {state.opening_m:.4f}  ({state.opening_frac:.3f} of the calibrated range)")
    print(f"velocity_mps     {state.velocity_mps:+.4f}")
    print(f"current_a        {state.current_a:+.3f}  (effort {state.effort_frac:.2f})")
    print(f"temperature_c    {state.temperature_c:.0f}")
    errs = decode_hardware_error(state.hardware_error)
    print(f"hardware_error   0x{state.hardware_error:02x} {', '.join(errs) or 'none'}")
    print(f"active           {'yes' if state.active else 'no'}")


def _state(args: argparse.Namespace) -> int:
    with _open(args) as g:
        _print_state(args, g.state(), {"lifecycle": g.lifecycle.value})
    return 0


def _go(args: argparse.Namespace) -> int:
    with _open(args) as g:
        g.activate(args.effort)
        go = g.gripper_go_frac if args.normalized else g.gripper_go
        outcome = go(args.position, args.effort, blocking=not args.no_wait, timeout_s=args.timeout)
        _print_state(args, g.state(), {"outcome": outcome.value})
    if outcome == GripperOutcome.FAULT:
        return 3
    return 0 if outcome in (GripperOutcome.REACHED, GripperOutcome.STALLED, GripperOutcome.MOVING) else 1


def _calibrate(args: argparse.Namespace) -> int:
    with _open(args) as g:
        cal = g.calibrate(effort=args.effort, max_opening_m=args.max_opening_m, closing_sign=args.closing_sign)
    if args.save:
        args.save.write_text(json.dumps(cal.to_dict(), indent=2) + "\n")
    if args.json:
        print_json(cal.to_dict())
    else:
        print(f"closed_ticks {cal.closed_ticks}  open_ticks {cal.open_ticks}  max_opening_m {cal.max_opening_m}")
    return 0


def _reboot(args: argparse.Namespace) -> int:
    with _open(args) as g:
        g.reboot()
        _print_state(args, g.state(), {"lifecycle": g.lifecycle.value})
    return 0
