"""Dynamixel bus under injected faults, against the MX-64 mock in process (virtual time).

Two parts, each beside its baseline in the same run:

* **fault table**: Protocol 2.0 and 1.0 × drop, flip, dup, garbage, noise, split, late, lost, stall, unplug
  (with replug): operations (ping, reads, writes), typed errors, recoveries (a success after a
  failure), untyped exceptions, hangs (an operation over 1 s of virtual time) and silently wrong
  values (a read that differs from the mock's register, a write that returned but did not land).
  Protocol 1.0 reads use ``verify=True`` here; the baseline rows are the bare dynamixel-sdk
  (``PacketHandler.readTxRx`` / ``ping``) on the same faults.
* **P1 residual**: the rate of wrong values among Protocol 1.0 reads of Goal Position with 1-8
  random bytes inserted at a random place inside 30 % of the statuses (line noise): the bare SDK,
  the bus's raw bytes, the bus's range-checked item, and the item with read-verify.
* **speed**: Present Position reads per second over a pty, the bus beside the bare SDK.

Usage: ``python benchmarks/bench_dynamixel_wire.py [--ops 300] [--reads 20000] [--sdk-reads 1000]
[--speed-reads 3000] [--parts table,residual,speed] [--quick] [--save | --out PATH]``; ``--save``
writes the parts run into ``benchmarks/results/dynamixel_wire.json`` (keeping the other parts').
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from typing import Any

import dynamixel_sdk as sdk
import numpy as np
from _output import add_save_args, parse_args, save_json, saved_results  # benchmarks/ is the script's folder

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import RigError
from tactile_rig.drivers.dynamixel import DynamixelBus, UrlPortHandler
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.registry import register_instance, unregister_instance

MODEL = {2: 311, 1: 310}
ITEMS = ["Model Number", "Goal Position", "LED", "Return Delay Time", "Present Position"]
HANG_S = 1.0

# rigfault:// faults (per byte unless noted), and the device-side ones applied to the mock's output
FAULTS: dict[str, dict[str, Any]] = {
    "drop": {"url": "drop=0.01"},
    "flip": {"url": "flip=0.01"},
    "dup": {"url": "dup=0.01"},
    "garbage": {"url": "garbage=0.2"},  # a burst before 20 % of the chunks of device output
    "noise": {"device": "noise"},  # 1-8 random bytes inside 20 % of the statuses (line noise)
    "split": {"device": "split"},  # a status arrives in two parts, 16 ms apart (a latency-timer boundary)
    "late": {"device": "late"},  # 10 % of statuses 20-120 ms late (queued behind: FIFO)
    "lost": {"device": "lost"},  # 5 % of statuses never sent
    "stall": {"url": "stall_after=400"},  # the link goes silent for good
    "unplug": {"url": "disconnect_after=300"},  # EIO; each reopen (replug) works for 300 more bytes
}


def _device_faults(dev: Any, kind: str, rng: np.random.Generator, p: float = 0.2) -> None:
    orig = dev.emit

    def emit(data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
        if kind == "noise" and rng.random() < p:
            k = int(rng.integers(0, len(data) + 1))
            burst = rng.integers(0, 256, size=int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
            data = data[:k] + burst + data[k:]
        if kind == "late" and rng.random() < 0.10:
            return orig(data, t_s, delay_s=delay_s + float(rng.uniform(0.02, 0.12)), reply=reply)
        if kind == "lost" and rng.random() < 0.05:
            return t_s
        if kind == "split" and len(data) > 2 and rng.random() < 0.5:
            k = int(rng.integers(1, len(data)))
            orig(data[:k], t_s, delay_s=delay_s, reply=reply)
            return orig(data[k:], t_s, delay_s=delay_s + 0.016, reply=reply)
        return orig(data, t_s, delay_s=delay_s, reply=reply)

    dev.emit = emit


class Row:
    def __init__(self) -> None:
        self.ops = self.ok = self.typed = self.recoveries = self.untyped = self.hangs = self.wrong = 0
        self.untyped_kinds: dict[str, int] = {}

    def as_dict(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items()}


def _setup(protocol: int, fault: str, seed: int) -> tuple[Any, VirtualClock, str, str]:
    clock = VirtualClock()
    dev = make_bus(protocol=protocol, ids=[1, 2], timing=True, return_delay_us=0)
    name = f"bench-dxl-{protocol}-{fault}-{seed}-{time.monotonic_ns()}"
    url = register_instance(name, dev, clock)
    spec = FAULTS[fault]
    if "device" in spec:
        _device_faults(dev, spec["device"], np.random.default_rng(seed))
        port = url
    else:
        port = f"rigfault://{url}#{spec['url']}&seed={seed}"
    return dev, clock, port, name


def run_bus(protocol: int, fault: str, n_ops: int, seed: int = 1) -> Row:
    dev, clock, port, name = _setup(protocol, fault, seed)
    rng = np.random.default_rng(seed + 100)
    row = Row()
    failed_before = False
    try:
        bus = DynamixelBus(port, protocol=protocol, baudrate=dev.baud, reconnect_policy=Reconnect(clock, initial_s=0.05))
    except RigError:
        row.typed += 1
        unregister_instance(name)
        return row
    with bus:
        for _ in range(n_ops):
            i = int(rng.integers(1, 3))
            op = rng.choice(["ping", "read", "read", "read", "led", "goal"])
            item = ITEMS[int(rng.integers(0, len(ITEMS)))]
            servo = dev.servo(i)
            t0 = clock.now_s()
            row.ops += 1
            try:
                if op == "ping":
                    good = bus.ping(i) == MODEL[protocol]
                elif op == "read":
                    good = bus.read(i, item, verify=protocol == 1) == servo.item(item)
                elif op == "led":
                    v = int(rng.integers(0, 2))
                    bus.write(i, "LED", v)
                    good = servo.item("LED") == v
                else:
                    v = int(rng.integers(1100, 3000))
                    bus.write(i, "Goal Position", v)
                    good = servo.item("Goal Position") == v
                row.ok += 1
                row.wrong += int(not good)
                row.recoveries += int(failed_before)
                failed_before = False
            except RigError:
                row.typed += 1
                failed_before = True
            except Exception as exc:  # what the table is for
                row.untyped += 1
                row.untyped_kinds[type(exc).__name__] = row.untyped_kinds.get(type(exc).__name__, 0) + 1
                failed_before = True
            if clock.now_s() - t0 > HANG_S:
                row.hangs += 1
            clock.sleep(0.005)
    unregister_instance(name)
    return row


def run_sdk(protocol: int, fault: str, n_ops: int, seed: int = 1) -> Row:
    """The bare SDK on the same faults: result codes are its 'typed errors'."""
    dev, clock, port, name = _setup(protocol, fault, seed)
    rng = np.random.default_rng(seed + 100)
    row = Row()
    try:
        ph = UrlPortHandler(port, exclusive=False)
        ph.openPort()
        ph.setBaudRate(dev.baud)
    except Exception:
        row.typed += 1
        unregister_instance(name)
        return row
    pk = sdk.PacketHandler(float(protocol))
    failed_before = False
    for _ in range(n_ops):
        i = int(rng.integers(1, 3))
        item = dev.servo(i).table[ITEMS[int(rng.integers(0, len(ITEMS)))]]
        row.ops += 1
        t0, w0 = clock.now_s(), time.monotonic()
        try:
            if rng.random() < 0.3:
                model, res, _ = pk.ping(ph, i)
                good = model == MODEL[protocol]
            else:
                data, res, _ = pk.readTxRx(ph, i, item.address, item.size)
                good = res != sdk.COMM_SUCCESS or item.from_raw(int.from_bytes(bytes(data), "little")) == \
                    dev.servo(i).item(item.name)
            if res == sdk.COMM_SUCCESS:
                row.ok += 1
                row.wrong += int(not good)
                row.recoveries += int(failed_before)
                failed_before = False
            else:
                row.typed += 1
                failed_before = True
        except Exception as exc:
            row.untyped += 1
            row.untyped_kinds[type(exc).__name__] = row.untyped_kinds.get(type(exc).__name__, 0) + 1
            failed_before = True
        if clock.now_s() - t0 > HANG_S or time.monotonic() - w0 > HANG_S:
            row.hangs += 1
        clock.sleep(0.005)
    try:
        ph.closePort()
    except Exception:
        pass
    unregister_instance(name)
    return row


#: how the residual is read: the bare SDK, the bus's raw bytes (no range check: an item using every
#: value of its bytes), a named item (Goal Position: values above 4095 are refused as damaged) and
#: the named item with read-verify
RESIDUAL_MODES = ("sdk", "raw", "read", "verify")


def p1_residual(n_reads: int, noise: float, *, mode: str, seed: int = 7) -> dict[str, Any]:
    """Wrong values among P1 reads of Goal Position with line noise inside statuses."""
    clock = VirtualClock()
    dev = make_bus(protocol=1, ids=[1], timing=True, return_delay_us=0)
    name = f"bench-dxl-residual-{mode}-{time.monotonic_ns()}"
    url = register_instance(name, dev, clock)
    _device_faults(dev, "noise", np.random.default_rng(seed + 1), p=noise)
    rng = np.random.default_rng(seed)
    servo = dev.servo(1)
    item = servo.table["Goal Position"]
    wrong = ok = failed = 0
    t0 = time.perf_counter()
    if mode == "sdk":
        ph = UrlPortHandler(url, exclusive=False)
        ph.openPort()
        ph.setBaudRate(dev.baud)
        pk = sdk.PacketHandler(1.0)
    else:
        bus = DynamixelBus(url, protocol=1, baudrate=dev.baud)
    for k in range(n_reads):
        if k % 50 == 0:  # a new true value now and then (written to the mock directly: no wire)
            servo._write_raw_item("Goal Position", int(rng.integers(0, 4096)))
        truth = servo.item("Goal Position")
        try:
            if mode == "sdk":
                got, res, _ = pk.read2ByteTxRx(ph, 1, item.address)
                if res != sdk.COMM_SUCCESS:
                    failed += 1
                    continue
            elif mode == "raw":
                got = int.from_bytes(bus.read_bytes(1, item.address, item.size), "little")
            else:
                got = bus.read(1, "Goal Position", verify=mode == "verify")
        except RigError:
            failed += 1
            continue
        ok += 1
        wrong += int(got != truth)
        clock.sleep(0.001)
    out = {"reads": n_reads, "noise_per_status": noise, "mode": mode, "returned": ok,
           "typed_failures": failed, "wrong": wrong, "wrong_per_returned": wrong / ok if ok else None,
           "wall_s": round(time.perf_counter() - t0, 2)}
    if mode != "sdk":
        out["stats"] = bus.stats.to_dict()
        bus.close()
    unregister_instance(name)
    return out


def speed(n_reads: int) -> list[dict[str, Any]]:
    """Present Position reads per second over a pty (mock in a thread, timing on, 1 Mbps, Return
    Delay Time 0): the bus (validation, flush, resync bookkeeping) beside the bare SDK."""
    from tactile_rig.testing.serve import serve_on_pty

    out = []
    for who in ("bare SDK", "bus"):
        dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
        with serve_on_pty(dev) as server:
            if who == "bus":
                bus = DynamixelBus(server.port)
                read = lambda: bus.read(1, "Present Position")  # noqa: E731
            else:
                ph = sdk.PortHandler(server.port)
                ph.openPort()
                ph.setBaudRate(1_000_000)
                pk = sdk.PacketHandler(2.0)
                read = lambda: pk.read4ByteTxRx(ph, 1, 132)  # noqa: E731
            for _ in range(50):
                read()
            times = []
            for _ in range(n_reads):
                t0 = time.perf_counter()
                read()
                times.append(time.perf_counter() - t0)
            if who == "bus":
                bus.close()
            else:
                ph.closePort()
        t = np.array(times)
        out.append({"who": who, "reads": n_reads, "reads_per_s": round(n_reads / t.sum(), 1),
                    "median_ms": round(float(np.median(t)) * 1e3, 3), "p90_ms": round(float(np.percentile(t, 90)) * 1e3, 3)})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ops", type=int, default=300, help="operations per protocol and fault (default 300)")
    ap.add_argument("--reads", type=int, default=20000, help="P1 residual: reads by the bus (default 20000)")
    ap.add_argument("--sdk-reads", type=int, default=1000,
                    help="P1 residual: reads by the bare SDK, whose failures wait on the wall clock (default 1000)")
    ap.add_argument("--noise", type=float, default=0.3,
                    help="P1 residual: chance of a 1-8 byte random burst inside each status (default 0.3)")
    ap.add_argument("--speed-reads", type=int, default=3000, help="speed: reads over a pty each (default 3000)")
    ap.add_argument("--parts", default="table,residual,speed",
                    help="comma-separated parts to run (table, residual, speed); --save updates only those")
    ap.add_argument("--quick", action="store_true", help="a short smoke run")
    add_save_args(ap, "dynamixel_wire.json")
    args = parse_args(ap, argv)
    logging.basicConfig(level=logging.ERROR)  # the bus warns on every unplug
    if args.quick:
        args.ops, args.reads, args.sdk_reads, args.speed_reads = 40, 500, 50, 200
    parts = set(args.parts.split(","))
    results: dict[str, Any] = {}
    if "speed" in parts:
        results["speed"] = speed(args.speed_reads)
        for r in results["speed"]:
            print(f"speed, {r['who']:8}: {r['reads_per_s']} reads/s, median {r['median_ms']} ms, p90 {r['p90_ms']} ms "
                  f"({r['reads']} Present Position reads over a pty)", flush=True)
    summary = {"ops": 0, "untyped": 0, "hangs": 0, "wrong": 0}
    if "table" in parts:
        results["table"], summary = fault_table(args.ops)
        results["bus_total"] = summary
    if "residual" in parts:
        results["p1_residual"] = residual(args)
    # a partial rerun (--parts) keeps the committed figures of the other parts
    saved = (saved_results("dynamixel_wire.json") or {}) if args.save else {}
    saved.update(results)
    commands = saved.get("commands") or ({k: saved["command"] for k in ("table", "residual")}
                                         if "command" in saved else {})
    for part in parts:
        commands[part] = "python benchmarks/bench_dynamixel_wire.py " + " ".join(argv if argv is not None else sys.argv[1:])
    saved["commands"] = commands
    saved.pop("command", None)
    save_json(args, saved)
    return 0 if summary["untyped"] == 0 and summary["hangs"] == 0 and summary["wrong"] == 0 else 1


def fault_table(n_ops: int) -> tuple[list[dict[str, Any]], dict[str, int]]:
    table = []
    print(f"{'who':5} {'P':>2} {'fault':8} {'ops':>5} {'ok':>5} {'typed':>5} {'recov':>5} {'untyped':>7} "
          f"{'hangs':>5} {'wrong':>5}")
    for protocol in (2, 1):
        for fault in FAULTS:
            for who, fn in (("bus", run_bus), ("sdk", run_sdk)):
                if who == "sdk" and fault in ("stall", "lost"):
                    n = max(10, n_ops // 10)  # each failure spins 34 ms of wall time in the SDK
                else:
                    n = n_ops
                r = fn(protocol, fault, n)
                d = {"who": who, "protocol": protocol, "fault": fault, **r.as_dict()}
                table.append(d)
                print(f"{who:5} {protocol:>2} {fault:8} {r.ops:>5} {r.ok:>5} {r.typed:>5} {r.recoveries:>5} "
                      f"{r.untyped:>7} {r.hangs:>5} {r.wrong:>5}" + (f"  {r.untyped_kinds}" if r.untyped else ""),
                      flush=True)
    bus_rows = [d for d in table if d["who"] == "bus"]
    summary = {k: sum(d[k] for d in bus_rows) for k in ("ops", "untyped", "hangs", "wrong")}
    print(f"bus total: {summary}")
    return table, summary


def residual(args: argparse.Namespace) -> list[dict[str, Any]]:
    out = [p1_residual(args.sdk_reads if mode == "sdk" else args.reads, args.noise, mode=mode)
           for mode in RESIDUAL_MODES]
    for r in out:
        who = {"sdk": "bare SDK", "raw": "bus bytes", "read": "bus read", "verify": "bus verify"}[r["mode"]]
        rate = r["wrong_per_returned"]
        print(f"P1 residual, {who:10}: {r['wrong']} wrong of {r['returned']} returned ({r['reads']} reads, "
              f"{r['typed_failures']} typed failures), rate {rate if rate is None else f'{rate:.2e}'}", flush=True)
    return out


if __name__ == "__main__":
    raise SystemExit(main())
