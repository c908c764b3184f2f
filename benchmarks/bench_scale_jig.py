"""Benchmark: scale readings delivered per second and jig status polls per second, over a pty;
the GRBL mock's motion time against GRBL 1.1h's own algorithms, and clean banners over 200 connects.

Each mock runs in a separate process (``tactile-rig mock serve``), as a real device would be on
the other side of a USB cable. Side by side with a baseline in the same run: a plain pyserial
``readline`` loop (scale) and a raw ``?``-then-readline loop (jig), to show what the drivers cost.

Jig timing (virtual time, in process): a 20-segment G1 polygon streamed in one burst and a homing
cycle, each against the time GRBL 1.1h takes by its planner (planner.c: junction deviation, reverse
and forward passes, trapezoids) and homing (limits.c: seek, pull-off, locate, pull-off, debounce),
computed here in closed form; the mock must be within 10 %. Connects: ``--connects N`` opens the
served jig N times as a slow client would (rate set up to 30 ms after the open) and counts banners
that are not byte-exact.

    python benchmarks/bench_scale_jig.py [--quick] [--jig-only] [--connects 200]

Prints a table; ``--save`` writes ``benchmarks/results/scale_jig.json``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json, saved_results  # noqa: E402  (benchmarks/ is the script's folder)

import serial

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tactile_rig.drivers.grbl import Jig  # noqa: E402
from tactile_rig.drivers.scale import Scale  # noqa: E402
from tactile_rig.mocks.grbl import GrblMock  # noqa: E402
from tactile_rig.testing.serve import serve_in_subprocess  # noqa: E402
from tests._slow_client import GRBL_BANNER, read_banner  # noqa: E402


def bench_scale(rate: int, seconds: float) -> dict:
    with serve_in_subprocess("scale", "--rate", str(rate), "--param", "boot_s=0.1") as info:
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
    with serve_in_subprocess("jig", "--param", "homing=0") as info:
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


# -- GRBL 1.1h's timing, in closed form ------------------------------------------------------------------
def _trapezoid_time(length: float, v0: float, v1: float, v_nom: float, a: float) -> float:
    """Seconds to cover ``length`` from ``v0`` to ``v1`` (mm/s), cruising at most ``v_nom``, at ``a``."""
    vp = min(v_nom, math.sqrt((2 * a * length + v0 * v0 + v1 * v1) / 2))
    vp = max(vp, v0, v1)
    cruise = length - (vp * vp - v0 * v0) / (2 * a) - (vp * vp - v1 * v1) / (2 * a)
    return (vp - v0) / a + (vp - v1) / a + max(cruise, 0.0) / vp


def grbl_path_time(points: list[tuple[float, ...]], feed_mm_per_min: float, rate_mm_per_min: list[float],
                   accel_mm_per_s2: list[float], junction_mm: float) -> float:
    """planner.c on a whole path known in advance: block limits along each direction, junction speeds
    v² = a·δ·sin(θ/2)/(1 − sin(θ/2)), a reverse pass from a stop and a forward pass from rest."""
    blocks = []
    for p, q in zip(points, points[1:]):
        d = [b - a for a, b in zip(p, q)]
        length = math.sqrt(sum(x * x for x in d))
        u = [x / length for x in d]
        acc = min(a / abs(c) for a, c in zip(accel_mm_per_s2, u) if c)
        v_nom = min(feed_mm_per_min, min(r / abs(c) for r, c in zip(rate_mm_per_min, u) if c)) / 60.0
        blocks.append({"L": length, "u": u, "a": acc, "v": v_nom})
    max_entry = [0.0]
    for prev, cur in zip(blocks, blocks[1:]):
        cos_t = -sum(x * y for x, y in zip(prev["u"], cur["u"]))
        if cos_t > 0.999999:
            vj2 = 0.0
        elif cos_t < -0.999999:
            vj2 = math.inf
        else:
            ju = [x - y for x, y in zip(cur["u"], prev["u"])]
            n = math.sqrt(sum(x * x for x in ju))
            aj = min(a / abs(x / n) for a, x in zip(accel_mm_per_s2, ju) if x)
            s = math.sqrt(0.5 * (1 - cos_t))
            vj2 = aj * junction_mm * s / (1 - s)
        max_entry.append(min(min(prev["v"], cur["v"]) ** 2, vj2))
    entry = list(max_entry) + [0.0]
    for k in range(len(blocks) - 1, -1, -1):  # reverse pass: each block can still stop in time
        entry[k] = min(max_entry[k], entry[k + 1] + 2 * blocks[k]["a"] * blocks[k]["L"])
    for k in range(len(blocks)):  # forward pass: each block starts where the previous one could reach
        entry[k + 1] = min(entry[k + 1], entry[k] + 2 * blocks[k]["a"] * blocks[k]["L"])
    return sum(_trapezoid_time(b["L"], math.sqrt(entry[k]), math.sqrt(entry[k + 1]), b["v"], b["a"])
               for k, b in enumerate(blocks))


def grbl_homing_time(dist_to_switch: dict[int, float], s: dict[int, float], cycles: list[tuple[int, ...]]) -> float:
    """limits.c limits_go_home for each cycle: seek at $25 until the last switch, pull-off ($27 in whole
    steps) at $25, locate at $24 over the pull-off, pull-off again, $26 ms after each move."""
    total = 0.0
    for axes in cycles:
        a = min(s[120 + i] for i in axes)
        seek, feed = s[25] / 60.0, s[24] / 60.0
        far = max(dist_to_switch[i] for i in axes)
        pull = min(round(s[27] * s[100 + i]) / s[100 + i] for i in axes)
        total += far / seek + seek / (2 * a)  # accelerate, then cruise until the last switch closes
        total += 2 * _trapezoid_time(pull, 0.0, 0.0, seek, a)
        total += pull / feed + feed / (2 * a)
        total += 4 * s[26] / 1000.0
    return total


def bench_jig_timing() -> dict:
    settings = GrblMock(homing=False).settings
    rates = [settings[110 + i] for i in range(3)]
    accels = [settings[120 + i] for i in range(3)]
    jd = settings[11]
    n, r, feed = 20, 4.0, 3000.0
    pts = [(-10.0 + r * math.cos(2 * math.pi * k / n), r * math.sin(2 * math.pi * k / n), 0.0) for k in range(n + 1)]
    burst = "".join(f"G1 X{x:.3f} Y{y:.3f}\n" for x, y, _ in pts[1:]).encode()
    rows = []
    for label, j in (("blended ($11=0.010)", jd), ("exact stop ($11=0)", 0.0)):
        mock = GrblMock(homing=False, settings={11: j})
        mock.open(0.0)
        mock.feed(f"G0 X{pts[0][0]:.3f} Y{pts[0][1]:.3f}\nG1 F{feed:.0f}\n".encode(), 0.0)
        mock.advance_to(30.0)
        mock.pop_ready(30.0)
        t = 30.0
        mock.feed(burst, t)
        sent_at = t
        while True:
            t += 0.0005
            mock.advance_to(t)
            if mock.state == "Idle" and not mock.planner.blocks and mock._job is None and not mock.rx:
                break
        mock_s = t - sent_at - len(burst) * 10 / mock.baud  # from the first byte's arrival
        grbl_s = grbl_path_time([p for p in pts], feed, rates, accels, j)
        rows.append({"what": f"20-segment polygon r=4 mm F{feed:.0f}, {label}", "mock_s": mock_s,
                     "grbl_1_1h_s": grbl_s, "ratio": mock_s / grbl_s})
    mock = GrblMock(work_origin="zero")
    t = 0.0
    mock.open(t)
    mock.feed(b"$H\n", 0.001)
    t = 0.001
    while b"ok" not in mock.pop_ready(t):
        t += 0.001
    mock_s = t - 0.001 - 4 * 10 / mock.baud
    s = mock.settings
    dist = {2: 180.0, 0: 20.0, 1: 20.0}  # from the stage's zero to the upper switches
    grbl_s = grbl_homing_time(dist, s, [(2,), (0, 1)])
    rows.append({"what": "homing cycle ($H) from the stage zero: Z(θ) then XY", "mock_s": mock_s,
                 "grbl_1_1h_s": grbl_s, "ratio": mock_s / grbl_s})
    return {"rows": rows, "within_10_percent": all(abs(r["ratio"] - 1.0) <= 0.10 for r in rows)}


def bench_jig_connects(n: int) -> dict:
    with serve_in_subprocess("jig", "--param", "homing=0") as info:
        t0 = time.monotonic()
        banners = [read_banner(info["port"], lag_s=0.03 * (i % 4) / 3) for i in range(n)]
        wall = time.monotonic() - t0
    bad = sum(b != GRBL_BANNER for b in banners)
    return {"connects": n, "garbled_or_missing": bad, "client_lags_s": [0.0, 0.01, 0.02, 0.03], "seconds": wall}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs (3 s each instead of 10 s)")
    ap.add_argument("--jig-only", action="store_true", help="skip the scale runs (results keep the last ones)")
    ap.add_argument("--connects", type=int, default=200, help="pty connects checked for a clean banner (200)")
    add_save_args(ap, "scale_jig.json")
    args = parse_args(ap)
    seconds = 3.0 if args.quick else 10.0
    results = (saved_results("scale_jig.json") or {}) if args.jig_only else {}
    if not args.jig_only:
        results["scale"] = [bench_scale(80, seconds), bench_scale(10, seconds)]
    results["jig"] = bench_jig(seconds)
    results["jig_timing"] = bench_jig_timing()
    results["jig_connects"] = bench_jig_connects(args.connects)
    with open("/proc/loadavg") as f:
        results["loadavg"] = f.read().split()[:3]
    save_json(args, results, indent=2)
    if "scale" in results:
        print(f"{'scale SPS':>10} {'driver/s':>9} {'pyserial/s':>11} {'dropped':>8} {'bad crc':>8} {'none lost':>10}")
        for r in results["scale"]:
            print(f"{r['configured_sps']:>10} {r['driver_readings_per_s']:>9.2f} {r['baseline_lines_per_s']:>11.2f} "
                  f"{r['dropped']:>8} {r['bad_checksum']:>8} {str(r['none_lost']):>10}")
    j = results["jig"]
    print(f"jig status polls/s: driver idle {j['driver_polls_per_s_idle']:.0f}, moving "
          f"{j['driver_polls_per_s_moving']:.0f}; raw pyserial baseline {j['baseline_raw_polls_per_s']:.0f}")
    for r in results["jig_timing"]["rows"]:
        print(f"{r['what']:<58} mock {r['mock_s']:7.3f} s   GRBL 1.1h {r['grbl_1_1h_s']:7.3f} s   x{r['ratio']:.3f}")
    c = results["jig_connects"]
    print(f"pty connects: {c['connects']}, banners garbled or missing: {c['garbled_or_missing']}")
    ok = results["jig_timing"]["within_10_percent"] and c["garbled_or_missing"] == 0
    if "scale" in results and not args.jig_only:
        ok = ok and all(abs(r["driver_readings_per_s"] - r["configured_sps"]) <= 1.0 and r["none_lost"]
                        for r in results["scale"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
