"""GRBL 1.1h's replies, command by command: what a sender sees must be what GRBL 1.1h prints.

Each test's docstring names the firmware function (gnea/grbl v1.1h) whose behaviour it pins.
The host is virtual (tests/_grbl.py): bytes in at a time, the mock's exact output back.
"""

from __future__ import annotations

import re

import pytest

from tests._grbl import Host

BANNER = "Grbl 1.1h ['$' for help]"


def test_a_long_line_of_comment_is_read_through_and_only_79_kept_characters_count() -> None:
    """protocol.c protocol_main_loop: comments are dropped as they stream in, so a 200-byte line
    never fills the 128-byte ring; LINE_FLAG_OVERFLOW only when the 80th kept character arrives."""
    h = Host(homing=False)
    assert h.line("G0 X-1 (" + "a very long comment " * 10 + ")") == ["ok"]
    kept = "G0X-1." + "0" * 73  # 79 characters after stripping
    assert len(kept) == 79 and h.line(kept) == ["ok"]
    assert h.line(kept + "0") == ["error:11"]
    assert h.line("G0 X-" + "1 " * 120) == ["error:11"]  # 245 bytes, 125 kept
    assert h.line("G4 P0") == ["ok"]  # nothing after it is lost
    assert h.mock.rx_overflow_bytes == 0


def test_jogging_never_changes_the_modal_state() -> None:
    """gcode.c gc_execute_line: a $J= block runs jog_execute and copies only the position back;
    G91, G20 and F of the jog line never reach gc_state.modal."""
    h = Host(homing=False)
    assert h.line("G1 X-1 F120") == ["ok"]
    h.until_idle()
    assert h.line("$J=G91 G20 X-0.01 F100") == ["ok"]
    h.until_idle()
    gc = h.line("$G")
    assert gc == ["[GC:G1 G54 G17 G21 G90 G94 M5 M9 T0 F120 S0]", "ok"]


@pytest.mark.parametrize("how", ["ctrl-x", "check-off", "restore"])
def test_a_reset_while_unlocked_stays_unlocked(how: str) -> None:
    """main.c: sys.state survives the re-initialisation loop (prior_state); HOMING_INIT_LOCK applies at
    power-up only, so a reset from Idle prints the banner alone and G-code runs on (protocol.c)."""
    h = Host()
    assert h.boot == ["", BANNER, "[MSG:'$H'|'$X' to unlock]"][1:]
    assert h.line("$X") == ["[MSG:Caution: Unlocked]", "ok"]
    if how == "ctrl-x":
        out = h.send(b"\x18")
    elif how == "check-off":
        assert h.line("$C") == ["[MSG:Enabled]", "ok"]
        out = h.line("$C")
        assert out[:2] == ["[MSG:Disabled]", "ok"]
        out = out[2:]
    else:
        out = h.line("$RST=$")
        assert out[:2] == ["[MSG:Restoring defaults]", "ok"]
        out = out[2:]
    assert out == [BANNER]
    assert h.status().startswith("<Idle|")
    assert h.line("G0 X-0.5") == ["ok"]


def test_startup_blocks_run_after_the_banner() -> None:
    """system.c system_execute_startup, report.c report_execute_startup_message: each stored $N
    block runs after a reset when not in Alarm and prints '>block:ok'."""
    h = Host(homing=False)
    assert h.line("$N0=G20") == ["ok"]
    assert h.line("$N") == ["$N0=G20", "$N1=", "ok"]
    assert h.send(b"\x18") == [BANNER, ">G20:ok"]
    assert "G20" in h.line("$G")[0]


def test_soft_limits_hold_in_check_mode() -> None:
    """motion_control.c mc_line: limits_soft_check runs before the check-mode return; limits.c:
    mc_reset then EXEC_ALARM_SOFT_LIMIT, a critical alarm (protocol.c) that locks until a reset."""
    h = Host(work_origin="zero")
    h.line("$X")
    assert h.line("$C") == ["[MSG:Enabled]", "ok"]
    assert h.line("G0 X-50", 0.2) == ["ALARM:2"]
    assert h.read(0.5) == ["[MSG:Reset to continue]"]
    assert h.status(0.5) is None and h.line("$X", 0.5) == []


def test_disabling_homing_forces_soft_limits_off() -> None:
    """settings.c settings_store_global_setting case 22: clearing $22 clears the soft-limit flag."""
    h = Host()
    assert h.line("$22=0") == ["ok"]
    settings = h.line("$$")
    assert "$20=0" in settings and "$22=0" in settings
    assert h.line("$20=1") == ["error:10"]


