"""Exclusive ports and thread-safe drivers: a second handle on a port is ``PortInUse`` naming it;
four threads sharing one scale or one jig see every sample once, in order, and no spurious error."""

from __future__ import annotations

import threading

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import NotConnected, PortInUse
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale, grams_mg
from tactile_rig.drivers.transport import SerialTransport
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.stage import Stage
from tactile_rig.testing import serve_in_process, serve_on_pty


def _run(workers: int, body) -> list[BaseException]:
    errors: list[BaseException] = []

    def run(i: int) -> None:
        try:
            body(i)
        except BaseException as exc:  # noqa: BLE001 - collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(workers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60.0)
    assert not any(t.is_alive() for t in threads), "a worker hung"
    return errors


def test_a_second_handle_on_a_device_path_is_port_in_use_naming_it() -> None:
    mock = ScaleMock(boot_s=0.05, spike_prob=0.0)
    with serve_on_pty(mock) as server:
        first = SerialTransport(server.port, baudrate=57600, device="scale")
        with pytest.raises(PortInUse) as info:
            SerialTransport(server.port, baudrate=57600, device="other")
        assert server.port in str(info.value) and "already in use" in str(info.value)
        assert isinstance(info.value, NotConnected) and info.value.port == server.port
        first.close()
        SerialTransport(server.port, baudrate=57600, device="other").close()  # free again


def test_a_driver_cannot_steal_a_port_another_driver_holds() -> None:
    mock = ScaleMock(boot_s=0.05, spike_prob=0.0)
    with serve_on_pty(mock) as server:
        with Scale(server.port, boot_timeout_s=5.0) as scale:
            with pytest.raises(PortInUse):
                Scale(server.port, boot_timeout_s=1.0)
            assert scale.read(timeout_s=2.0).raw is not None  # the first one is undisturbed


def test_four_threads_share_one_scale_without_losing_or_corrupting_a_sample() -> None:
    clock = VirtualClock()
    mock = ScaleMock(clock=clock, spike_prob=0.0)
    got: list = []
    lock = threading.Lock()
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)

        def body(i: int) -> None:
            for k in range(60):
                batch = [scale.read()] if (i + k) % 3 else scale.poll()
                if (i + k) % 5 == 0:
                    batch.append(scale.latest())
                with lock:
                    got.extend(batch)

        errors = _run(4, body)
        assert not errors, errors[:3]
        assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0 and scale.stats.resets == 0
    seqs = sorted(r.seq for r in got)
    # latest() consumes the ones before it: every sample is delivered at most once, and only a
    # latest() may skip some (they are counted as consumed, not lost on the wire).
    assert len(seqs) == len(set(seqs))
    assert all(r.grams == grams_mg(r.raw, scale.zero_raw, scale.cal_milli) / 1000 for r in got)


def test_four_threads_share_one_jig() -> None:
    clock = VirtualClock()
    mock = GrblMock(clock=clock, stage=Stage(), homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)

        def body(i: int) -> None:
            for k in range(25):
                if k % 3 == 0:
                    assert jig.command("G90") == []
                elif k % 3 == 1:
                    assert jig.status().state in ("Idle", "Run")
                else:
                    jig.pose()

        errors = _run(4, body)
        assert not errors, errors[:3]
        assert jig.stats.replies_lost == 0 and jig.stats.corrupt_reports == 0
