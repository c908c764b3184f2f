"""GRBL 1.1h's ``$`` commands (system.c ``system_execute_line``) and setting writes (settings.c).

:func:`system_line` is a line's job on the firmware (a generator, like a G-code line): it prints
what report.c prints and returns the status code. The state checks are system.c's: ``$$`` refused
while running, ``$#``/``$H``/``$I``/``$N``/``$RST``/``$SLP``/settings only when Idle or Alarm,
``$N0=`` (which runs its block) and ``$C`` only when Idle, ``$J=`` when Idle or jogging.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

import tactile_rig.mocks.grbl.gcode as gcode
import tactile_rig.mocks.grbl.report as report
from tactile_rig.mocks.grbl.motion_control import Job

OK = 0
N_STARTUP_LINES = 2
_BOOLEAN = frozenset({4, 5, 6, 13, 20, 21, 22, 32})
_UINT8 = frozenset({0, 1, 2, 3, 10, 23, 26})
_FLOAT = frozenset({11, 12, 24, 25, 27, 30, 31})


def system_line(fw: Any, line: str) -> Job:
    """Execute one ``$`` line on ``fw`` (a ``GrblMock``); returns GRBL's status code (0 is ``ok``)."""
    say = _printer(fw)
    state = fw.state
    if len(line) == 1:
        say(report.HELP)
        return OK
    c = line[1]
    if c == "J":
        if state not in ("Idle", "Jog"):
            return 8
        if line[2:3] != "=":
            return 3
        status = yield from fw._gcode_job(line[3:], jog=True)
        return status
    if c in "$GCX":
        if len(line) > 2:
            return 3
        inches = bool(fw.settings[13])
        if c == "$":
            if state in ("Run", "Hold"):
                return 8
            for text in report.settings_lines(fw.settings):
                say(text)
        elif c == "G":
            g = fw.gc
            say(report.gcode_modes(g.modal, g.tool, g.feed_rate, g.spindle_rpm, inches))
        elif c == "C":
            if state == "Check":
                say(report.message("disabled"))
                fw._after_reply = fw._boot  # mc_reset: the ok, then the reboot
            else:
                if state != "Idle":
                    return 8
                fw.state = "Check"
                say(report.message("enabled"))
        elif state == "Alarm":  # $X
            say(report.message("unlocked"))
            fw.state = "Idle"
        return OK
    if state not in ("Idle", "Alarm"):
        return 8
    if c == "#":
        if len(line) > 2:
            return 3
        g = fw.gc
        for text in report.ngc_parameters(fw.coords, g.g92, g.tlo_mm, fw.probe_pos, fw.probe_ok,
                                          bool(fw.settings[13])):
            say(text)
        return OK
    if c == "H":
        if not fw.settings[22]:
            return 5
        fw.state = "Home"
        if len(line) > 2:
            return 3  # HOMING_SINGLE_AXIS_COMMANDS is off; GRBL leaves the state at Home here
        status = yield from fw.homing_job()
        return status
    if c == "S":
        if line != "$SLP":
            return 3
        fw._after_reply = fw._sleep
        return OK
    if c == "I":
        if len(line) == 2:
            for text in report.build_info(fw.build_info, fw.planner.capacity, 128):
                say(text)
            return OK
        if line[2] != "=":
            return 3
        fw.build_info = line[3:]
        return OK
    if c == "R":
        if line[2:5] != "ST=" or len(line) != 6 or line[5] not in "$#*":
            return 3
        what = line[5]
        if what in "$*":
            fw.settings = dict(fw.default_settings_)
        if what in "#*":
            fw.coords = [np.zeros(fw.n_axes) for _ in range(8)]
        if what == "*":
            fw.startup_lines = [""] * N_STARTUP_LINES
            fw.build_info = ""
        say(report.message("restore"))
        fw._after_reply = fw._boot
        return OK
    startup = c == "N"
    pos = 2 if startup else 1
    if startup:
        if len(line) == 2:
            for text in report.startup_lines(fw.startup_lines):
                say(text)
            return OK
        if state != "Idle":
            return 8
    got = gcode.read_float(line, pos)
    if got is None:
        return 2
    parameter, pos = got
    if line[pos:pos + 1] != "=":
        return 3
    pos += 1
    if startup:
        block = line[pos:]
        status = yield from fw._gcode_job(block, jog=False)  # the block runs to prove it is valid
        if status:
            return status
        index = int(math.trunc(parameter))
        if 0 <= index < N_STARTUP_LINES:
            fw.startup_lines[index] = block
        return OK
    got = gcode.read_float(line, pos)
    if got is None:
        return 2
    value, pos = got
    if pos != len(line) or parameter > 255:
        return 3
    return store_setting(fw, int(math.trunc(parameter)) & 0xFF, value)


def store_setting(fw: Any, n: int, value: float) -> int:
    """settings_store_global_setting: ``$n=value`` or GRBL's error code (no 30 kHz check: compiled out)."""
    if value < 0.0:
        return 4
    s = fw.settings
    if n >= 100:
        p, set_idx = n - 100, 0
        while set_idx < 4:
            if p < fw.n_axes:
                s[100 + 10 * set_idx + p] = float(value)
                return OK
            set_idx += 1
            if p < 10 or set_idx == 4:
                return 3
            p -= 10
        return 3
    int_value = int(math.trunc(value)) & 0xFF
    if n not in _BOOLEAN | _UINT8 | _FLOAT:
        return 3
    if n == 0 and int_value < 3:
        return 6
    if n == 20 and int_value and not s[22]:
        return 10
    if n in _BOOLEAN:
        s[n] = 1 if int_value else 0
    elif n in _UINT8:
        s[n] = int_value
    else:
        s[n] = float(value)
    if n == 22 and not int_value:
        s[20] = 0  # soft limits need homing: forced off
    if n == 13:
        fw.counters.wco = 0  # system_flag_wco_change
    return OK


def _printer(fw: Any) -> Any:
    def say(text: str) -> None:
        fw._say(text, fw._t_now)
    return say
