"""The scale driver against the emulated sketch, in virtual time (and a byte-exact exchange)."""

from __future__ import annotations

import os

import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.devices import scale as sp
from tactile_rig.drivers.scale import Scale, stable_port_path
from tactile_rig.drivers.transport import SerialTransport
from tactile_rig.core.errors import CalibrationError, DeviceTimeout, NotConnected
from tactile_rig.mocks.scale import ScaleMock, frame
from tactile_rig.sim import World
from tactile_rig.sim.world.load_cell import LoadCell
from tactile_rig.testing import expected_protocol, serve_in_process

G = sp.STANDARD_GRAVITY_MPS2


def _rig(**kw):
    clock = VirtualClock()
    mock = ScaleMock(clock=clock, **kw)
    return clock, mock


def test_mock_is_silent_for_the_bootloader_then_prints_its_banner() -> None:
    clock, mock = _rig(boot_s=1.6, boot_junk=False)
    with serve_in_process(mock, clock) as url:
        tr = SerialTransport(url, baudrate=sp.BAUD, device="scale")
        assert tr.read_some(100, 1.5) == b""  # nothing during the bootloader's 1.5 s
        line = tr.read_until(b"\n", 0.5)
    assert line.startswith(b"B,hx711-scale,1.1.0,80,")
    assert clock.now_s() >= 1.6


@pytest.mark.parametrize("rate", [10, 80])
def test_delivers_the_configured_rate_in_order_with_none_lost(rate: int) -> None:
    clock, mock = _rig(rate_sps=rate)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        assert scale.info.rate_sps == rate and scale.info.firmware == "hx711-scale"
        t0 = clock.now_s()
        got = scale.read_many(2 * rate)
        span = got[-1].t_host_s - got[0].t_host_s
    assert [r.seq for r in got] == list(range(got[0].seq, got[0].seq + 2 * rate))
    assert span == pytest.approx((2 * rate - 1) / rate, abs=1.5 / rate)
    assert clock.now_s() - t0 < 2.0 + 2.0 / rate
    assert scale.stats.dropped == 0 and scale.stats.bad_checksum == 0


def test_reads_the_load_from_the_world_and_converts_to_newtons() -> None:
    clock = VirtualClock()
    world = World(clock)
    cell = world.build("load_cell", "load_cell")
    mock = ScaleMock(clock=clock, load_cell=cell, spike_prob=0.0)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        assert abs(scale.read().grams) < 1.0
        cell.set_force_source(lambda t: 0.5 * G)  # 500 g pressing on the platform
        scale.read_many(40)  # the sketch's smoothing window refills
        r = scale.latest()
    assert r.grams == pytest.approx(500.0, abs=1.5)
    assert r.newtons == pytest.approx(0.5 * G, abs=0.02)
    assert r.raw > mock.offset_counts + 400 * mock.counts_per_g


def test_tare_and_known_mass_calibration_persist_across_a_reset() -> None:
    clock, mock = _rig(counts_per_g=720.0, spike_prob=0.0)  # the sketch's default 696 is wrong here
    with serve_in_process(mock, clock, name="scale-cal") as url:
        scale = Scale(url)
        mock.load_cell.applied_force_n = 0.05 * G  # 50 g of tray: tare it away
        scale.read_many(30)
        scale.tare()
        scale.poll()  # readings from before the confirmation were not tared yet
        assert abs(scale.read().grams) < 0.5
        with pytest.raises(CalibrationError, match="load too small"):
            scale.calibrate(200.0)  # nothing on the scale
        mock.load_cell.applied_force_n = 0.25 * G  # + 200 g
        scale.poll()
        scale.read_many(30)
        assert scale.latest().grams == pytest.approx(200 * 720 / 696, abs=1.0)
        factor = scale.calibrate(200.0)
        assert factor == pytest.approx(720.0, rel=0.005)
        scale.poll()
        scale.read_many(30)
        assert scale.latest().grams == pytest.approx(200.0, abs=0.5)
        scale.reconnect()  # the Arduino resets on open: the factor comes back from EEPROM
        assert scale.info.cal_factor_counts_per_g == pytest.approx(factor, abs=1e-3)
        with pytest.raises(ValueError, match="known_mass_g"):
            scale.calibrate(-5.0)


def test_dropped_and_corrupted_lines_are_all_accounted_for() -> None:
    clock, mock = _rig()
    with serve_in_process(mock, clock, name="scale-lossy"):
        scale = Scale("rigfault://rigsim://@scale-lossy#drop=0.002&flip=0.002&seed=4")
        got = scale.read_many(800, timeout_s=1.0)
        injected = scale.transport.serial.faults.counts()
    seqs = [r.seq for r in got]
    assert seqs == sorted(set(seqs))  # in order, never duplicated
    s = scale.stats
    assert s.readings + s.dropped == seqs[-1] - seqs[0] + 1  # every missing sample is counted
    assert s.dropped > 0 and s.bad_checksum > 0 and injected["drop"] > 0 and injected["flip"] > 0
    assert {e.kind for e in scale.events} >= {"drop", "checksum"}


