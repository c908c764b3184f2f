"""The scale keeps its zero: the driver computes grams from raw counts with its own zero, so a sketch
reboot (which re-tares at boot, load on or not) changes nothing a caller sees; a reboot is an event;
a stock sketch (no raw counts) that reboots gives ``ZeroLost``, never a wrong reading."""

from __future__ import annotations

import pytest
from hypothesis import given, strategies as st

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import ZeroLost
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import Scale, ScaleEvent, infer_zero_raw, mg_from_raw
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.sim.world.load_cell import LoadCell
from tactile_rig.testing import serve_in_process

G = sp.STANDARD_GRAVITY_MPS2


def _rig(**kw):
    clock = VirtualClock()
    cell = LoadCell()
    mock = ScaleMock(clock=clock, load_cell=cell, spike_prob=0.0, drift_counts=0.0, **kw)
    return clock, mock, cell


def _settle(scale: Scale, n: int = 40) -> float:
    """The mean of the readings after the smoothing window has filled with the new load."""
    got = scale.read_many(n)
    tail = got[-10:]
    return sum(r.grams for r in tail) / len(tail)


def test_a_reboot_with_the_load_on_changes_nothing_the_caller_sees() -> None:
    clock, mock, cell = _rig()
    events: list[ScaleEvent] = []
    with serve_in_process(mock, clock) as url:
        scale = Scale(url, on_event=events.append)
        before = scale.read_many(20)
        assert all(r.grams == r.sketch_grams for r in before)  # one zero: the sketch's grams, to the mg
        cell.applied_force_n = 0.2 * G  # 200 g
        assert _settle(scale) == pytest.approx(200.0, abs=0.5)
        mock.inject("reset")
        after = scale.read_many(60, timeout_s=5.0)
        assert scale.stats.resets == 1 and [e.kind for e in events if e.kind == "reset"] == ["reset"]
        # The sketch now says ~0 g (it tared at boot with 200 g on); the driver still says 200 g.
        assert after[-1].sketch_grams == pytest.approx(0.0, abs=0.5)
        assert sum(r.grams for r in after[-10:]) / 10 == pytest.approx(200.0, abs=0.5)
        cell.applied_force_n = 0.0
        assert _settle(scale) == pytest.approx(0.0, abs=0.5)


def test_a_tare_moves_the_zero_and_a_reboot_keeps_it() -> None:
    clock, mock, cell = _rig()
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        cell.applied_force_n = 0.05 * G  # a 50 g fixture
        _settle(scale)
        scale.tare()
        assert _settle(scale) == pytest.approx(0.0, abs=0.5)
        cell.applied_force_n = 0.15 * G
        assert _settle(scale) == pytest.approx(100.0, abs=0.5)
        mock.inject("reset")
        scale.read_many(60, timeout_s=5.0)
        assert _settle(scale) == pytest.approx(100.0, abs=0.5)
        assert scale.zero_raw is not None and not scale.zero_lost


def test_a_recalibration_is_followed_and_grams_still_equal_the_sketch() -> None:
    clock, mock, cell = _rig()
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        cell.applied_force_n = 0.1 * G
        _settle(scale)
        factor = scale.calibrate(120.0)  # say it is 120 g
        assert scale.cal_milli == round(factor * 1000)
        got = scale.read_many(30)
        assert got[-1].grams == got[-1].sketch_grams
        assert sum(r.grams for r in got[-10:]) / 10 == pytest.approx(120.0, abs=0.5)


def test_a_stock_sketch_that_reboots_gives_zero_lost_until_a_tare() -> None:
    clock, mock, cell = _rig(firmware="stock", rate_sps=10)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url, boot_timeout_s=8.0)
        scale.read_many(5)
        cell.applied_force_n = 0.2 * G
        scale.read_many(30)
        mock.inject("reset")
        with pytest.raises(ZeroLost):
            for _ in range(100):
                scale.read(timeout_s=5.0)
        assert scale.zero_lost and scale.stats.resets == 1
        with pytest.raises(ZeroLost):
            scale.latest(timeout_s=5.0)
        clock.advance(4.0)  # the sketch boots and settles again
        scale.tare(timeout_s=5.0)
        assert abs(scale.read(timeout_s=2.0).grams) < 1.0


@given(raw=st.integers(sp.RAW_MIN, sp.RAW_MAX), zero=st.integers(sp.RAW_MIN, sp.RAW_MAX),
       cal=st.integers(100, 100_000_000).flatmap(lambda c: st.sampled_from([c, -c])))
def test_the_zero_inferred_from_a_sample_reproduces_the_sketchs_grams(raw: int, zero: int, cal: int) -> None:
    mg = mg_from_raw(raw, zero, cal)
    z = infer_zero_raw(raw, mg, cal)
    assert z is not None and mg_from_raw(raw, z, cal) == mg
