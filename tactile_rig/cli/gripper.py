"""``tactile-rig gripper state|go|calibrate|reboot``: the MX-64 gripper from the shell.

The gripper is the bench's ``[gripper]`` (``--bench FILE``, ``--mock`` or ``$TACTILE_RIG_BENCH``: its
IDs, protocol, baud, latency timer and calibration), or a bare ``--port`` with ``--id``/``--protocol``
(:mod:`tactile_rig.cli.device_args`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from tactile_rig.cli.args import EFFORT, TIMEOUT_S, any_int, finite_float, float_in, int_in, output_file
from tactile_rig.cli.common import EXIT_FAILED, EXIT_FAULT, EXIT_OK, add_command_group, print_json
from tactile_rig.cli.device_args import DeviceTarget, add_device_arguments, device_target, open_device
from tactile_rig.control.protocols import GripperOutcome
from tactile_rig.devices.dynamixel.error_codes import decode_hardware_error
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper
from tactile_rig.rig.bench import GripperConfig
from tactile_rig.rig.loaders import load_gripper_calibration

OPENING_M = float_in(0.0, 1.0, "m", low_open=True)  # a gripper's opening: more than zero, at most a metre


def register(sub: argparse._SubParsersAction) -> None:
    _, gsub = add_command_group(sub, "gripper", help="the Dynamixel MX-64 gripper: state, go, calibrate, reboot")

    def common(sp: argparse.ArgumentParser) -> None:
        add_device_arguments(sp, "gripper", port_example="/dev/ttyUSB0, rigsim://dynamixel",
                             baud_default="1000000 for protocol 2, 57600 for 1")
        sp.add_argument("--id", dest="dxl_id", type=int_in(0, 252), help="servo ID (default: the bench's, else 1)")
        sp.add_argument("--protocol", type=any_int, choices=[1, 2],
                        help="Dynamixel protocol (default: the bench's, else 2)")
        sp.add_argument("--calibration", type=Path,
                        help="JSON file of closed_ticks/open_ticks/max_opening_m (default: the bench's)")

    st = gsub.add_parser("state", help="print position, velocity, current, temperature, error bits")
    common(st)
    st.set_defaults(func=_state)

    go = gsub.add_parser("go", help="activate and move to an opening with an effort cap (torque stays on)",
                         description="Outcome: reached (within the position tolerance and slower than 2 mm/s: "
                                     "settled), stalled (on an object at the effort cap), timeout or fault.")
    common(go)
    go.add_argument("position", type=finite_float, help="opening in metres (or 0-1 with --normalized)")
    go.add_argument("--effort", type=EFFORT, default=0.3, help="fraction of the current limit, (0, 1] (default 0.3)")
    go.add_argument("--normalized", action="store_true", help="position is 0 (closed) - 1 (open)")
    go.add_argument("--timeout", type=TIMEOUT_S, default=5.0, help="seconds to wait for the move (default 5)")
    go.add_argument("--no-wait", action="store_true", help="start the move and return")
    go.set_defaults(func=_go)

    cal = gsub.add_parser("calibrate", help="find the closed and open stops (moves the fingers!)")
    common(cal)
    cal.add_argument("--effort", type=EFFORT, default=0.2, help="effort used to find the stops (default 0.2)")
    cal.add_argument("--max-opening-m", type=OPENING_M, help="measured opening at the open stop, metres")
    cal.add_argument("--closing-sign", type=any_int, choices=[-1, 1], default=-1, help="tick direction that closes")
    cal.add_argument("--save", type=lambda t: Path(output_file(".json")(t)),
                     help="write the calibration to this JSON file (its folder must exist)")
    cal.set_defaults(func=_calibrate)

    rb = gsub.add_parser("reboot", help="reboot the servo (clears a latched overload/overheating error)")
    common(rb)
    rb.set_defaults(func=_reboot)


def _target(args: argparse.Namespace) -> DeviceTarget[GripperConfig]:
    """The gripper: the bench's table (or a bare port) with the command line's ID, protocol and calibration."""
    return device_target(args, GripperConfig, ids=None if args.dxl_id is None else [args.dxl_id],
                         protocol=args.protocol, calibration=args.calibration)


def _open(args: argparse.Namespace, **kw: Any):
    target = _target(args)
    cal = load_gripper_calibration(target.config.calibration) if target.config.calibration else None
    # A bare port without --baud: the driver's default for the protocol (that of `mock serve dynamixel`).
    baud = None if target.bench is None and not args.baud else target.config.baud

    def build(cfg: GripperConfig) -> DynamixelGripper:
        return DynamixelGripper(cfg.port, dxl_id=cfg.ids[0], protocol=cfg.protocol, baudrate=baud, calibration=cal,
                                latency_timer_ms=cfg.latency_timer_ms, retries=cfg.retries, **kw)

    return open_device(target, build)


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
        return EXIT_FAULT
    return EXIT_OK if outcome in (GripperOutcome.REACHED, GripperOutcome.STALLED, GripperOutcome.MOVING) else EXIT_FAILED


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