def test_a_reset_mid_session_is_detected_and_numbering_restarts() -> None:
    clock, mock = _rig(boot_s=0.5)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        scale.read_many(20)
        mock.inject("reset")
        with pytest.raises(DeviceTimeout):
            scale.read_many(100)  # silent while the bootloader runs: stale after 0.5 s
        after = scale.read(timeout_s=1.0)
    assert scale.stats.resets == 1 and scale.events[-1].kind == "reset"
    assert after.seq == 0 and scale.stats.dropped == 0


def test_a_scale_that_stops_talking_raises_by_its_deadline() -> None:
    clock, mock = _rig(rate_sps=10)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url, stale_after_s=0.3)
        scale.read()
        mock.inject("hang")
        scale.poll()
        t0 = clock.now_s()
        with pytest.raises(DeviceTimeout, match="no reading for 0.3 s"):
            scale.read()
    assert clock.now_s() - t0 == pytest.approx(0.3, abs=1e-6)


def test_wrong_baud_and_an_unplugged_port_are_typed_errors() -> None:
    clock, mock = _rig()
    with serve_in_process(mock, clock) as url:
        with pytest.raises(DeviceTimeout, match="no banner and no valid reading"):
            Scale(url, baudrate=9600, boot_timeout_s=3.0)
    clock, mock = _rig(boot_s=0.1)
    with serve_in_process(mock, clock, name="scale-unplug"):
        scale = Scale("rigfault://rigsim://@scale-unplug#disconnect_after=2000")
        with pytest.raises(NotConnected, match="EIO|unplugged"):
            scale.read_many(1000)


def test_saturation_is_flagged_and_counted() -> None:
    clock, mock = _rig(spike_prob=0.0)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        mock.load_cell.applied_force_n = 200.0  # far past the 24-bit range at 696 counts/g
        got = scale.read_many(30)
    assert got[-1].raw == sp.RAW_MAX and got[-1].saturated
    assert scale.stats.saturated >= 1


def test_the_stock_hx711_adc_example_is_read_too() -> None:
    clock, mock = _rig(firmware="stock", rate_sps=10, boot_s=0.2)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        mock.load_cell.applied_force_n = 0.1 * G
        got = scale.read_many(30)
        scale.tare()
        with pytest.raises(CalibrationError, match="stock"):
            scale.calibrate(100.0)
    assert scale.format == "stock" and [r.seq for r in got] == list(range(30))
    assert got[-1].grams == pytest.approx(100.0, abs=1.0) and got[-1].raw is None


def test_tare_exchanges_exactly_these_bytes() -> None:
    banner = frame("B,hx711-scale,1.1.0,80,696.000")
    with expected_protocol([(None, banner), (b"t\n", frame("T,ok"))], baud=sp.BAUD) as url:
        scale = Scale(url)
        scale.tare(timeout_s=0.5)
        assert scale.info.cal_factor_counts_per_g == 696.0


def test_stable_path_prefers_the_by_id_link(tmp_path) -> None:
    dev = tmp_path / "ttyACM3"
    dev.write_text("")
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    link = by_id / "usb-Arduino_Uno_85735313-if00"
    os.symlink(dev, link)
    assert stable_port_path(str(dev), by_id) == str(link)
    assert stable_port_path("rigsim://scale", by_id) == "rigsim://scale"
    assert stable_port_path(str(tmp_path / "nope"), by_id) == str(tmp_path / "nope")


def test_load_cell_model_takes_a_settable_force_or_a_source() -> None:
    cell = LoadCell(applied_force_n=2.0, stiffness_n_per_mm=40.0)
    cell.advance_to(1.0)
    assert cell.force_n == 2.0 and cell.deflection_mm == pytest.approx(0.05)
    cell.set_force_source(lambda t: float("nan") if t > 5 else t)
    cell.advance_to(3.0)
    assert cell.force_n == 3.0
    cell.advance_to(6.0)
    assert cell.force_n == 0.0
    with pytest.raises(ValueError, match="capacity_n"):
        LoadCell(capacity_n=-1)


def test_warm_up_drift_creeps_in_over_minutes_and_a_new_tare_removes_it() -> None:
    clock, mock = _rig(rate_sps=10, drift_counts=1500.0, drift_tau_s=60.0, spike_prob=0.0)
    with serve_in_process(mock, clock) as url:
        scale = Scale(url)
        early = [r.grams for r in scale.read_many(20)]
        scale.read_many(3000)  # five minutes at 10 samples/s, nothing on the scale
        late = [r.grams for r in scale.read_many(20)]
        scale.tare()
        scale.poll()
        retared = [r.grams for r in scale.read_many(20)]
    mean = lambda xs: sum(xs) / len(xs)  # noqa: E731
    assert abs(mean(early)) < 0.3
    assert mean(late) > 1.5  # ~1500 counts of drift at 696 counts/g, minus what the boot tare caught
    assert abs(mean(retared)) < 0.3