def test_sleep_answers_ok_then_sleeps_until_a_reset() -> None:
    """system.c '$SLP' sets EXEC_SLEEP and returns ok; protocol.c protocol_exec_rt_suspend prints
    [MSG:Sleeping] and loops on realtime commands only until reset."""
    h = Host(homing=False)
    assert h.line("$SLP") == ["ok", "[MSG:Sleeping]"]
    assert h.line("G0 X-1", 1.0) == []
    assert h.status().startswith("<Sleep|MPos:0.000,0.000,0.000")
    assert h.stage.pose() == (0.0, 0.0, 0.0)
    assert h.send(b"\x18") == [BANNER, "[MSG:'$H'|'$X' to unlock]"]  # a sleep re-initialises as Alarm


def test_no_invented_step_rate_limit() -> None:
    """config.h: MAX_STEP_RATE_HZ is commented out in 1.1h, so settings.c never returns error:12."""
    h = Host(homing=False)
    assert h.line("$100=1600") == ["ok"]
    assert h.line("$110=1500") == ["ok"]
    assert h.line("$110=1200") == ["ok"]
    assert h.line("$100=16000") == ["ok"]


def test_status_waits_for_homing_and_stops_after_a_critical_alarm() -> None:
    """limits.c limits_go_home never runs protocol_execute_realtime: a '?' is answered when mc_homing_cycle
    ends (state still Home, before $H's ok); protocol.c loops on EXEC_RESET alone after ALARM:1/2."""
    h = Host()
    h.line("$H", 0.01)
    assert h.send("?", 1.0) == []
    out = h.read(30.0)
    assert out[0].startswith("<Home|MPos:-1.000,-1.000,-1.01") and out[1:] == ["ok"]
    assert h.line("G90 G0 X25", 0.1) == ["ALARM:2"]  # G54 is the travel centre: X25 is past it
    assert h.read(0.6) == ["[MSG:Reset to continue]"]
    assert h.status(1.0) is None


def test_the_line_that_raised_a_soft_limit_is_answered_after_the_reset() -> None:
    """limits.c limits_soft_check returns once the reset aborts the critical loop; gc_execute_line
    then returns STATUS_OK, so its ok precedes the banner (main.c)."""
    h = Host(work_origin="zero")
    h.line("$X")
    assert h.line("G0 X5", 1.0) == ["ALARM:2", "[MSG:Reset to continue]"]
    assert h.send(b"\x18") == ["ok", BANNER, "[MSG:'$H'|'$X' to unlock]"]


def test_report_inches_prints_four_decimals_and_feed_in_inches() -> None:
    """report.c printFloat_CoordValue / printFloat_RateValue follow $13 (4 and 1 decimals)."""
    h = Host(homing=False)
    h.line("G0 X-12.7")
    h.until_idle()
    assert h.line("$13=1") == ["ok"]
    st = h.status()
    assert st.startswith("<Idle|MPos:-0.5000,0.0000,0.0000|FS:0.0,0|WCO:0.0000,0.0000,0.0000")
    assert h.line("$#")[0] == "[G54:0.0000,0.0000,0.0000]"


def test_g43_1_sets_a_tool_length_offset_and_moves_nothing() -> None:
    """gcode.c step 14: G43.1 stores the offset of TOOL_LENGTH_OFFSET_AXIS (Z) and flags a WCO change."""
    h = Host(homing=False)
    assert h.line("G43.1 Z0.5") == ["ok"]
    assert "[TLO:0.500]" in h.line("$#")
    st = h.status()
    assert st.startswith("<Idle|MPos:0.000,0.000,0.000") and "WCO:0.000,0.000,0.500" in st
    assert h.stage.pose() == (0.0, 0.0, 0.0)
    assert h.line("G43.1 X1") == ["error:37"]


def test_homing_ends_pulled_off_in_negative_machine_space() -> None:
    """limits.c limits_go_home: sys_position = -$27 on each homed axis (HOMING_FORCE_SET_ORIGIN off);
    system.c system_check_travel_limits: a target > 0 is a soft-limit violation (ALARM:2)."""
    h = Host(work_origin="zero")
    assert h.line("$H", 40.0) == ["ok"]
    st = h.status()
    assert re.match(r"<Idle\|MPos:-1\.000,-1\.000,-1\.01\d\|", st)
    switch_deg = 6400 / 35.556  # the θ switch closes at 180°, on the motor's step grid
    pulloff_deg = 36 / 35.556  # lround($27 x $102) whole steps
    assert h.stage.pose() == pytest.approx((19.0, 19.0, switch_deg - pulloff_deg), abs=1e-9)
    assert h.line("G0 X5", 0.1) == ["ALARM:2"]


