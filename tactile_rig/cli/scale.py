"""``tactile-rig scale read|tare|calibrate``: the Arduino HX711 scale from the shell."""

from __future__ import annotations

import argparse

from tactile_rig.cli.args import any_int, finite_float
from tactile_rig.cli.common import print_json
from tactile_rig.drivers.scale import Scale


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("scale", help="the Arduino HX711 load-cell scale: read, tare, calibrate")
    ssub = p.add_subparsers(dest="scale_command", metavar="ACTION")

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--port", required=True,
                        help="device path or URL (/dev/serial/by-id/..., /dev/ttyACM0, rigsim://scale?boot_s=0.1)")
        sp.add_argument("--baud", type=any_int, default=57600, help="baud rate (default 57600)")
        sp.add_argument("--boot-timeout", type=finite_float, default=5.0,
                        help="seconds to wait for the banner after the reset on open (default 5)")
        sp.add_argument("--json", action="store_true", help="print JSON (one object per line)")

    rd = ssub.add_parser("read", help="print readings (grams, newtons, raw counts, sequence number)")
    common(rd)
    rd.add_argument("--count", type=any_int, default=10, help="number of readings (default 10)")
    rd.set_defaults(func=_read)

    ta = ssub.add_parser("tare", help="zero the scale with what is on it now")
    common(ta)
    ta.set_defaults(func=_tare)

    ca = ssub.add_parser("calibrate", help="calibrate with a known mass on the tared scale (stored in EEPROM)")
    common(ca)
    ca.add_argument("known_mass_g", type=finite_float, help="the known mass on the scale, grams")
    ca.set_defaults(func=_calibrate)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _open(args: argparse.Namespace):
    if args.boot_timeout <= 0:
        raise ValueError(f"--boot-timeout={args.boot_timeout!r} must be > 0 seconds")
    return Scale(args.port, baudrate=args.baud, boot_timeout_s=args.boot_timeout)


def _summary(scale) -> dict:
    return {"port": scale.port, "info": scale.info, "format": scale.format, "stats": scale.stats}


def _read(args: argparse.Namespace) -> int:
    if args.count < 1:
        raise ValueError(f"--count={args.count!r} must be at least 1")
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
