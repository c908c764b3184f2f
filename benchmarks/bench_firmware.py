"""Benchmark: the scale sketch on the simulated board and the Python mock, timing side by side.

Wall clock, over ptys: each device in its own process (``tactile-rig mock serve scale [--firmware]``),
read by the same plain pyserial loop: boot silence (port open -> banner), samples per second and
lost ones, tare latency (``t`` -> ``T,ok``) and answer latency (``?`` -> ``I``).

Simulated time (deterministic): the reference session of ``tests/mocks/test_scale_firmware_differential.py`` on
the board and on the mock: lines identical or not, and how far apart each kind of line starts.

The board's cost: CPU seconds per simulated second when it runs a script as fast as it can.

    python benchmarks/bench_firmware.py [--quick] [--save]

Prints JSON (and a table on stderr); ``--save`` also writes ``benchmarks/results/firmware.json`` (full runs
only; ``--out PATH`` writes anywhere).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import time
from pathlib import Path

from _output import add_save_args, parse_args, save_json  # noqa: E402  (benchmarks/ is the script's folder)

import serial

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tactile_rig.drivers.scale import parse_line  # noqa: E402
from tactile_rig.mocks import scale_firmware as sf  # noqa: E402
from tactile_rig.testing.serve import serve_in_subprocess  # noqa: E402


def _next_line(ser: serial.Serial) -> tuple[float, object]:
    raw = ser.readline()
    t = time.monotonic()
    if not raw.endswith(b"\n"):
        raise TimeoutError(f"no whole line within {ser.timeout} s (got {raw!r})")
    return t, parse_line(raw.rstrip(b"\r\n"), t)


def _wait_for(ser: serial.Serial, kind: str) -> float:
    while True:
        t, p = _next_line(ser)
        if p is not None and p.kind == kind:
            return t


def measure(port: str, rate: int, seconds: float, repeats: int) -> dict:
    """Timing as a host sees it, with a plain pyserial reader."""
    with serial.Serial(port, 57600, timeout=6.0) as ser:
        t_open = time.monotonic()
        boot_s = _wait_for(ser, "banner") - t_open
        # Rate: whole S lines over `seconds`, and gaps in their sequence numbers.
        t0 = time.monotonic()
        seqs, arrivals = [], []
        while time.monotonic() - t0 < seconds:
            t, p = _next_line(ser)
            if p is not None and p.kind == "sample":
                seqs.append(p.reading.seq)
                arrivals.append(t)
        lost = sum((b - a - 1) % 65536 for a, b in zip(seqs, seqs[1:]))
        # Answer latency: '?' sent right after a sample line, until the I line is whole.
        id_ms = []
        for _ in range(repeats * 4):
            _wait_for(ser, "sample")
            t_send = time.monotonic()
            ser.write(b"?\n")
            id_ms.append((_wait_for(ser, "id") - t_send) * 1e3)
        # Tare latency: 't' right after a sample line, until T,ok (one smoothing window).
        tare_ms = []
        for _ in range(repeats):
            _wait_for(ser, "sample")
            t_send = time.monotonic()
            ser.write(b"t\n")
            tare_ms.append((_wait_for(ser, "tare") - t_send) * 1e3)
    span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else 0.0
    return {"boot_silence_s": boot_s, "samples_per_s": (len(seqs) - 1) / span if span > 0 else 0.0,
            "samples": len(seqs), "lost": lost, "id_answer_ms_median": statistics.median(id_ms),
            "id_answer_ms_max": max(id_ms), "tare_ms_median": statistics.median(tare_ms),
            "tare_ms_expected": (16 + 2) * 1000.0 / rate}


def wall_clock(rate: int, seconds: float, repeats: int) -> dict:
    out = {}
    for name, fw in (("firmware", True), ("mock", False)):
        options = ("--rate", str(rate), "--firmware") if fw else ("--rate", str(rate))
        with serve_in_subprocess("scale", *options, stop_timeout_s=10.0) as info:
            time.sleep(0.3)  # the board's first power-on, unwatched
            out[name] = measure(info["port"], rate, seconds, repeats)
    return out


def simulated(rate: int) -> dict:
    cfg = sf.BoardConfig(rate_sps=rate, noise_counts=0.0, drift_counts=0.0, spike_prob=0.0, boot_junk=2)
    script = sf.reference_session(cfg)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    fw = sf.run_script(script, cfg)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    mk = sf.run_script_mock(script, cfg)
    cmp = sf.Comparison(fw, mk)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)

    def timeline(result: sf.ScriptResult) -> dict:
        # When each line is whole at the host (its glitch bytes aside), as the wall-clock figures are.
        lines = [(ln.t_last_s, parse_line(ln.data.rstrip(b"\r\n"), ln.t_last_s)) for ln in result.lines]
        banner = next(t for t, p in lines if p.kind == "banner")
        tare_sent = next(t for t, action, v in sorted(script.events) if action == "send" and v == b"t\n")
        tare = next(t for t, p in lines if p.kind == "tare")
        return {"boot_silence_s": banner, "tare_s": tare - tare_sent}

    return {"lines_firmware": len(fw.lines), "lines_mock": len(mk.lines), "differences": cmp.differences(),
            "start_time_difference_ms": {
                k: {"max_abs": max(abs(x) for x in v) * 1e3, "mean": statistics.fmean(v) * 1e3}
                for k, v in sorted(cmp.time_differences_s().items())},
            "firmware": timeline(fw), "mock": timeline(mk), "simulated_s": script.end_s,
            "board_cpu_s": cpu_s, "board_cpu_per_simulated_s": cpu_s / script.end_s}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short wall-clock runs (3 s of samples, fewer repeats)")
    add_save_args(ap, "firmware.json")
    args = parse_args(ap)
    problem = sf.toolchain_problem()
    if problem:
        print(f"bench_firmware: {problem}", file=sys.stderr)
        return 2
    build = sf.build()
    seconds, repeats = (3.0, 3) if args.quick else (10.0, 5)
    results = {
        "machine_load": os.getloadavg(),
        "build": {"flash_bytes": build.flash_bytes, "ram_bytes": build.ram_bytes},
        "simulated_time": {str(r): simulated(r) for r in (80, 10)},
        "wall_clock": {str(r): wall_clock(r, seconds, repeats) for r in (80, 10)},
        "seconds": seconds,
    }
    text = json.dumps(results, indent=2)
    print(text)
    save_json(args, results, indent=2)
    header = f"{'SPS':>4} {'who':>9} {'boot s':>7} {'samples/s':>10} {'lost':>5} {'? ms':>6} {'tare ms':>8}"
    print(header, file=sys.stderr)
    for rate, sides in results["wall_clock"].items():
        for who, m in sides.items():
            print(f"{rate:>4} {who:>9} {m['boot_silence_s']:>7.3f} {m['samples_per_s']:>10.2f} {m['lost']:>5} "
                  f"{m['id_answer_ms_median']:>6.2f} {m['tare_ms_median']:>8.1f}", file=sys.stderr)
    same = all(not r["differences"] for r in results["simulated_time"].values())
    print(f"simulated time: reference session line for line {'identical' if same else 'DIFFERENT'}", file=sys.stderr)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
