"""The driver template: reconnect with backoff, its fail-fast message, the shared counters, the line pump.

A toy :class:`PortDriver` whose cable the test pulls checks the template alone, in virtual time,
under any schedule of losses and returns; then the scale, the jig and the Dynamixel bus go
through the same unplug and replug over their mocks and must behave alike.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Callable

import pytest
from hypothesis import given, settings, strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import NotConnected
from tactile_rig.drivers.base import DriverStats, PortDriver, locked
from tactile_rig.drivers.dynamixel import DynamixelBus
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.lines import LineSplitter
from tactile_rig.drivers.reconnect import Reconnect
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.stage import Stage
from tactile_rig.testing import serve_in_process
from tests._plug import Plug

PORT = "/dev/ttyTOY0"
INITIAL_S, FACTOR, MAX_S = 0.1, 2.0, 0.8


@dataclass
class Cable:
    plugged: bool = True


class Toy(PortDriver):
    """A port driver whose device answers ``op()`` while the cable is in; records every reopen."""

    def __init__(self, clock: VirtualClock, cable: Cable, *, reopen_calls_op: bool = False) -> None:
        super().__init__("toy", reconnect_port=PORT)
        self.clock = clock
        self.cable = cable
        self.reopen_calls_op = reopen_calls_op
        self.reopens: list[tuple[float, bool]] = []  # (when, succeeded)
        self.releases = 0
        self.lost: list[str] = []
        self.backs = 0
        self.reconnect_policy = Reconnect(clock, initial_s=INITIAL_S, factor=FACTOR, max_s=MAX_S)

    @locked
    def op(self) -> str:
        if not self.cable.plugged:
            raise NotConnected(f"port {PORT!r} failed: unplugged (EIO)", device=self.device)
        return "ok"

    def _reopen(self) -> None:
        self.reopens.append((self.clock.now_s(), self.cable.plugged))
        if not self.cable.plugged:
            raise NotConnected(f"cannot open port {PORT!r}: [Errno 2] No such file or directory", device=self.device)
        if self.reopen_calls_op:
            self.op()  # identifying the device through a locked method must not reopen again

    def _release_port(self) -> None:
        self.releases += 1

    def _on_port_lost(self, reason: str) -> None:
        self.lost.append(reason)

    def _on_port_back(self) -> None:
        self.backs += 1


def _toy(**kw: Any) -> tuple[VirtualClock, Cable, Toy]:
    clock, cable = VirtualClock(), Cable()
    return clock, cable, Toy(clock, cable, **kw)


# -- the backoff -------------------------------------------------------------------------------------
def test_reconnect_backoff_grows_to_its_cap_and_resets() -> None:
    clock = VirtualClock()
    r = Reconnect(clock, initial_s=0.1, factor=3.0, max_s=0.5)
    assert not r.away and not r.due()
    r.lost("EIO")
    assert r.away and not r.due()
    waits = []
    for _ in range(4):
        clock.advance(r.next_attempt_s - clock.now_s())
        assert r.due()
        r.failed()
        waits.append(round(r.wait_s, 6))
    assert waits == [0.3, 0.5, 0.5, 0.5]
    assert "EIO" in str(r.not_connected("dev", "/dev/ttyUSB0")) and "/dev/ttyUSB0" in str(r.not_connected("d", "/dev/ttyUSB0"))
    clock.advance(0.5)
    r.succeeded()
    assert not r.away and r.reconnects == 1
    r.lost()
    assert r.next_attempt_s == pytest.approx(clock.now_s() + 0.1)  # back to the first wait
    with pytest.raises(ValueError, match="factor"):
        Reconnect(clock, factor=0.5)


def test_an_unplugged_port_fails_fast_naming_the_port_the_cause_and_the_next_attempt() -> None:
    clock, cable, toy = _toy()
    assert toy.op() == "ok"
    cable.plugged = False
    with pytest.raises(NotConnected, match="unplugged"):
        toy.op()
    assert toy.stats.disconnects == 1 and toy.releases == 1 and toy.lost == [f"toy: port {PORT!r} failed: unplugged (EIO)"]
    with pytest.raises(NotConnected) as info:
        toy.op()
    assert str(info.value) == (f"toy: port {PORT!r} is gone for 0 s (toy: port {PORT!r} failed: unplugged (EIO)); "
                               "next reconnect attempt in 0.1 s")
    clock.advance(0.06)
    with pytest.raises(NotConnected, match=r"gone for 0.06 s .*next reconnect attempt in 0.04 s"):
        toy.op()
    assert toy.reopens == []  # nothing was tried before the backoff allowed it


def test_a_reopen_that_fails_waits_longer_and_one_that_succeeds_counts_a_reconnect() -> None:
    clock, cable, toy = _toy()
    cable.plugged = False
    with pytest.raises(NotConnected):
        toy.op()
    for wait in (0.2, 0.4, 0.8, 0.8):  # doubling from 0.1 to the 0.8 s cap
        clock.advance(toy.reconnect_policy.next_attempt_s - clock.now_s())
        with pytest.raises(NotConnected, match=rf"cannot open port .*; next reconnect attempt in {wait:g} s") as info:
            toy.op()
        assert PORT in str(info.value)
    assert [ok for _, ok in toy.reopens] == [False] * 4 and toy.releases == 1 + 4
    cable.plugged = True
    with pytest.raises(NotConnected, match="next reconnect attempt"):
        toy.op()  # back, but the backoff is not over: still no attempt
    clock.advance(0.8)
    assert toy.op() == "ok"
    assert toy.reopens[-1][1] and toy.backs == 1
    assert (toy.stats.disconnects, toy.stats.reconnects, toy.reconnect_policy.reconnects) == (1, 1, 1)
    cable.plugged = False
    with pytest.raises(NotConnected):
        toy.op()
    assert toy.reconnect_policy.next_attempt_s == pytest.approx(clock.now_s() + INITIAL_S)  # the backoff starts over


def test_a_second_report_of_the_same_loss_changes_nothing() -> None:
    clock, cable, toy = _toy()
    toy._port_lost("EIO")
    toy._port_lost("EIO again")
    assert toy.stats.disconnects == 1 and toy.releases == 1 and toy.lost == ["EIO"]


def test_a_reopen_that_identifies_the_device_through_a_locked_method_reopens_once() -> None:
    clock, cable, toy = _toy(reopen_calls_op=True)
    cable.plugged = False
    with pytest.raises(NotConnected):
        toy.op()
    cable.plugged = True
    clock.advance(INITIAL_S)
    assert toy.op() == "ok"
    assert len(toy.reopens) == 1 and toy.stats.reconnects == 1


def test_a_closed_driver_is_never_reopened() -> None:
    clock, cable, toy = _toy()
    cable.plugged = False
    with pytest.raises(NotConnected):
        toy.op()
    toy.close()
    cable.plugged = True
    clock.advance(10.0)
    with pytest.raises(NotConnected, match="was closed"):
        toy.op()
    assert toy.reopens == []


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 0.6, allow_nan=False), st.booleans()), min_size=1, max_size=40))
def test_any_schedule_of_losses_and_returns_follows_the_backoff(steps: list[tuple[float, bool]]) -> None:
    """The backoff law, stated independently: after a loss at L the first attempt is due at
    L + initial; after a failed attempt at a the next is due at a + min(max, max(initial, factor x
    the last wait)). A call makes an attempt exactly when one is due, never more than one, and every
    failure is a NotConnected naming the port."""
    clock, cable, toy = _toy()
    away, due, wait = False, 0.0, 0.0
    losses = reconnects = failed_attempts = 0
    for dt, plugged in steps:
        clock.advance(dt)
        cable.plugged = plugged
        now = clock.now_s()
        before = len(toy.reopens)
        try:
            result: str | None = toy.op()
        except NotConnected as exc:
            assert PORT in str(exc)
            result = None
        attempts = toy.reopens[before:]
        assert len(attempts) <= 1
        if away:
            assert bool(attempts) == (now >= due), (now, due, attempts)
            if attempts and plugged:
                away = False
                reconnects += 1
                assert result == "ok"
            elif attempts:
                failed_attempts += 1
                wait = min(MAX_S, max(INITIAL_S, wait * FACTOR))
                due = now + wait
                assert result is None
            else:
                assert result is None  # fail fast
        else:
            assert not attempts
            if plugged:
                assert result == "ok"
            else:
                away, wait, due = True, INITIAL_S, now + INITIAL_S
                losses += 1
                assert result is None
        assert toy.reconnect_policy.away == away
    assert (toy.stats.disconnects, toy.stats.reconnects) == (losses, reconnects)
    assert toy.releases == losses + failed_attempts and toy.backs == reconnects


# -- every kind of driver goes through it ------------------------------------------------------------------
@dataclass
class Kind:
    mock: Callable[[VirtualClock], Any]
    open: Callable[[str, Reconnect], Any]
    touch: Callable[[Any], Any]  # a call that reads the port
    check: Callable[[Any], bool]  # the device answers sensibly


KINDS = {
    "scale": Kind(lambda clock: ScaleMock(clock=clock, spike_prob=0.0),
                  lambda url, policy: Scale(url, reconnect_policy=policy),
                  lambda d: d.poll(), lambda d: d.read().raw is not None),
    "jig": Kind(lambda clock: GrblMock(clock=clock, stage=Stage(), homing=False),
                lambda url, policy: Jig(url, reconnect_policy=policy),
                lambda d: d.status(), lambda d: d.status().state == "Idle"),
    "dynamixel": Kind(lambda clock: make_bus(protocol=2, ids=[1], timing=True, return_delay_us=0),
                      lambda url, policy: DynamixelBus(url, reconnect_policy=policy),
                      lambda d: d.ping(1), lambda d: d.ping(1) == 311),
}


@pytest.mark.parametrize("name", KINDS)
def test_each_kind_of_driver_loses_and_regains_its_port_through_the_template(monkeypatch, name: str) -> None:
    kind = KINDS[name]
    plug = Plug(monkeypatch)
    clock = VirtualClock()
    with serve_in_process(kind.mock(clock), clock) as url:
        policy = Reconnect(clock, initial_s=0.1, factor=2.0, max_s=0.4)
        with kind.open(url, policy) as drv:
            assert kind.check(drv)
            plug.plugged = False
            with pytest.raises(NotConnected, match="unplugged"):
                kind.touch(drv)
            opens = plug.opens
            with pytest.raises(NotConnected, match=rf"port '{re.escape(url)}' is gone .*next reconnect attempt in 0.1 s"):
                kind.touch(drv)
            assert plug.opens == opens  # failed fast
            clock.advance(0.1)
            with pytest.raises(NotConnected, match=rf"port '{re.escape(url)}' is gone .*No such file.*next reconnect "
                                                   r"attempt in 0.2 s"):
                kind.touch(drv)
            assert plug.opens == opens + 1
            plug.plugged = True
            clock.advance(0.2)
            assert kind.check(drv)
            assert isinstance(drv.stats, DriverStats) and drv.reconnect_policy is policy
            assert (drv.stats.disconnects, drv.stats.reconnects, policy.reconnects) == (1, 1, 1)
            assert {"disconnects", "reconnects"} <= set(drv.stats.to_dict())


# -- the line pump's splitter ---------------------------------------------------------------------------------
@settings(max_examples=200, deadline=None)
@given(lines=st.lists(st.binary(max_size=40).map(lambda b: b.replace(b"\n", b"")), max_size=20),
       cuts=st.lists(st.integers(0, 1000), max_size=30))
def test_lines_split_anywhere_come_out_whole_and_in_order(lines: list[bytes], cuts: list[int]) -> None:
    data = b"".join(line + b"\n" for line in lines)
    edges = [0, *sorted(c for c in cuts if c <= len(data)), len(data)]
    splitter = LineSplitter()
    got: list[bytes] = []
    for a, b in zip(edges, edges[1:]):
        got += splitter.feed(data[a:b])
    assert got == lines and splitter.pending == b""


@settings(max_examples=100, deadline=None)
@given(garbage=st.binary(min_size=0, max_size=300).map(lambda b: b.replace(b"\n", b"")),
       chunk=st.integers(1, 64), tail=st.binary(max_size=10).map(lambda b: b.replace(b"\n", b"")))
def test_a_run_without_a_newline_is_cut_to_its_tail(garbage: bytes, chunk: int, tail: bytes) -> None:
    splitter = LineSplitter(max_line=16)
    for k in range(0, len(garbage), chunk):
        assert splitter.feed(garbage[k:k + chunk]) == []
        assert len(splitter.pending) <= 16
    assert (splitter.overlong > 0) == (len(garbage) > 16)
    line = splitter.feed(tail + b"\n")
    assert line == [(garbage + tail)[-len(line[0]):]] and len(line[0]) <= 16 + len(tail)
