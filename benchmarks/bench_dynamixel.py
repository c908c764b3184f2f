"""Position reads per second through the real dynamixel-sdk against the MX-64 mock.

Runs, side by side in one process:

* ``pty timing``: ``tactile-rig mock serve dynamixel`` in a separate process (1 Mbps, Return Delay
  Time 0, wire timing on); per-transaction latency against the wire time (29 bytes = 0.29 ms).
* ``pty no-timing``: the same server with ``--no-timing``.
* ``baseline pty``: a canned responder (a separate process answering every packet with one fixed,
  precomputed status packet): the floor of the pty + SDK round trip, with no firmware at all.
* ``in-process``: ``rigsim://dynamixel`` on a virtual clock, timing on and off.

Usage: ``python benchmarks/bench_dynamixel.py [--quick] [--save | --out PATH]``; ``--save`` writes
``benchmarks/results/dynamixel.json`` (full runs only).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import dynamixel_sdk as sdk

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tactile_rig.testing.serve import serve_in_subprocess  # noqa: E402

WIRE_S = 29 * 10 / 1_000_000  # 14-byte read + 15-byte status at 1 Mbps

_CANNED = r"""
import os, pty, tty, select, sys
sys.path.insert(0, %(root)r)
from tactile_rig.mocks.dynamixel.codec import encode_p2_status
master, slave = pty.openpty(); tty.setraw(master)
print(os.ttyname(slave), flush=True)
reply = encode_p2_status(1, 0, (2048).to_bytes(4, "little"))
buf = b""
while True:
    select.select([master], [], [])
    buf += os.read(master, 4096)
    while len(buf) >= 14:  # every instruction of the benchmark is a 14-byte read
        buf = buf[14:]
        os.write(master, reply)
"""


def _measure(port_name: str, n: int, *, url: bool = False) -> tuple[list[float], int]:
    from tactile_rig.drivers.dynamixel.bus import UrlPortHandler

    port = UrlPortHandler(port_name) if url else sdk.PortHandler(port_name)
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = sdk.PacketHandler(2.0)
    for _ in range(20):  # warm up
        ph.read4ByteTxRx(port, 1, 132)
    times, failures = [], 0
    for _ in range(n):
        t0 = time.perf_counter()
        _, res, err = ph.read4ByteTxRx(port, 1, 132)
        dt = time.perf_counter() - t0
        if res == sdk.COMM_SUCCESS:
            times.append(dt)
        else:  # a starved server on a loaded machine: counted, not timed
            failures += 1
    port.closePort()
    return times, failures


def _summary(name: str, measured: tuple[list[float], int]) -> dict:
    times, failures = measured
    s = sorted(times)
    pct = lambda q: s[min(len(s) - 1, int(q * len(s)))] * 1e3  # noqa: E731
    return {
        "case": name,
        "n": len(s),
        "failures": failures,
        "reads_per_s": len(s) / sum(s),
        "reads_per_s_at_median": 1.0 / statistics.median(s),  # robust to a loaded machine's tail
        "median_ms": statistics.median(s) * 1e3,
        "min_ms": s[0] * 1e3,
        "p10_ms": pct(0.10),
        "p90_ms": pct(0.90),
        "median_over_wire_ms": statistics.median(s) * 1e3 - WIRE_S * 1e3,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer transactions")
    add_save_args(ap, "dynamixel.json")
    args = parse_args(ap)
    n = 500 if args.quick else 5000
    rows = []
    for name, extra in (("pty timing (1 Mbps, RDT 0)", []), ("pty no-timing", ["--no-timing"])):
        with serve_in_subprocess("dynamixel", "--param", "return_delay_us=0", *extra) as info:
            rows.append(_summary(name, _measure(info["port"], n)))
    root = str(Path(__file__).resolve().parents[1])
    proc = subprocess.Popen([sys.executable, "-c", _CANNED % {"root": root}], stdout=subprocess.PIPE, text=True)
    try:
        rows.append(_summary("baseline pty: canned responder", _measure(proc.stdout.readline().strip(), n)))
    finally:
        proc.terminate()
        proc.wait()
    for name, q in (("in-process timing", "timing=1"), ("in-process no-timing", "timing=0")):
        rows.append(_summary(name, _measure(f"rigsim://dynamixel?return_delay_us=0&{q}", n, url=True)))

    print(f"{'case':<34} {'reads/s':>9} {'1/median':>9} {'median ms':>10} {'min ms':>8} {'p10 ms':>8} {'p90 ms':>8} "
          f"{'med-wire':>9} {'fails':>5}")
    for r in rows:
        print(f"{r['case']:<34} {r['reads_per_s']:>9.0f} {r['reads_per_s_at_median']:>9.0f} {r['median_ms']:>10.3f} {r['min_ms']:>8.3f} "
              f"{r['p10_ms']:>8.3f} {r['p90_ms']:>8.3f} {r['median_over_wire_ms']:>9.3f} {r['failures']:>5}")
    print(f"load average while running: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(f"wire time of one read: {WIRE_S * 1e3:.2f} ms")
    save_json(args, {"wire_ms": WIRE_S * 1e3, "quick": args.quick, "loadavg_1min": os.getloadavg()[0],
                     "cpus": os.cpu_count(), "rows": rows}, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
