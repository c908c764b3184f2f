"""The jig driver against the GRBL mock in virtual time: motion, limits, alarms, streaming, faults."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_rig.core.clock import VirtualClock
from tactile_rig.control.protocols import Motion, Pose
from tactile_rig.core.errors import GrblAlarm, GrblError, GrblReset
from tactile_rig.drivers.grbl import Jig
from tactile_rig.core.errors import DeviceTimeout, LimitError, NotConnected
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.sim import World
from tactile_rig.testing import serve_in_process

STEP_MM = 1 / 1600
STEP_DEG = 1 / 35.556


def _rig(**kw):
    clock = VirtualClock()
    world = World(clock)
    stage = world.build("stage", "stage")
    return clock, GrblMock(clock=clock, stage=stage, **kw), stage


def _assert_at(jig: Jig, stage, x: float, y: float, th: float) -> None:
    p = jig.pose()
    assert (p.x_mm, p.y_mm) == pytest.approx((x, y), abs=STEP_MM)
    assert p.theta_deg == pytest.approx(th, abs=STEP_DEG)
    stage.advance_to(jig.clock.now_s())
    assert stage.pose() == pytest.approx((p.x_mm, p.y_mm, p.theta_deg), abs=1e-3)  # G54 work position IS the stage pose


def test_boots_locked_then_homes_and_moves() -> None:
    clock, mock, stage = _rig()
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        assert jig.banner.startswith("Grbl 1.1") and jig.alarm_on_boot and jig.status().state == "Alarm"
        with pytest.raises(GrblError) as info:
            jig.move_to(1.0, 0.0, 0.0)
        assert info.value.code == 9 and "locked out" in str(info.value)
        jig.home()
        assert not jig.alarm_on_boot and jig.status().state == "Idle"
        t0 = clock.now_s()
        jig.move_to(5.0, -3.0, 90.0, wait=True)
        elapsed = clock.now_s() - t0
        _assert_at(jig, stage, 5.0, -3.0, 90.0)
    # A rapid is limited by the slowest axis: θ at 3600 deg/min needs at least 1.5 s for 90°.
    assert elapsed >= 90.0 / 60.0


def test_an_accuracy_run_takes_plausible_virtual_time_and_lands_on_every_pose() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url, x_range_mm=(-20, 20), y_range_mm=(-20, 20), theta_range_deg=(-180, 180))
        t0 = clock.now_s()
        for th in range(-90, 91, 10):
            jig.move_to(0.0, 0.0, float(th), wait=True)
            _assert_at(jig, stage, 0.0, 0.0, th)
        for x in range(-6, 7):
            jig.move_to(float(x), 0.0, 0.0, wait=True)
            _assert_at(jig, stage, x, 0.0, 0.0)
        elapsed = clock.now_s() - t0
    assert 5.0 < elapsed < 120.0  # seconds to minutes, like a real stepper jig; not instant, not hours


def test_a_rejected_line_is_a_typed_error_and_streaming_stops_there() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        with pytest.raises(GrblError) as info:
            jig.command("G1 X1")  # no feed rate yet
        assert info.value.code == 22 and "Feed rate has not yet been set" in str(info.value)
        with pytest.raises(GrblError) as info:
            jig.stream(["G90", "G1 X1 F600", "G1 X2 Q7", "G1 X3", "G1 X4"])
        assert info.value.code == 20 and "3: G1 X2 Q7" in str(info.value)
        jig.wait_idle()
        x = jig.pose().x_mm
    assert x == pytest.approx(1.0) or x == pytest.approx(3.0)  # lines already buffered may still run
    assert mock.lines_executed <= 5


def test_moves_past_the_travel_are_refused_by_the_host_and_alarmed_by_grbl() -> None:
    clock, mock, stage = _rig()
    with serve_in_process(mock, clock) as url:
        jig = Jig(url, x_range_mm=(-20, 20))
        jig.home()
        jig.move_to(0.0, 0.0, 0.0, wait=True)  # homing ends at the switches (-$27): back to the centre
        with pytest.raises(LimitError, match="x_mm=25"):
            jig.move_to(25.0, 0.0, 0.0)
        jig.ranges["x_mm"] = None
        jig.move_to(-10.0, 0.0, 0.0)  # still moving when the next line breaks the soft limit
        clock.advance(0.3)
        with pytest.raises(GrblAlarm) as info:
            jig.move_to(25.0, 0.0, 0.0, wait=True)
        assert info.value.code == 2
        with pytest.raises(GrblAlarm, match="no status until a soft reset"):
            jig.status()  # GRBL answers no '?' in a critical alarm
        jig.soft_reset()  # the position survives a reset
        st = jig.status()
        assert st.state == "Alarm" and -10.0 < st.wpos[0] < 0.0  # a controlled stop part-way
        clock.advance(1.0)
        assert jig.status().mpos == st.mpos  # and it stays stopped
        _assert_at(jig, stage, st.wpos[0], 0.0, 0.0)
        jig.unlock()
        jig.move_to(0.0, 0.0, 0.0, wait=True)
        _assert_at(jig, stage, 0.0, 0.0, 0.0)


def test_a_hard_limit_during_a_move_halts_at_the_switch() -> None:
    clock, mock, stage = _rig(homing=False)  # no soft limits: the switch is the last line of defence
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.move_to(30.0, 0.0, 0.0)
        with pytest.raises(GrblAlarm) as info:
            jig.wait_idle(10.0)
        assert info.value.code == 1 and "Hard limit" in str(info.value)
        with pytest.raises(GrblAlarm, match="only a soft reset"):
            jig.unlock()  # GRBL reads no line in a critical alarm: the driver does not send it
        jig.soft_reset()  # GRBL answers no '?' until then
        st = jig.status()
        assert st.state == "Alarm" and st.mpos[0] == pytest.approx(20.0, abs=0.002) and "X" in st.pins
        assert "[MSG:Check Limits]" in jig.messages  # the switch is still closed after the reset
        _assert_at(jig, stage, st.mpos[0], 0.0, 0.0)


def test_an_injected_limit_trip_and_an_unplug_mid_move_are_caught_by_their_deadlines() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.move_to(10.0, 0.0, 0.0)
        clock.advance(0.5)
        mock.inject("hard_limit", axis="Y")
        with pytest.raises(GrblAlarm, match="ALARM:1"):
            jig.wait_idle(5.0)
        jig.soft_reset()  # a critical alarm: no status report before a reset
        x = jig.status().mpos[0]
        clock.advance(1.0)
        assert 0.0 < x < 10.0 and jig.status().mpos[0] == x
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock, name="jig-unplug"):
        jig = Jig("rigfault://rigsim://@jig-unplug#disconnect_after=200")
        jig.move_to(10.0, 0.0, 0.0)
        t0 = clock.now_s()
        with pytest.raises(NotConnected, match="unplugged"):
            jig.wait_idle(30.0)
        assert clock.now_s() - t0 < 30.0


def test_wrong_baud_is_a_timeout_and_an_unexpected_banner_is_a_reset_error() -> None:
    clock, mock, stage = _rig()
    with serve_in_process(mock, clock) as url:
        with pytest.raises(DeviceTimeout, match="no GRBL banner"):
            Jig(url, baudrate=9600, boot_timeout_s=0.5)
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.move_to(5.0, 0.0, 0.0)
        clock.advance(0.2)
        mock.inject("reset")
        with pytest.raises(GrblReset, match="reset unexpectedly"):
            jig.wait_idle(5.0)
        assert jig.stats.resets == 1


def test_feed_hold_stops_and_resume_finishes_the_move() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.move_to(10.0, 0.0, 0.0)
        clock.advance(0.4)
        jig.feed_hold()
        clock.advance(1.0)
        st = jig.status()
        assert (st.state, st.substate) == ("Hold", 0)
        clock.advance(1.0)
        assert jig.status().mpos == st.mpos and 0 < st.mpos[0] < 10
        jig.resume()
        jig.wait_idle(10.0)
        _assert_at(jig, stage, 10.0, 0.0, 0.0)


def test_jog_cancel_stops_early_and_a_jog_past_travel_is_refused() -> None:
    clock, mock, stage = _rig(homing=False)
    mock.settings[20] = 1  # soft limits on (the jig is known to be at its centre)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.jog(dx_mm=-10.0, feed_mm_per_min=300.0)  # machine space is [-$130, 0]
        clock.advance(0.5)
        assert jig.status().state == "Jog"
        jig.jog_cancel()
        st = jig.wait_idle(2.0)
        assert -4.0 < st.mpos[0] < -1.0
        with pytest.raises(GrblError) as info:
            jig.jog(dx_mm=-50.0, feed_mm_per_min=300.0)
        assert info.value.code == 15


def test_settings_read_write_and_persist_through_a_soft_reset() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        s = jig.read_settings()
        assert s[22] == 0 and s[130] == 40.0 and s[132] == 360.0
        jig.write_setting(110, 300.0)
        with pytest.raises(GrblError) as info:
            jig.write_setting(24, -1.0)
        assert info.value.code == 4
        with pytest.raises(ValueError, match=r"\$77"):
            jig.write_setting(77, 1)
        jig.soft_reset()
        assert jig.read_settings()[110] == 300.0
        t0 = clock.now_s()
        jig.move_to(5.0, 0.0, 0.0, wait=True)
        assert clock.now_s() - t0 >= 5.0 / (300.0 / 60.0)  # the new max rate rules the rapid
        jig.write_setting(10, 2)  # WPos and buffer state
        st = jig.status()
        assert st.wpos is not None and st.planner_free == 15 and st.rx_free == 128


def test_character_counting_never_overflows_the_128_byte_buffer() -> None:
    clock, mock, stage = _rig(homing=False)
    lines = ["G21 G90 (square)", "G1 F900"]
    for i in range(60):
        lines += [f"G1 X{(i % 7) - 3:.3f} Y{(i % 5) - 2:.3f} Z{(i % 9) * 10 - 40:.3f} ; hop {i}"]
    lines += ["G0 X2.5 Y-1.5 Z33"]
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        res = jig.stream(lines)
        st = jig.wait_idle(120.0)
    assert res.sent == res.ok == len(lines) and not res.errors
    assert mock.rx_overflow_bytes == 0 and 64 < mock.rx_high_water <= 128
    assert st.mpos == pytest.approx((2.5, -1.5, 33.0), abs=STEP_DEG)


def test_check_mode_parses_without_moving() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        jig.set_check_mode(True)
        assert jig.status().state == "Check"
        res = jig.stream(["G1 X5 F100", "G0 Y3", "G4 P1"])
        with pytest.raises(GrblError) as info:
            jig.command("G1 X1 D3")
        assert res.ok == 3 and jig.status().mpos == (0.0, 0.0, 0.0) and info.value.code == 20
        jig.set_check_mode(False)  # GRBL resets on leaving check mode
        assert jig.status().state == "Idle" and jig.stats.resets == 0


def test_theta_on_the_a_channel_of_grblhal() -> None:
    clock, mock, stage = _rig(homing=False, axes=4, theta_axis="A", firmware="grblhal")
    with serve_in_process(mock, clock) as url:
        jig = Jig(url, theta_axis="A")
        assert jig.banner.startswith("GrblHAL")
        jig.move_to(1.0, 2.0, -45.0, wait=True)
        st = jig.status()
        assert len(st.mpos) == 4 and st.mpos[2] == 0.0
        _assert_at(jig, stage, 1.0, 2.0, -45.0)


def test_a_failed_homing_cycle_raises_its_alarm() -> None:
    clock, mock, stage = _rig()
    mock.inject("homing_fail")
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        with pytest.raises(GrblAlarm) as info:
            jig.home(timeout_s=60.0)
        assert info.value.code == 9 and "Could not find limit switch" in str(info.value)


def test_the_jig_is_a_motion_device() -> None:
    clock, mock, stage = _rig(homing=False)
    with serve_in_process(mock, clock) as url:
        jig = Jig(url)
        assert isinstance(jig, Motion)
        jig.move_toward(Pose(x_mm=4.0, y_mm=0.0, theta_deg=0.0), path_speed_mps=0.002)
        clock.advance(0.5)
        jig.move_toward(Pose(x_mm=-4.0, y_mm=1.0, theta_deg=0.0), path_speed_mps=0.004)  # replaces the first
        jig.wait_idle(10.0)
        _assert_at(jig, stage, -4.0, 1.0, 0.0)
        jig.move_to(8.0, 0.0, 0.0)
        clock.advance(0.3)
        jig.stop()
        p = jig.pose()
        clock.advance(1.0)
        assert jig.pose() == p and -4.0 < p.x_mm < 8.0 and jig.status().state == "Idle"
        with pytest.raises(ValueError, match="x_mm"):
            jig.move_to(math.nan, 0.0, 0.0)
    assert np.isfinite(stage.x_mm)
