"""Exclusive ports and thread-safe drivers: a second handle on a port is ``PortInUse`` naming it;
four threads sharing one scale get every sample once, each thread in order, as the sketch sent it;
four threads sharing one jig see no spurious error."""

from __future__ import annotations

import threading

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import NotConnected, PortInUse
from tactile_rig.drivers.grbl import Jig
from tactile_rig.drivers.scale import Scale
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


def test_four_threads_reading_one_scale_get_every_sample_once_each_in_order_as_the_sketch_sent_it() -> None:
    clock = VirtualClock()
    mock = ScaleMock(clock=clock, spike_prob=0.0)
    sent: dict[int, tuple[int, float]] = {}  # seq -> (raw counts, grams) as the sketch printed them
    emit = mock._emit

    def record(data: bytes, t_write: float, *, reply: bool = False) -> None:
        body = data.decode("ascii").split("*")[0]
        if body.startswith("S,"):
            seq, grams, raw = body.split(",")[1:]
            sent[int(seq)] = (int(raw), float(grams))
        emit(data, t_write, reply=reply)

    mock._emit = record  # type: ignore[method-assign]
    per_thread: list[list] = [[] for _ in range(4)]
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)

        def body(i: int) -> None:
            for k in range(60):
                batch = [scale.read()] if (i + k) % 3 else scale.poll()
                if (i + k) % 5 == 0:
                    batch += scale.read_many(2)
                per_thread[i].extend(batch)

        errors = _run(4, body)
        assert not errors, errors[:3]
        assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0 and scale.stats.resets == 0
    for got in per_thread:  # each thread's calls follow one another: each sees the samples in order
        seqs = [r.seq for r in got]
        assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    every = sorted(r.seq for got in per_thread for r in got)
    assert every == list(range(every[0], every[0] + len(every)))  # none twice, none lost between
    for r in (r for got in per_thread for r in got):  # each is the sample the sketch sent, intact
        assert (r.raw, r.sketch_grams) == sent[r.seq] and r.grams == r.sketch_grams


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
