"""The fault soak: every serial device × every fault kind, in process and over a pty relay.

For each device (Dynamixel Protocol 2, Dynamixel Protocol 1, the HX711 scale, the GRBL jig) and
each fault of :data:`tactile_rig.mocks.faults.KINDS`, the device's mock is driven through its
real driver for ``n`` operations while the fault is injected into what the driver receives, either
in process (``rigfault://rigsim://...``, virtual time) or over a pty (the mock served on a pty in
real time, :class:`~tactile_rig.mocks.relay.PtyRelay` in between). Each operation ends in one of:

* ``ok``: a value, compared with the mock's true state at that moment (the servo's register, the
  load on the cell, GRBL's machine position): a mismatch is a **silently wrong value**;
* a **typed error** (any :class:`~tactile_rig.core.errors.RigError`), counted by class; an ``ok``
  after one or more errors is a **recovery**; a :class:`~tactile_rig.core.errors.DeviceFault` is
  answered as a controller would, by ``activate()``;
* an **untyped exception** (anything else): a bug;
* a **hang**: an operation that took longer than ``hang_s`` (on the port's clock).

:func:`soak_row` runs one cell of the table, :func:`soak` the whole table; ``benchmarks/bench_faults.py``
prints it and saves it; ``tests/testing/test_fault_soak.py`` runs a short deterministic subset.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterator

import numpy as np

from tactile_rig.core.clock import Clock, RealClock, VirtualClock
from tactile_rig.core.errors import DeviceFault, RigError
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.dynamixel.bus import DynamixelBus
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.faults import KINDS, FaultInjector
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.relay import PtyRelay
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.load_cell import LoadCell
from tactile_rig.sim.world.stage import Stage
from tactile_rig.testing.serve import serve_in_process, serve_on_pty

DEVICES = ("dynamixel_p2", "dynamixel_p1", "scale", "jig")
TRANSPORTS = ("in_process", "relay")

#: how often each fault strikes: per byte for drop/flip/duplicate, per chunk of device output for
#: the rest, so that a few hundred operations see it several times
FAULT_QUERIES: dict[str, str] = {
    "drop": "drop=0.002",
    "flip": "flip=0.002",
    "duplicate": "dup=0.002",
    "garbage": "garbage=0.02",
    "split": "split=0.3",
    "late": "late=0.03&late_s=0.06",
    "stall": "stall=0.01&stall_s=0.6",
    "unplug": "unplug=0.005&away_s=0.5",
    "replug": "replug=0.01&replug_s=0.1",
    "reboot": "reboot=0.01",
}
LOAD_G = 150.0  # on the scale during the soak
SETTLE_S = 0.4  # the sketch's smoothing window (18 samples at 80/s) plus its latency
SCALE_TOLERANCE_G = 1.0  # noise of the smoothed HX711 at this load is a few hundredths of a gram
JIG_TOLERANCE_MM = 0.0011  # GRBL prints 3 decimals


@dataclass
class SoakRow:
    """One cell of the table: what ``operations`` calls on ``device`` under ``fault`` ended in."""

    device: str
    fault: str
    transport: str
    operations: int = 0
    ok: int = 0
    typed: dict[str, int] = field(default_factory=dict)
    recoveries: int = 0
    untyped: int = 0
    hangs: int = 0
    wrong: int = 0
    injected: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def typed_errors(self) -> int:
        return sum(self.typed.values())

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["typed_errors"] = self.typed_errors
        return d

    def note(self, text: str) -> None:
        if len(self.examples) < 5:
            self.examples.append(text[:300])


# -- the devices: how to build one, open its driver, and run and check one operation ---------------------

class _Harness:
    """A device under test: its mock (the truth), how to open the driver, one checked operation."""

    baud: int = 115200
    kind: str = ""

    def __init__(self, clock: Clock, seed: int) -> None:
        self.clock = clock
        self.rng = np.random.default_rng(seed)
        self.mock: Any = None

    def open(self, port: str) -> Any:  # pragma: no cover - overridden
        raise NotImplementedError

    def operate(self, driver: Any, i: int) -> str | None:
        """Run operation ``i``; return None if the value was true, else what was wrong."""
        raise NotImplementedError  # pragma: no cover

    def recover(self, driver: Any, error: RigError) -> None:
        """What a controller does after ``error`` (default: nothing; the next call retries)."""


class _Dynamixel(_Harness):
    kind = "dynamixel"

    def __init__(self, clock: Clock, seed: int, protocol: int) -> None:
        super().__init__(clock, seed)
        self.protocol = protocol
        self.baud = 1_000_000 if protocol == 2 else 57600
        self.mock = make_bus(protocol=protocol, ids=(1,), baud=self.baud, t_s=clock.now_s())
        self.servo = self.mock.servo(1)

    def open(self, port: str) -> DynamixelBus:
        return DynamixelBus(port, baudrate=self.baud, protocol=self.protocol)

    def operate(self, bus: DynamixelBus, i: int) -> str | None:
        k = i % 3
        if k == 0:
            got, truth = bus.ping(1), self.servo.item("Model Number")
            what = "ping"
        elif k == 1:
            value = int(self.rng.integers(1000, 3000))
            bus.write(1, "Goal Position", value)
            got, truth = value, self.servo.item("Goal Position")
            what = "written Goal Position"
        else:
            name = "Goal Position" if i % 2 else "Present Position"
            got = bus.read(1, name)
            truth = self.servo.item(name)
            what = name
        return None if got == truth else f"{what}: got {got}, true {truth}"


class _Scale(_Harness):
    kind = "scale"
    baud = sp.BAUD

    def __init__(self, clock: Clock, seed: int) -> None:
        super().__init__(clock, seed)
        self.cell = LoadCell()
        self.mock = ScaleMock(clock=clock if clock.is_virtual else None, load_cell=self.cell, spike_prob=0.0,
                              drift_counts=0.0, seed=seed, boot_s=0.3)

    def open(self, port: str) -> Scale:
        """Open, tare the empty scale (the session's zero), then put the load on and let the sketch's
        smoothing window fill with it (by time: lines queued before the change are read first)."""
        self.cell.applied_force_n = 0.0
        scale = Scale(port, boot_timeout_s=3.0)
        self._read_until(scale, scale.clock.now_s() + SETTLE_S)
        scale.tare()
        self.cell.applied_force_n = LOAD_G / 1000.0 * sp.STANDARD_GRAVITY_MPS2
        self._read_until(scale, scale.clock.now_s() + SETTLE_S)
        return scale

    @staticmethod
    def _read_until(scale: Scale, t_s: float) -> None:
        while scale.read().t_host_s < t_s:
            pass

    def operate(self, scale: Scale, i: int) -> str | None:
        r = scale.read()
        if abs(r.grams - LOAD_G) > SCALE_TOLERANCE_G:
            return f"reading {r.grams} g (seq {r.seq}, raw {r.raw}), true {LOAD_G} g"
        return None


class _Jig(_Harness):
    kind = "jig"

    def __init__(self, clock: Clock, seed: int) -> None:
        super().__init__(clock, seed)
        self.stage = Stage()
        self.mock = GrblMock(clock=clock if clock.is_virtual else None, stage=self.stage, homing=False, seed=seed)

    def open(self, port: str) -> Jig:
        return Jig(port, boot_timeout_s=2.0)

    def _true_work_mm(self) -> np.ndarray | None:
        m = self.mock
        if m.state != "Idle" or getattr(m, "_active", None) is not None:
            return None
        return m._quantize(m.pos) - m.wco

    def operate(self, jig: Jig, i: int) -> str | None:
        k = i % 4
        if k == 1:
            x, y = (float(v) for v in self.rng.uniform(-2.0, 2.0, 2))
            jig.move_to(round(x, 3), round(y, 3), None, 1200.0, wait=True, timeout_s=10.0)
            return None
        if k == 3:
            jig.command("G90")
            return None
        st = jig.status()
        if st.state != "Idle":
            return None
        truth = self._true_work_mm()
        pos = st.wpos or st.mpos
        if truth is None or pos is None:
            return None
        if st.wpos is None:  # MPos: compare machine positions
            truth = truth + self.mock.wco
        if any(abs(a - b) > JIG_TOLERANCE_MM for a, b in zip(pos, truth)):
            return f"status {st.raw!r}, true {np.round(truth, 3).tolist()}"
        return None

    def recover(self, jig: Jig, error: RigError) -> None:
        if isinstance(error, DeviceFault):
            jig.activate(home=False)


def make_harness(device: str, clock: Clock, seed: int) -> _Harness:
    if device == "dynamixel_p2":
        return _Dynamixel(clock, seed, 2)
    if device == "dynamixel_p1":
        return _Dynamixel(clock, seed, 1)
    if device == "scale":
        return _Scale(clock, seed)
    if device == "jig":
        return _Jig(clock, seed)
    raise ValueError(f"device={device!r}: expected one of {', '.join(DEVICES)}")


# -- one cell ---------------------------------------------------------------------------------------------

@contextlib.contextmanager
def _port(h: _Harness, fault_query: str, transport: str, seed: int) -> Iterator[tuple[Callable[[int], str],
                                                                                        Callable[[], dict]]]:
    """Ports for the driver with the faults on them: yields (port for open attempt k, a function giving
    the injected counts). In process every attempt to open gets its own seed: a fresh injector with the
    seed of a failed attempt would strike at the same byte again, for ever."""
    if transport == "in_process":
        with serve_in_process(h.mock, h.clock) as url:
            yield (lambda k: f"rigfault://{url}#{fault_query}&seed={seed * 1000 + k}"), _injected_in_process
    elif transport == "relay":
        faults = FaultInjector.from_query(f"{fault_query}&seed={seed}")
        with serve_on_pty(h.mock) as server, PtyRelay(server.port, faults, baudrate=h.baud, name=h.kind) as relay:
            yield (lambda k: relay.port), faults.counts
            if relay.error is not None:
                raise RuntimeError(f"the relay failed: {relay.error!r}") from relay.error
    else:
        raise ValueError(f"transport={transport!r}: expected one of {', '.join(TRANSPORTS)}")


_INJECTORS: list[FaultInjector] = []  # those of the current in-process cell, one per opened port


def _injected_in_process() -> dict:
    total: dict[str, int] = {}
    for inj in _INJECTORS:
        for k, v in inj.counts().items():
            total[k] = total.get(k, 0) + v
    return total


def _injector_of(driver: Any) -> FaultInjector | None:
    for path in (("transport", "serial"), ("port", "ser")):
        obj = driver
        for name in path:
            obj = getattr(obj, name, None)
        faults = getattr(obj, "faults", None)
        if isinstance(faults, FaultInjector):
            return faults
    return None


def soak_row(device: str, fault: str, *, transport: str = "in_process", n: int = 500, seed: int = 0,
             hang_s: float = 10.0, gap_s: float = 0.01) -> SoakRow:
    """Drive ``device`` through ``n`` operations under ``fault``; see the module docstring."""
    if fault not in FAULT_QUERIES:
        raise ValueError(f"fault={fault!r}: expected one of {', '.join(KINDS)}")
    clock: Clock = VirtualClock() if transport == "in_process" else RealClock()
    h = make_harness(device, clock, seed)
    row = SoakRow(device, fault, transport)
    wall0 = time.monotonic()
    _INJECTORS.clear()
    with _port(h, FAULT_QUERIES[fault], transport, seed) as (port, injected):
        driver: Any = None
        failing = False
        attempts = 0
        try:
            for i in range(n):
                t0, w0 = clock.now_s(), time.monotonic()
                row.operations += 1
                try:
                    if driver is None:
                        attempts += 1
                        driver = h.open(port(attempts))
                        inj = _injector_of(driver)
                        if inj is not None:
                            _INJECTORS.append(inj)
                    wrong = h.operate(driver, i)
                    row.ok += 1
                    if failing:
                        row.recoveries += 1
                        failing = False
                    if wrong is not None:
                        row.wrong += 1
                        row.note(f"wrong: {wrong}")
                except RigError as exc:
                    name = type(exc).__name__
                    row.typed[name] = row.typed.get(name, 0) + 1
                    failing = True
                    if driver is not None:
                        try:
                            h.recover(driver, exc)
                        except RigError:
                            pass
                except Exception as exc:  # noqa: BLE001 - an untyped exception is what the soak counts
                    row.untyped += 1
                    failing = True
                    row.note(f"untyped {type(exc).__name__}: {exc}")
                took = max(clock.now_s() - t0, time.monotonic() - w0 if not clock.is_virtual else 0.0)
                if took > hang_s:
                    row.hangs += 1
                    row.note(f"op {i} took {took:.3g} s")
                clock.sleep(gap_s)
        finally:
            if driver is not None:
                with contextlib.suppress(Exception):
                    driver.close()
            row.injected = dict(injected())
            _INJECTORS.clear()
    row.seconds = time.monotonic() - wall0
    return row


@dataclass
class MovingReports:
    """Status reports read while the jig moves, under ``fault``: how many, how many typed errors,
    and how many returned a report GRBL never printed (a corrupted one that passed every check)."""

    fault: str
    transport: str
    reports: int = 0
    typed: int = 0
    wrong: int = 0
    examples: list[str] = field(default_factory=list)

    @property
    def wrong_rate(self) -> float:
        return self.wrong / self.reports if self.reports else 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"wrong_rate": self.wrong_rate}


def moving_reports(fault: str = "flip", *, moves: int = 100, seed: int = 0) -> MovingReports:
    """The residual the jig's checks cannot remove: reports polled while moving (in process).

    The truth is the text GRBL printed: a report the driver returns that GRBL never printed was
    corrupted on the wire and still passed the strict parser (a digit flipped into a digit)."""
    clock = VirtualClock()
    h = _Jig(clock, seed)
    printed: set[str] = set()
    original = h.mock._status_report

    def recording(t_s: float) -> str:
        text = original(t_s)
        printed.add(text)
        return text

    h.mock._status_report = recording
    out = MovingReports(fault, "in_process")
    with serve_in_process(h.mock, clock) as url:
        jig = Jig(f"rigfault://{url}#{FAULT_QUERIES[fault]}&seed={seed}", boot_timeout_s=2.0)
        try:
            for _ in range(moves):
                x, y = (round(float(v), 3) for v in h.rng.uniform(-3.0, 3.0, 2))
                try:
                    jig.move_to(x, y, None, 600.0)
                except RigError:
                    out.typed += 1
                    with contextlib.suppress(RigError):
                        jig.wait_idle(10.0)
                    continue
                for _ in range(200):
                    try:
                        st = jig.status()
                    except RigError as exc:
                        out.typed += 1
                        with contextlib.suppress(RigError):
                            h.recover(jig, exc)
                        continue
                    if st.state == "Idle":
                        break
                    out.reports += 1
                    if st.raw not in printed:
                        out.wrong += 1
                        if len(out.examples) < 5:
                            out.examples.append(st.raw)
                    clock.sleep(0.02)
        finally:
            jig.close()
    return out


def soak(devices: tuple[str, ...] = DEVICES, faults: tuple[str, ...] = KINDS,
         transports: tuple[str, ...] = TRANSPORTS, *, n: int = 500, n_relay: int | None = None, seed: int = 0,
         on_row: Callable[[SoakRow], None] | None = None) -> list[SoakRow]:
    """Every (device, fault, transport) cell; ``n_relay`` operations over the relay (default ``n``)."""
    rows = []
    for transport in transports:
        for device in devices:
            for fault in faults:
                count = n if transport == "in_process" or n_relay is None else n_relay
                row = soak_row(device, fault, transport=transport, n=count, seed=seed)
                rows.append(row)
                if on_row is not None:
                    on_row(row)
    return rows


def format_table(rows: list[SoakRow]) -> str:
    """A plain-text table: one line per cell."""
    head = (f"{'device':<13} {'fault':<10} {'transport':<10} {'ops':>5} {'ok':>5} {'typed':>5} {'recov':>5} "
            f"{'untyped':>7} {'hangs':>5} {'wrong':>5}  {'injected':<28} typed errors")
    lines = [head, "-" * len(head)]
    for r in rows:
        inj = ",".join(f"{k}:{v}" for k, v in sorted(r.injected.items()))
        typed = ",".join(f"{k}:{v}" for k, v in sorted(r.typed.items()))
        lines.append(f"{r.device:<13} {r.fault:<10} {r.transport:<10} {r.operations:>5} {r.ok:>5} "
                     f"{r.typed_errors:>5} {r.recoveries:>5} {r.untyped:>7} {r.hangs:>5} {r.wrong:>5}  "
                     f"{inj[:28]:<28} {typed}")
    return "\n".join(lines)


def totals(rows: list[SoakRow]) -> dict[str, int]:
    return {k: sum(getattr(r, k) for r in rows) for k in ("operations", "ok", "recoveries", "untyped", "hangs",
                                                           "wrong")} | {"typed_errors": sum(r.typed_errors for r in rows)}


__all__ = ["DEVICES", "FAULT_QUERIES", "KINDS", "MovingReports", "SoakRow", "TRANSPORTS", "format_table",
           "moving_reports", "soak", "soak_row", "totals"]
