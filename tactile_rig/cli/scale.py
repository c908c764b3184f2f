"""``tactile-rig scale read|tare|calibrate``: the Arduino HX711 scale from the shell.

The scale is the bench's ``[scale]`` (``--bench FILE``, ``--mock`` or ``$TACTILE_RIG_BENCH``) or a bare
``--port`` (:mod:`tactile_rig.cli.device_args`).
"""

from __future__ import annotations

import argparse

from tactile_rig.cli.args import COUNT, float_in
from tactile_rig.cli.common import add_command_group, print_json
from tactile_rig.cli.device_args import add_device_arguments, device_target, open_device
from tactile_rig.drivers.scale import Scale
from tactile_rig.rig.bench import ScaleConfig


def register(sub: argparse._SubParsersAction) -> None:
    _, ssub = add_command_group(sub, "scale", help="the Arduino HX711 load-cell scale: read, tare, calibrate")

    def common(sp: argparse.ArgumentParser) -> None:
        add_device_arguments(sp, "scale", port_example="/dev/serial/by-id/..., /dev/ttyACM0, rigsim://scale?boot_s=0.1",
                             baud_default="57600, the sketch's")
        sp.add_argument("--boot-timeout", type=float_in(0.0, 600.0, "s", low_open=True), default=5.0,
                        help="seconds to wait for the banner after the reset on open (default 5)")

    rd = ssub.add_parser("read", help="print readings (grams, newtons, raw counts, sequence number)")
    common(rd)
    rd.add_argument("--count", type=COUNT, default=10, help="number of readings (default 10)")
    rd.set_defaults(func=_read)

    ta = ssub.add_parser("tare", help="zero the scale with what is on it now")
    common(ta)
    ta.set_defaults(func=_tare)

    ca = ssub.add_parser("calibrate", help="calibrate with a known mass on the tared scale (stored in EEPROM)")
    common(ca)
    ca.add_argument("known_mass_g", type=float_in(0.0, 1e6, "g", low_open=True),
                    help="the known mass on the scale, grams")
    ca.set_defaults(func=_calibrate)


def _open(args: argparse.Namespace):
    target = device_target(args, ScaleConfig)

    def build(cfg: ScaleConfig) -> Scale:  # named by its bench table, or by its port
        return Scale(cfg.port, baudrate=cfg.baud, boot_timeout_s=args.boot_timeout,
                     device=cfg.name if target.bench else None)

    return open_device(target, build)


def _summary(scale) -> dict:
    return {"port": scale.port, "info": scale.info, "format": scale.format, "stats": scale.stats}


def _read(args: argparse.Namespace) -> int:
    with _open(args) as scale:
        for _ in range(args.count):
            r = scale.read()
            if args.json:
                print_json({"seq": r.seq, "grams": r.grams, "newtons": r.newtons, "raw": r.raw,
                            "t_host_s": r.t_host_s, "saturated": r.saturated})
            else:
                raw = "" if r.raw is None else f"  raw {r.raw:>9d}"
                print(f"#{r.seq:<6} {r.grams:>11.3f} g  {r.newtons:>9.4f} N{raw}{'  SATURATED' if r.saturated else ''}")
        s = scale.stats
        if args.json:
            print_json(_summary(scale))
        else:
            print(f"{s.readings} readings, {s.dropped} dropped, {s.bad_checksum} bad checksums, {s.resets} resets")
    return 0


def _tare(args: argparse.Namespace) -> int:
    with _open(args) as scale:
        scale.tare()
        scale.poll()  # readings from before the confirmation are not tared
        r = scale.read()
        if args.json:
            print_json({"tared": True, "grams": r.grams, **_summary(scale)})
        else:
            print(f"tared; now reading {r.grams:.3f} g")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    with _open(args) as scale:
        factor = scale.calibrate(args.known_mass_g)
        if args.json:
            print_json({"cal_factor": factor, "known_mass_g": args.known_mass_g, **_summary(scale)})
        else:
            print(f"calibration factor {factor:.3f} counts/g stored in the Arduino's EEPROM")
    return 0