@pytest.mark.parametrize("line,reply", [("$=5", "error:2"), ("G59.1", "error:23"), ("G0 G1 X-1", "error:24"),
                                        ("N-1", "error:4"), ("G10 L2 X0", "ok"), ("N1.5 G0 X0", "ok"),
                                        ("G17 G18", "error:21"), ("M7", "error:20")])
def test_error_codes_follow_the_firmwares_check_order(line: str, reply: str) -> None:
    """system.c (read_float before '='), gcode.c step 2 (mantissa → 23, axis command conflict → 24,
    negative N → 4, N truncated; G10 needs L or P, not both; modal group 2 twice → 21; ENABLE_M7 off)."""
    h = Host(homing=False)
    assert h.line(line) == [reply]


def test_cosmetics_settings_modes_program_end_and_reports() -> None:
    """report.c: $30/$31 with N_DECIMAL_RPMVALUE (0); $G prints the plane and F in mm/min unless
    $13; gcode.c M30 prints [MSG:Pgm End]; system.c $RST=# resets; settings.c $13 flags a WCO refresh."""
    h = Host(homing=False)
    settings = h.line("$$")
    assert "$30=1000" in settings and "$31=0" in settings and "$11=0.010" in settings
    h.line("G18 G20 G1 F10")
    assert h.line("$G")[0] == "[GC:G1 G54 G18 G20 G90 G94 M5 M9 T0 F254 S0]"
    assert h.line("M30") == ["[MSG:Pgm End]", "ok"]
    assert h.line("$RST=#") == ["[MSG:Restoring defaults]", "ok", BANNER]
    h.status()
    assert "WCO:" not in h.status()
    h.line("$13=0")
    assert "WCO:" in h.status()


def test_every_alarm_is_followed_by_a_half_second_pause() -> None:
    """report.c report_alarm_message: delay_ms(500) after ALARM:N, during which nothing is printed."""
    h = Host(homing=False)
    h.line("G1 X-10 F600", 0.2)
    assert h.send(b"\x18", 0.1) == ["ALARM:3"]
    assert h.send("?", 0.3) == []
    out = h.read(0.2)
    assert out[0] == BANNER and out[1] == "[MSG:'$H'|'$X' to unlock]"


def test_build_info_startup_lines_and_a_full_restore() -> None:
    """system.c: '$I=' stores the build-info text (ENABLE_BUILD_INFO_WRITE_COMMAND), '$Nx=' only when
    Idle (error:8 in Alarm), '$RST=*' wipes settings, coordinates, startup lines and build info."""
    h = Host()
    assert h.line("$N0=G21") == ["error:8"]  # locked in Alarm: startup lines are stored only when Idle
    assert h.line("$I=jig 7") == ["ok"]
    assert h.line("$I")[0] == "[VER:1.1h.20190830:JIG7]"  # the protocol loop upper-cases and drops spaces
    h.line("$X")
    assert h.line("$N1=G91") == ["ok"] and h.line("$N")[:2] == ["$N0=", "$N1=G91"]
    h.line("$110=300")
    assert h.line("$RST=*") == ["[MSG:Restoring defaults]", "ok", BANNER]  # no $N1 left to run
    assert h.line("$I")[0] == "[VER:1.1h.20190830:]" and h.line("$N")[:2] == ["$N0=", "$N1="]
    assert "$110=1200.000" in h.line("$$")


def test_homing_runs_the_startup_blocks_and_needs_homing_enabled() -> None:
    """system.c '$H': STATUS_SETTING_DISABLED (5) with $22=0; after a successful cycle
    system_execute_startup runs the $N blocks (their '>line:ok' before $H's own ok)."""
    assert Host(homing=False).line("$H") == ["error:5"]
    h = Host()
    h.line("$X")
    assert h.line("$N0=G20") == ["ok"]
    assert h.line("$H", 40.0) == [">G20:ok", "ok"]
    assert h.line("$SLP") == ["ok", "[MSG:Sleeping]"]
