"""Benchmark: scale readings delivered per second and jig status polls per second, over a pty.

Each mock runs in a separate process (``tactile-rig mock serve``), as a real device would be on
the other side of a USB cable. Side by side with a baseline in the same run: a plain pyserial
``readline`` loop (scale) and a raw ``?``-then-readline loop (jig), to show what the drivers cost.

    python benchmarks/bench_scale_jig.py [--quick]

Writes ``benchmarks/results/scale_jig.json`` and prints a table.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import serial

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tactile_rig.drivers.jig import Jig  # noqa: E402
from tactile_rig.drivers.scale import Scale  # noqa: E402


@contextmanager
def served(*args: str):
    proc = subprocess.Popen([sys.executable, "-m", "tactile_rig.cli", "mock", "serve", *args],
                            stdout=subprocess.PIPE, text=True)
    try:
        yield json.loads(proc.stdout.readline())
    finally:
        proc.terminate()
        proc.wait(5)
        proc.stdout.close()


def bench_scale(rate: int, seconds: float) -> dict:
    with served("scale", "--rate", str(rate), "--param", "boot_s=0.1") as info:
        # Baseline: count whole lines with a plain pyserial reader.
        with serial.Serial(info["port"], 57600, timeout=1.0) as ser:
            ser.readline()  # the banner or a partial first line
            t0 = time.monotonic()
            n_lines = 0
            while time.monotonic() - t0 < seconds:
                if ser.readline().endswith(b"\n"):
                    n_lines += 1
            base_rate = n_lines / (time.monotonic() - t0)
        time.sleep(0.2)  # let the server see the port close, so the next open resets the sketch
        with Scale(info["port"], boot_timeout_s=3.0) as scale:
            first = scale.read(1.0)
            t0 = time.monotonic()
            n = 0
            last = first
            while time.monotonic() - t0 < seconds:
                last = scale.read(1.0)
                n += 1
            elapsed = time.monotonic() - t0
            stats = scale.stats
            seq_span = (last.seq - first.seq) % 65536
    return {"configured_sps": rate, "driver_readings_per_s": n / elapsed, "baseline_lines_per_s": base_rate,
            "readings": n, "dropped": stats.dropped, "bad_checksum": stats.bad_checksum, "resets": stats.resets,
            "seq_span": seq_span, "none_lost": stats.dropped == 0 and seq_span == n, "seconds": seconds}


def bench_jig(seconds: float) -> dict:
    with served("jig", "--param", "homing=0") as info:
        with serial.Serial(info["port"], 115200, timeout=1.0) as ser:
            time.sleep(0.1)
            ser.reset_input_buffer()
            t0 = time.monotonic()
            n_raw = 0
            while time.monotonic() - t0 < seconds:
                ser.write(b"?")
                if ser.readline().startswith(b"<"):
                    n_raw += 1
            raw_rate = n_raw / (time.monotonic() - t0)
        time.sleep(0.2)
        with Jig(info["port"]) as jig:
            t0 = time.monotonic()
            n = 0
            while time.monotonic() - t0 < seconds:
                jig.status()
                n += 1
            idle_rate = n / (time.monotonic() - t0)
            jig.move_to(15.0, 0.0, 90.0, feed_mm_per_min=600.0)
            t0 = time.monotonic()
            m = 0
            while time.monotonic() - t0 < min(seconds, 2.0):
                jig.status()
                m += 1
            moving_rate = m / (time.monotonic() - t0)
    return {"driver_polls_per_s_idle": idle_rate, "driver_polls_per_s_moving": moving_rate,
            "baseline_raw_polls_per_s": raw_rate, "seconds": seconds}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs (3 s each instead of 10 s)")
    args = ap.parse_args()
    seconds = 3.0 if args.quick else 10.0
    results = {"scale": [bench_scale(80, seconds), bench_scale(10, seconds)], "jig": bench_jig(seconds)}
    out = ROOT / "benchmarks" / "results" / "scale_jig.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"{'scale SPS':>10} {'driver/s':>9} {'pyserial/s':>11} {'dropped':>8} {'bad crc':>8} {'none lost':>10}")
    for r in results["scale"]:
        print(f"{r['configured_sps']:>10} {r['driver_readings_per_s']:>9.2f} {r['baseline_lines_per_s']:>11.2f} "
              f"{r['dropped']:>8} {r['bad_checksum']:>8} {str(r['none_lost']):>10}")
    j = results["jig"]
    print(f"jig status polls/s: driver idle {j['driver_polls_per_s_idle']:.0f}, moving "
          f"{j['driver_polls_per_s_moving']:.0f}; raw pyserial baseline {j['baseline_raw_polls_per_s']:.0f}")
    print(f"wrote {out}")
    ok = all(abs(r["driver_readings_per_s"] - r["configured_sps"]) <= 1.0 and r["none_lost"] for r in results["scale"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
