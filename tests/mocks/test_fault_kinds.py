"""The fault kinds of ``rigfault://`` (late, split, stall, unplug, replug, reboot) and what the scale
and jig drivers make of them: typed errors, reconnection with backoff, never a wrong value."""

from __future__ import annotations

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import DeviceFault, DeviceTimeout, NotConnected, RigError
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.faults import FaultInjector
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.relay import PtyRelay
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.load_cell import LoadCell
from tactile_rig.sim.world.stage import Stage
from tactile_rig.testing import serve_in_process, serve_on_pty


def test_every_kind_parses_and_bad_values_are_refused() -> None:
    f = FaultInjector.from_query("duplicate=0.1&split=0.5&late=0.2&late_s=0.08&stall=0.01&unplug=0.01&"
                                 "replug=0.01&reboot=0.01&away_s=1&replug_s=0.2&stall_s=0.5")
    assert (f.dup, f.split, f.late, f.late_s, f.away_s) == (0.1, 0.5, 0.2, 0.08, 1.0)
    with pytest.raises(ValueError, match="late"):
        FaultInjector(late=2.0)
    with pytest.raises(ValueError, match="stall_s"):
        FaultInjector(stall_s=-1.0)


def test_split_and_late_chunks_arrive_whole_and_in_order() -> None:
    clock = VirtualClock()
    mock = ScaleMock(clock=clock, spike_prob=0.0, seed=1)
    with serve_in_process(mock, clock) as url:
        scale = Scale(f"rigfault://{url}#split=0.5&late=0.2&seed=3")
        got = scale.read_many(200)
        counts = scale.transport.serial.faults.counts()
    assert counts.get("split", 0) > 10 and counts.get("late", 0) > 10
    seqs = [r.seq for r in got]
    assert seqs == list(range(seqs[0], seqs[0] + 200))
    assert scale.stats.bad_checksum == 0 and scale.stats.dropped == 0


def _scale_session(query: str, n: int, grams: float = 150.0):
    clock = VirtualClock()
    cell = LoadCell(applied_force_n=grams / 1000 * 9.80665)
    mock = ScaleMock(clock=clock, load_cell=cell, spike_prob=0.0, drift_counts=0.0, seed=2)
    outcomes: dict[str, int] = {}
    values: list[float] = []
    with serve_in_process(mock, clock) as url:
        cell.applied_force_n = 0.0
        scale = Scale(f"rigfault://{url}#{query}")

        def warm(n: int) -> None:  # faults may strike here too: only typed errors are allowed
            got = 0
            while got < n:
                try:
                    scale.read()
                    got += 1
                except (NotConnected, DeviceTimeout):
                    clock.sleep(0.005)

        warm(30)
        cell.applied_force_n = grams / 1000 * 9.80665
        warm(40)
        for _ in range(n):
            try:
                values.append(scale.read().grams)
                key = "ok"
            except RigError as exc:
                key = type(exc).__name__
            outcomes[key] = outcomes.get(key, 0) + 1
            clock.sleep(0.005)
    return scale, outcomes, values


@pytest.mark.parametrize("query", ["unplug=0.01&away_s=0.3&seed=4", "replug=0.01&seed=5", "reboot=0.01&seed=6",
                                   "stall=0.01&stall_s=0.8&seed=7"])
def test_the_scale_survives_unplug_replug_reboot_and_stall_with_typed_errors_and_true_grams(query: str) -> None:
    scale, outcomes, values = _scale_session(query, 400)
    assert set(outcomes) <= {"ok", "NotConnected", "DeviceTimeout"}, outcomes
    assert outcomes.get("ok", 0) > 100
    # Whatever happened on the wire, every reading delivered is the true load (150 g) to within noise.
    assert all(abs(v - 150.0) < 1.0 for v in values), [v for v in values if abs(v - 150.0) >= 1.0][:5]
    if "unplug" in query or "replug" in query:
        assert scale.stats.disconnects >= 1 and scale.stats.reconnects >= 1
    if "reboot" in query:
        assert scale.stats.resets >= 1


def test_an_unplugged_jig_fails_fast_then_comes_back_in_fault_and_activates() -> None:
    clock = VirtualClock()
    mock = GrblMock(clock=clock, stage=Stage(), homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(f"rigfault://{url}#away_s=0.5")
        faults = jig.transport.serial.faults
        faults.unplug = 1.0  # the cable is pulled at the next bytes GRBL sends
        with pytest.raises(NotConnected):
            jig.status()
        faults.unplug = 0.0
        with pytest.raises(NotConnected, match="gone"):
            jig.status()  # fail fast: no reopen before the backoff allows it
        for _ in range(200):
            clock.sleep(0.05)
            try:
                jig.build_info()
                break
            except NotConnected:
                continue
        assert jig.stats.reconnects == 1
        with pytest.raises(DeviceFault):
            jig.move_to(1.0, 0.0, 0.0)  # GRBL rebooted: moves wait for activate()


def test_the_pty_relay_passes_bytes_and_an_unplug_there_is_not_connected_then_a_reconnect() -> None:
    mock = ScaleMock(boot_s=0.05, spike_prob=0.0)
    faults = FaultInjector(replug_s=0.2)
    with serve_on_pty(mock) as server, PtyRelay(server.port, faults, baudrate=57600, name="scale") as relay:
        with Scale(relay.port, boot_timeout_s=3.0) as scale:
            seqs = [r.seq for r in scale.read_many(20, timeout_s=1.0)]
            assert seqs == list(range(seqs[0], seqs[0] + 20))
            faults.replug = 1.0
            with pytest.raises(NotConnected):
                for _ in range(50):
                    scale.read(timeout_s=1.0)
            faults.replug = 0.0
            for _ in range(100):
                try:
                    scale.read(timeout_s=1.0)
                    break
                except (NotConnected, DeviceTimeout):
                    relay._stop.wait(0.05)
            assert scale.stats.disconnects == 1 and scale.stats.reconnects == 1 and relay.unplugs == 1
        assert relay.error is None
