"""DynamixelBus under the faults of a real bench: late and lost status packets, noisy links, unplug
and replug, a second user of the port. Every value the bus returns is compared with the mock's true
register state; every failure must be a typed RigError."""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Any, Iterator

import pytest
from hypothesis import given, settings, strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import DeviceTimeout, LinkCorrupt, NotConnected, PortInUse, RigError
from tactile_rig.core.types import GripperOutcome
from tactile_rig.drivers.dynamixel import DynamixelBus, DynamixelGripper
from tactile_rig.drivers.base import Lifecycle
from tactile_rig.drivers.dynamixel import wire
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.pty_server import PtyServer
from tactile_rig.testing import serve_in_process
from tests._plug import Plug

MODEL = {2: 311, 1: 310}


class LateReplies:
    """Delays chosen status packets at the device: ``delays`` gives the extra delay of each reply
    in turn (seconds). The servo's line stays busy meanwhile, so later replies queue behind a
    late one, as they do behind an adapter's latency timer."""

    def __init__(self, dev: Any, delays: list[float]) -> None:
        self.delays = list(delays)
        self.count = 0
        orig = dev.emit

        def emit(data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
            extra = self.delays[self.count] if self.count < len(self.delays) else 0.0
            self.count += 1
            if extra is None:  # this status is lost
                return t_s
            return orig(data, t_s, delay_s=delay_s + extra, reply=reply)

        dev.emit = emit


@contextmanager
def _bus(protocol: int = 2, ids=(1, 2), faults: str = "", **kw) -> Iterator[tuple[DynamixelBus, Any]]:
    dev = make_bus(protocol=protocol, ids=list(ids), timing=True, return_delay_us=0)
    with serve_in_process(dev) as url:
        port = f"rigfault://{url}#{faults}" if faults else url
        with DynamixelBus(port, protocol=protocol, baudrate=dev.baud, **kw) as bus:
            yield bus, dev


# -- late status packets -------------------------------------------------------------------------------
@pytest.mark.parametrize("protocol", [2, 1])
def test_a_status_60_ms_late_is_discarded_and_the_retry_returns_the_true_value(protocol: int) -> None:
    with _bus(protocol) as (bus, dev):
        bus.write(1, "Goal Position", 1234)
        bus.write(2, "Goal Position", 2345)
        LateReplies(dev, [0.060])  # the status of the next request arrives 60 ms late
        assert bus.read(1, "Goal Position") == 1234
        assert bus.stats.stale_packets == 1 and bus.stats.resyncs == 1 and bus.stats.retries == 1
        # every request after the late packet gets its own answer
        assert bus.ping(1) == MODEL[protocol]
        assert bus.read(1, "Present Position") == dev.servo(1).item("Present Position")
        assert bus.read(2, "Goal Position") == 2345


@pytest.mark.parametrize("protocol", [2, 1])
def test_without_retries_the_late_status_is_a_timeout_and_never_the_next_answer(protocol: int) -> None:
    with _bus(protocol, retries=0) as (bus, dev):
        bus.write(1, "Goal Position", 2048)
        LateReplies(dev, [0.060])
        with pytest.raises(DeviceTimeout):
            bus.read(1, "Goal Position")
        # a bus that took the late read status as the next reply would return 2048 here
        assert bus.ping(1) == MODEL[protocol]
        assert bus.stats.stale_packets == 1
        LateReplies(dev, [0.060])
        with pytest.raises(DeviceTimeout):
            bus.read(1, "Model Number")  # same length as the next read: only a resync tells them apart
        assert bus.read(1, "Goal Position") == 2048


def test_a_late_status_from_another_id_is_not_taken() -> None:
    with _bus(2, retries=0) as (bus, dev):
        bus.write(2, "Goal Position", 777)
        LateReplies(dev, [0.060])
        with pytest.raises(DeviceTimeout):
            bus.read(2, "Goal Position")
        bus.write(1, "Goal Position", 999)
        assert bus.read(1, "Goal Position") == 999
        assert bus.read(2, "Goal Position") == 777


# -- lost write statuses: read back, never blindly repeat --------------------------------------------------
@pytest.mark.parametrize("protocol", [2, 1])
def test_a_write_whose_status_is_lost_is_confirmed_by_reading_back(protocol: int) -> None:
    with _bus(protocol) as (bus, dev):
        LateReplies(dev, [None])  # the servo applied the write; its status is lost
        bus.write(1, "Goal Position", 1500)
        assert dev.servo(1).item("Goal Position") == 1500
        assert bus.stats.writes_confirmed_by_readback == 1 and bus.stats.writes_repeated_after_readback == 0


def test_a_write_that_never_arrived_is_sent_again_after_reading_back() -> None:
    with _bus(2) as (bus, dev):
        orig, calls = dev.feed, []

        def feed(data: bytes, t_s: float) -> None:
            calls.append(data)
            if len(calls) != 1:  # the first instruction is lost on the way
                orig(data, t_s)

        dev.feed = feed
        bus.write(1, "LED", 1)
        assert dev.servo(1).item("LED") == 1
        assert bus.stats.writes_repeated_after_readback == 1
        writes = [c for c in calls if c[7:8] == b"\x03"]
        assert len(writes) == 2  # the second only after the read-back showed 0


def test_reboot_is_never_repeated() -> None:
    with _bus(2) as (bus, dev):
        sent = []
        orig = dev.feed
        dev.feed = lambda data, t_s: (sent.append(data), orig(data, t_s))[1]
        LateReplies(dev, [None])
        with pytest.raises(DeviceTimeout):
            bus.reboot(1)
        assert sum(1 for d in sent if d[7:8] == b"\x08") == 1


# -- Protocol 1.0 read-verify --------------------------------------------------------------------------------
def test_p1_verify_catches_a_corruption_the_checksum_lets_through() -> None:
    with _bus(1, ids=[1]) as (bus, dev):
        bus.write(1, "Goal Position", 1000)
        orig = dev.emit
        forged = []

        def emit(data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
            if not forged:  # two bytes corrupted so that the 8-bit sum is unchanged
                p = bytearray(data)
                p[5], p[6] = (p[5] + 1) & 0xFF, (p[6] - 1) & 0xFF
                forged.append(bytes(p))
                data = bytes(p)
            return orig(data, t_s, delay_s=delay_s, reply=reply)

        dev.emit = emit
        assert bus.read(1, "Goal Position", verify=True) == 1000
        assert wire.parse_status(1, forged[0])[0].params != (1000).to_bytes(2, "little")  # it was valid, and wrong
        assert bus.stats.verify_mismatches == 1


# -- noisy links and late packets together: no wrong value, only typed errors --------------------------------
ITEMS = ["Model Number", "Goal Position", "LED", "Return Delay Time", "Present Position", "ID"]


@settings(max_examples=20, deadline=None)
@given(
    protocol=st.sampled_from([2, 1]),
    ops=st.lists(st.tuples(st.sampled_from(["read", "read", "ping", "led", "goal"]), st.sampled_from([1, 2]),
                           st.sampled_from(ITEMS), st.integers(1100, 3000)), min_size=1, max_size=12),
    delays=st.lists(st.sampled_from([0.0, 0.0, 0.0, 0.01, 0.03, 0.06, 0.1, None]), max_size=20),
    fault=st.sampled_from(["", "garbage=0.3", "drop=0.02", "dup=0.02", "flip=0.02"]),
    seed=st.integers(0, 10_000),
)
def test_late_lost_and_corrupt_statuses_never_yield_a_wrong_value(protocol, ops, delays, fault, seed) -> None:
    faults = f"{fault}&seed={seed}" if fault else ""
    with _bus(protocol, faults=faults) as (bus, dev):
        LateReplies(dev, delays)
        for op, i, item, value in ops:
            servo = dev.servo(i)
            try:
                if op == "read":
                    # Protocol 1.0's checksum is weak: critical reads use read-verify there
                    got = bus.read(i, item, verify=protocol == 1)
                    assert got == servo.item(item), (op, i, item)
                elif op == "ping":
                    assert bus.ping(i) == MODEL[protocol]
                elif op == "led":
                    bus.write(i, "LED", value % 2)
                    assert servo.item("LED") == value % 2  # a write that returned has landed
                else:
                    bus.write(i, "Goal Position", value)
                    assert servo.item("Goal Position") == value
            except RigError:
                pass
            bus.clock.sleep(0.001)
        assert not bus.port.is_using


# -- unplug and replug ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("protocol", [2, 1])
def test_unplug_is_not_connected_fails_fast_and_replug_reconnects_with_backoff(monkeypatch, protocol: int) -> None:
    plug = Plug(monkeypatch)
    clock = VirtualClock()
    dev = make_bus(protocol=protocol, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url:
        policy = Reconnect(clock, initial_s=0.1, factor=2.0, max_s=1.0)
        with DynamixelBus(url, protocol=protocol, baudrate=dev.baud, reconnect_policy=policy) as bus:
            bus.write(1, "Goal Position", 1111)
            plug.plugged = False
            with pytest.raises(NotConnected, match="unplugged"):
                bus.read(1, "Goal Position")
            assert not bus.port.is_using  # the SDK's flag is free: nothing is wedged
            opens = plug.opens
            with pytest.raises(NotConnected, match="is gone"):
                bus.ping(1)  # fails fast: no open attempt before the backoff
            assert plug.opens == opens
            clock.advance(0.1)
            with pytest.raises(NotConnected, match="next reconnect attempt in 0.2 s"):
                bus.ping(1)  # one attempt, the cable is still out; the next wait doubles
            assert plug.opens == opens + 1
            plug.plugged = True
            with pytest.raises(NotConnected):
                bus.ping(1)  # still inside the backoff
            clock.advance(0.2)
            assert bus.read(1, "Goal Position") == 1111
            assert bus.stats.disconnects == 1 and bus.stats.reconnects == 1 and policy.reconnects == 1
            bus.write(1, "Goal Position", 2222)
            assert dev.servo(1).item("Goal Position") == 2222


def test_the_gripper_sees_not_connected_and_works_after_replug(monkeypatch) -> None:
    plug = Plug(monkeypatch)
    clock = VirtualClock()
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url, DynamixelGripper(url) as g:
        g.activate()
        plug.plugged = False
        with pytest.raises(NotConnected):
            g.state()
        with pytest.raises(NotConnected):
            g.gripper_go(0.05, 0.3)
        plug.plugged = True
        clock.advance(1.0)
        assert g.state().hardware_error == 0


@pytest.mark.parametrize("protocol,power_lost", [(2, True), (1, True), (2, False)])
def test_after_a_replug_a_servo_that_lost_power_is_not_driven_as_if_holding(monkeypatch, protocol: int,
                                                                               power_lost: bool) -> None:
    # The adapter and the servo's supply on one hub: unplugged together, the servo comes back with
    # torque off and its RAM at defaults, and a move must not wait for motion that never comes. A
    # replug that kept the servo powered leaves it holding and the driver active.
    plug = Plug(monkeypatch)
    clock = VirtualClock()
    dev = make_bus(protocol=protocol, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url, DynamixelGripper(url, protocol=protocol, baudrate=dev.baud) as g:
        g.activate()
        assert g.lifecycle == Lifecycle.ACTIVE and dev.servo(1).torque_on
        plug.plugged = False
        with pytest.raises(NotConnected):
            g.state()
        if power_lost:
            dev.servo(1).reboot(clock.now_s(), 0.0)  # torque off, RAM defaults
        plug.plugged = True
        clock.advance(1.0)
        if power_lost:
            with pytest.raises(NotConnected, match="torque is off"):
                g.gripper_go(0.05, 0.3)
            assert g.lifecycle == Lifecycle.CONNECTED and not g.state().active
            g.activate()
        assert g.gripper_go(0.05, 0.3, blocking=False) == GripperOutcome.MOVING
        assert g.lifecycle == Lifecycle.ACTIVE and g.state().active and dev.servo(1).torque_on


def test_torque_lost_without_a_fault_reads_as_not_active(monkeypatch) -> None:
    clock = VirtualClock()
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev, clock) as url, DynamixelGripper(url) as g:
        g.activate()
        dev.servo(1).reboot(clock.now_s(), 0.0)  # a brown-out: no unplug seen by the host
        clock.advance(1.0)
        st = g.state()
        assert not st.active and st.hardware_error == 0 and g.lifecycle == Lifecycle.CONNECTED
        with pytest.raises(NotConnected, match="before activate"):
            g.gripper_go(0.05, 0.3)


def _symlink(link: str, target: str) -> None:
    tmp = link + ".new"
    os.symlink(target, tmp)
    os.replace(tmp, link)  # as udev updates /dev/serial/by-id/...


@pytest.mark.pty
def test_unplug_and_replug_over_a_pty(tmp_path) -> None:
    """A by-id style symlink to the pty: unplug = the server goes away (EIO) and the link vanishes;
    replug = a new pty behind the same link."""
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    link = str(tmp_path / "usb-FTDI_U2D2-if00-port0")
    server = PtyServer(dev).start()
    _symlink(link, server.port)
    try:
        with DynamixelBus(link, reconnect_policy=Reconnect(initial_s=0.05, max_s=0.2)) as bus:
            bus.write(1, "Goal Position", 1357)
            server.stop()
            os.unlink(link)
            with pytest.raises(NotConnected):
                bus.read(1, "Goal Position")
            assert not bus.port.is_using
            with pytest.raises(NotConnected):
                bus.ping(1)
            server = PtyServer(dev).start()
            _symlink(link, server.port)
            import time

            t_end = time.monotonic() + 5.0
            while True:  # wait out the backoff; each failed call is fast and typed
                try:
                    value = bus.read(1, "Goal Position")
                    break
                except NotConnected:
                    assert time.monotonic() < t_end, "the bus never reconnected"
                    time.sleep(0.02)
            assert value == 1357 and bus.stats.reconnects == 1
    finally:
        server.stop()


@pytest.mark.pty
def test_a_second_open_of_the_port_is_port_in_use() -> None:
    dev = make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0)
    with PtyServer(dev) as server:
        with DynamixelBus(server.port) as bus:
            # (the pty server counts client handles with inotify, which merges two IN_OPEN events in
            # a row: let it see the first open before the second one)
            assert bus.ping(1) == 311
            with pytest.raises(PortInUse, match=f"{server.port}.*already in use") as info:
                DynamixelBus(server.port)
            assert info.value.port == server.port and isinstance(info.value, NotConnected)
            assert bus.ping(1) == 311  # the first user is undisturbed
        with DynamixelBus(server.port) as again:  # released on close
            assert again.ping(1) == 311
            # and another process is refused as well, with the typed error naming the port
            import subprocess
            import sys

            code = ("from tactile_rig.drivers.dynamixel import DynamixelBus\n"
                    "from tactile_rig.core.errors import PortInUse\n"
                    "try:\n    DynamixelBus(%r)\nexcept PortInUse as e:\n    print('PortInUse', e.port)\n" % server.port)
            root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                                 env={**os.environ, "PYTHONPATH": root})
            assert out.stdout.strip() == f"PortInUse {server.port}", out.stderr
            assert again.ping(1) == 311


def test_typed_errors_only_from_a_cut_off_and_flipped_link() -> None:
    with _bus(2, faults="stall_after=5") as (bus, dev):
        with pytest.raises(LinkCorrupt):
            bus.read(1, "Model Number")
        assert not bus.port.is_using


def test_verify_that_never_agrees_is_link_corrupt() -> None:
    with _bus(1, ids=[1]) as (bus, dev):
        orig, n = dev.emit, [0]

        def emit(data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
            n[0] += 1  # every status a different (valid) value: a register that keeps changing
            return orig(wire.encode_status(1, 1, 0, n[0].to_bytes(2, "little")), t_s, delay_s=delay_s, reply=reply)

        dev.emit = emit
        with pytest.raises(LinkCorrupt, match="never agreed"):
            bus.read(1, "Goal Position", verify=True)
        assert bus.stats.verify_mismatches == bus.retries + 1


def test_an_id_write_with_a_lost_status_is_an_error_not_a_repeat() -> None:
    with _bus(2, ids=[1]) as (bus, dev):
        sent: list[bytes] = []
        orig = dev.feed
        dev.feed = lambda data, t_s: (sent.append(bytes(data)), orig(data, t_s))[1]
        LateReplies(dev, [None])
        with pytest.raises(DeviceTimeout):
            bus.write(1, "ID", 7)  # the servo answers to 7 now; reading ID 1 back would mislead
        assert dev.servo(7) is not None
        assert sum(1 for d in sent if d[7:8] == b"\x03") == 1 and bus.stats.writes_repeated_after_readback == 0


@pytest.mark.parametrize("protocol", [2, 1])
def test_after_a_long_silence_the_bus_answers_as_soon_as_the_line_is_back(protocol: int) -> None:
    """Dozens of failed requests (each one's status may still come) exhaust no resync: the bus
    never refuses to try, and the first request after the silence is answered."""
    # latency timer 0: timeouts of ~3 ms, so all 80 failures fall within LATE_HORIZON_S
    with _bus(protocol, ids=[1], latency_timer_ms=0) as (bus, dev):
        silent = LateReplies(dev, [None] * 80)
        failures = 0
        while True:
            try:
                model = bus.ping(1)
                break
            except DeviceTimeout:
                failures += 1
        assert silent.count > 80 and model == MODEL[protocol]  # answered once statuses came again
        assert failures >= 12 and bus.stats.resyncs > 64  # more than the lengths a resync can use
        assert bus.clock.now_s() < 1.0
        assert bus.read(1, "Model Number") == MODEL[protocol]


@pytest.mark.parametrize("protocol", [2, 1])
def test_group_reads_discard_a_late_status_and_return_the_true_values(protocol: int) -> None:
    with _bus(protocol) as (bus, dev):
        bus.write(1, "Goal Position", 1111)
        bus.write(2, "Goal Position", 2222)
        LateReplies(dev, [0.0, 0.060])  # ID 2's status of the first attempt comes 60 ms late
        got = bus.bulk_read([(1, "Goal Position"), (2, "Goal Position")])
        assert got == {1: 1111, 2: 2222} and bus.stats.retries == 1 and bus.stats.stale_packets >= 1
        if protocol == 2:
            LateReplies(dev, [0.060])
            assert bus.sync_read([1, 2], "Goal Position") == {1: 1111, 2: 2222}


@pytest.mark.parametrize("protocol", [2, 1])
def test_the_gripper_state_after_a_late_one_byte_status_is_the_true_state(protocol: int) -> None:
    """A 1-byte read times out and its status comes 60 ms late: the next block read (the gripper's
    state) must not take it (a 24-byte read returning 1 byte would read as an opening of -0.05 m)."""
    dev = make_bus(protocol=protocol, ids=[1], timing=True, return_delay_us=0)
    with serve_in_process(dev) as url:
        with DynamixelBus(url, protocol=protocol, baudrate=dev.baud, retries=0) as bus:
            g = DynamixelGripper(bus)
            LateReplies(dev, [0.060])
            with pytest.raises(DeviceTimeout):
                bus.read(1, "Torque Enable")
            st = g.state()
            servo = dev.servo(1)
            ticks = servo.item("Present Position")
            assert st.opening_frac == pytest.approx(g.calibration.frac_from_ticks(ticks))
            assert st.temperature_c == servo.item("Present Temperature")
            assert bus.stats.stale_packets == 1


def test_a_late_fast_sync_read_status_is_never_the_next_ones_answer() -> None:
    with _bus(2, retries=0) as (bus, dev):
        bus.sync_write("Goal Position", {1: 1111, 2: 2222})
        LateReplies(dev, [0.060])
        with pytest.raises(DeviceTimeout):
            bus.sync_read([1, 2], "Goal Position", fast=True)
        bus.sync_write("Goal Position", {1: 1500, 2: 2500})
        assert bus.sync_read([1, 2], "Goal Position", fast=True) == {1: 1500, 2: 2500}
        assert bus.stats.stale_packets == 1 and bus.stats.resyncs == 2
        assert bus.bulk_read([(1, "Model Number"), (2, "Goal Position")], fast=True) == {1: 311, 2: 2500}


@pytest.mark.pty
@pytest.mark.parametrize("protocol", [2, 1])
def test_over_a_pty_relay_late_and_split_statuses_never_give_a_wrong_value(protocol: int) -> None:
    """Real time, the real SDK sending, a relay holding statuses 60 ms and splitting others."""
    from tactile_rig.mocks.faults import FaultInjector
    from tactile_rig.mocks.relay import PtyRelay
    from tactile_rig.testing.serve import serve_on_pty

    dev = make_bus(protocol=protocol, ids=[1], timing=True, return_delay_us=0)
    faults = FaultInjector.from_query("late=0.2&late_s=0.06&split=0.3&seed=1")
    servo = dev.servo(1)
    with serve_on_pty(dev) as server, PtyRelay(server.port, faults, baudrate=dev.baud) as relay:
        with DynamixelBus(relay.port, protocol=protocol, baudrate=dev.baud) as bus:
            returned = 0
            for k in range(30):
                try:
                    if k % 3 == 0:
                        bus.write(1, "Goal Position", 1000 + 37 * k)
                        assert servo.item("Goal Position") == 1000 + 37 * k
                    elif k % 3 == 1:
                        assert bus.read(1, "Goal Position", verify=protocol == 1) == servo.item("Goal Position")
                    else:
                        assert bus.ping(1) == MODEL[protocol]
                    returned += 1
                except RigError:
                    pass
            assert returned >= 10 and faults.counts().get("late", 0) >= 1  # not vacuous


def test_the_latency_timer_knob_sets_how_late_a_status_may_be() -> None:
    """A status 20 ms late is in time for an adapter at the FTDI default (16 ms: twice it is
    allowed) and late for one set to 1 ms, where it is then discarded, never taken."""
    with _bus(2, ids=[1], retries=0) as (bus, dev):
        assert bus.latency_timer_ms == 16
        LateReplies(dev, [0.020])
        assert bus.read(1, "Model Number") == 311 and bus.stats.timeouts == 0
    with _bus(2, ids=[1], retries=0, latency_timer_ms=1) as (bus, dev):
        bus.write(1, "Goal Position", 3000)
        LateReplies(dev, [0.020])
        with pytest.raises(DeviceTimeout, match="1 ms allowed"):
            bus.read(1, "Model Number")
        bus.clock.sleep(0.05)
        assert bus.read(1, "Goal Position") == 3000 and bus.stats.stale_bytes + bus.stats.stale_packets >= 1
    with pytest.raises(ValueError, match="latency_timer_ms"):
        DynamixelBus("rigsim://dynamixel", latency_timer_ms=-1)


def test_a_value_the_servo_never_stores_is_read_again() -> None:
    """P1: a status damaged in two bytes so its checksum still holds, carrying a Goal Position of
    0xF0xx (the firmware refuses anything above 4095): read again, the true value returned."""
    with _bus(1, ids=[1]) as (bus, dev):
        bus.write(1, "Goal Position", 1000)
        orig, forged = dev.emit, []

        def emit(data: bytes, t_s: float, *, delay_s: float = 0.0, reply: bool = True) -> float:
            if not forged:
                p = bytearray(data)
                p[5], p[6] = (p[5] + 0xF0) & 0xFF, (p[6] - 0xF0) & 0xFF  # same 8-bit sum
                forged.append(bytes(p))
                data = bytes(p)
            return orig(data, t_s, delay_s=delay_s, reply=reply)

        dev.emit = emit
        assert bus.read(1, "Goal Position") == 1000
        assert bus.stats.implausible_values == 1
        assert int.from_bytes(wire.parse_status(1, forged[0])[0].params, "little") > 4095
