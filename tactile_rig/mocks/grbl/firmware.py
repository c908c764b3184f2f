"""GRBL 1.1h on a serial line: bytes in, the firmware's bytes out, with its timing.

What the host can tell, as the firmware does it (each piece cites its source in GRBL 1.1h):

* serial.c: realtime bytes (``? ! ~ ^X``, 0x84-0xA1) are picked off as they arrive; other bytes
  enter a 128-byte ring and are lost when it is full; bytes ≥ 0x80 that name no command are dropped.
* protocol.c: the main loop reads the ring one byte at a time, drops spaces and control characters,
  ``( )`` and ``;`` comments, upper-cases, and flags a line longer than 79 characters (``error:11``)
  however long the raw line was; it reads nothing while a line is executing (planner full, a sync,
  a dwell, homing), while a feed hold or a jog cancel is suspended, asleep or in a critical alarm.
* gcode.c (:mod:`.gcode`), system.c (``$`` commands, :mod:`.system`), report.c (:mod:`.report`),
  settings.c (EEPROM: settings, G54-G59, G28/G30, startup lines and build info survive resets).
* planner.c / stepper.c (:mod:`.planner`): junction-deviation look-ahead, trapezoids, feed hold,
  overrides; limits.c (:mod:`.homing`): seek, locate and pull-off, soft limits (ALARM:2 after a
  controlled stop), hard limits (ALARM:1, instant halt); motion_control.c: arcs, dwell, probing.
* main.c: the DTR reset on open (and a brown-out) is a power-up: step counters at zero, Alarm if
  homing is enabled; Ctrl-X keeps the position and the state (Idle stays Idle), and prints the
  banner, ``[MSG:Check Limits]`` on a pressed switch, the unlock hint in Alarm, else runs ``$N``.

Physical geometry: the stage's travel ranges are where its limit switches close; homing runs onto
the upper ones ($23 bits: the lower ones) and sets the machine position to −$27 there, so the
machine space is negative as on every GRBL machine. ``work_origin="stage"`` (the default with
homing) stores in the EEPROM's G54 the machine position of the stage's zero, as a lab sets up its
jig once (jog there, ``G10 L20 P1 X0 Y0 Z0``): work coordinates are then the stage pose. The switch
positions sit on whole motor steps from the stage's zero, so that zero is a reachable position.

This module is the protocol loop (main.c, protocol.c, serial.c): the receive ring, the line buffer,
the realtime flags, the alarm and reset states. Parsing, ``$`` commands, reports, planning, motion,
homing and the machine's settings and geometry are the modules beside it.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

import tactile_rig.mocks.grbl.gcode as gcode
import tactile_rig.mocks.grbl.report as report
import tactile_rig.mocks.grbl.system as system
from tactile_rig.core.clock import Clock
from tactile_rig.devices import grbl as gp
from tactile_rig.mocks.grbl.homing import HomingLeg
from tactile_rig.mocks.grbl.machine import Machine, default_settings
from tactile_rig.mocks.grbl.motion_control import OK, Job, MotionControl, Wait
from tactile_rig.mocks.grbl.planner import Planner, Profile
from tactile_rig.mocks.grbl.stepper import Stepper
from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.sim.world.stage import Stage

_LINE_DELAY_S = 0.0005  # an AVR parses and plans a line in about half a millisecond
_STATUS_DELAY_S = 0.002
ALARM_PAUSE_S = 0.5  # report_alarm_message: delay_ms(500) after every ALARM:N
LINE_BUFFER_SIZE = 80  # protocol.h: 79 characters and the terminator
RT_JOG_CANCEL, RT_SAFETY_DOOR = 0x85, 0x84


class GrblMock(MotionControl, Stepper, Machine, SerialDevice):
    """GRBL 1.1h on a serial line; see the module docstring. The stage pose is physical truth."""

    kind = "jig"
    #: a pty server holds the output this long after an open: the Uno's bootloader time, shortened
    open_hold_s = 0.05

    def __init__(self, *, clock: Clock | None = None, stage: Stage | None = None, axes: int = 3,
                 theta_axis: str = "Z", firmware: str = "grbl", baud: int = gp.BAUD, timing: bool = True,
                 seed: int = 0, homing: bool = True, boot_s: float = 0.0,
                 settings: dict[int, float] | None = None, work_origin: str | None = None) -> None:
        super().__init__(baud=baud, timing=timing, seed=seed)
        if axes not in (3, 4):
            raise ValueError(f"jig axes={axes!r}: GRBL 1.1 drives 3 axes (grblHAL 4)")
        if theta_axis not in gp.AXIS_LETTERS[:axes] or theta_axis in ("X", "Y"):
            raise ValueError(f"jig theta_axis={theta_axis!r} must be Z{' or A' if axes == 4 else ''} with {axes} axes")
        if firmware not in ("grbl", "grblhal"):
            raise ValueError(f"jig firmware={firmware!r}: expected 'grbl' or 'grblhal'")
        work_origin = work_origin or ("stage" if homing else "zero")
        if work_origin not in ("stage", "zero"):
            raise ValueError(f"jig work_origin={work_origin!r}: expected 'stage' or 'zero'")
        self.clock = clock
        self.n_axes = axes
        self.letters = gp.AXIS_LETTERS[:axes]
        self.axes_word = "".join(self.letters)
        self.theta_index = self.letters.index(theta_axis)
        self.firmware = firmware
        self.boot_s = float(boot_s)
        self.stage = stage if stage is not None else Stage()
        self.stage.attach(self)
        # -- EEPROM ----------------------------------------------------------------------------------
        self.settings = default_settings(axes, theta_axis)
        if not homing:
            self.settings[20] = self.settings[22] = 0  # hard limits stay: switches need no homing
        self.settings.update(settings or {})
        self.default_settings_ = dict(self.settings)  # this build's defaults.h, for $RST=$
        self._after_reply = None
        self.startup_lines = ["", ""]
        self.build_info = ""
        self.coords = [np.zeros(axes) for _ in range(8)]  # G54..G59, G28, G30 (machine mm)
        # -- the physical machine --------------------------------------------------------------------
        self._stage_axes = {0: 0, 1: 1, self.theta_index: 2}  # GRBL axis -> stage pose index
        self.phys_lo, self.phys_hi = self._switch_positions()
        if work_origin == "stage":  # where homing puts the stage's zero in machine coordinates
            negative = [bool(int(self.settings[23]) >> i & 1) for i in range(axes)]
            self.coords[0] = np.array([-self.phys_lo[i] - self._travel()[i] if negative[i] else -self.phys_hi[i]
                                       for i in range(axes)])
        self.origin = self._phys_from_stage()  # physical position of machine zero
        self.pos = np.zeros(axes)  # machine position, mm (deg on the θ channel)
        self.faults: list[tuple[float, str]] = []
        self.rx_overflow_bytes = 0
        self.rx_high_water = 0  # most bytes ever waiting in the receive buffer
        self.lines_executed = 0
        self._fail_next_homing = False
        self._t_now = 0.0 if clock is None else clock.now_s()
        self.state = "Idle"
        self._active: Profile | None = None
        self._home_leg: HomingLeg | None = None
        self._power_up(self._t_now, emit=False)

    # == power-up, resets, banner =================================================================
    def _power_up(self, t_s: float, *, emit: bool = True) -> None:
        """main(): the step counters start at zero wherever the stage is; Alarm if homing is on."""
        self._halt(t_s)
        self.origin = self.phys()
        self.pos = np.zeros(self.n_axes)
        self.state = "Alarm" if self.settings[22] else "Idle"
        self._boot(t_s + self.boot_s, emit=emit)
        self._booted_at = t_s + self.boot_s

    def _boot(self, t_s: float, *, emit: bool = True) -> None:
        """The re-initialisation loop of main() and the start of protocol_main_loop()."""
        self._t_now = max(self._t_now, t_s)
        self.feed_ovr, self.rapid_ovr, self.spindle_ovr = 100, 100, 100
        self.probe_pos = np.zeros(self.n_axes)
        self.probe_ok = False
        self.counters = report.ReportCounters()
        self.pos = self._quantize(self.pos)
        self.planner = Planner(self.n_axes)
        self.planner.reset(np.round(self.pos * self._steps()).astype(np.int64))
        self.gc = gcode.ParserState.fresh(self.n_axes, self.coords[0], self.pos)
        self.rx: deque[int] = deque()
        self._line: list[str] = []
        self._line_flags: set[str] = set()
        self._job: Job | None = None
        self._job_kind = "line"
        self._wait: Wait | None = None
        self._active = None
        self._event_t: float | None = None
        self._trip: tuple[str, int] | None = None  # what happens at _event_t: ("limit", axis) / ("probe", 0) / ("end", 0)
        self._hold = False  # a feed hold (or jog/motion cancel) is decelerating or complete
        self._hold_done = False
        self._cancel: str | None = None  # "jog" | "motion" (probe) | "soft" (soft limit)
        self._probe_active: tuple[bool, bool] | None = None  # (away, no_error)
        self._home_leg = None
        self._critical = False
        self._asleep = False
        self._busy_until = t_s
        self._status_pending = False
        if self.state not in ("Alarm", "Sleep"):
            self.state = "Idle"
        elif self.state == "Sleep":
            self.state = "Alarm"
        if not emit:
            return
        text = "GrblHAL 1.1f ['$' or '$HELP' for help]" if self.firmware == "grblhal" else gp.BANNER
        self.emit(b"\r\n" + text.encode() + b"\r\n", t_s, reply=False)
        if self.settings[21] and self._pressed():
            self.state = "Alarm"
            self._say(report.message("check_limits"), t_s)
        if self.state == "Alarm":
            self._say(report.message("alarm_lock"), t_s)
        elif any(self.startup_lines):
            self._job, self._wait, self._job_kind = self._startup_job(), None, "startup"

    def _startup_job(self) -> Job:
        """system_execute_startup: each stored block runs and reports ``>line:ok``."""
        for line in list(self.startup_lines):
            if line:
                status = yield from self._gcode_job(line, jog=False)
                self._say(report.startup_result(line, status), self._t_now)
        return -1  # no ok: nobody sent a line

    def on_open(self, t_s: float) -> None:
        self._power_up(t_s)  # the Uno resets on open (DTR): RAM is lost, the EEPROM kept

    def on_dtr(self, state: bool, t_s: float) -> None:
        if state:
            self.on_open(t_s)

    def inject(self, fault: str, *, axis: str = "X", t_s: float | None = None) -> None:
        """``hard_limit`` (a switch trips now, on ``axis``), ``homing_fail`` (the next $H finds no
        switch), ``reset`` (a brown-out or DTR glitch: the board reboots and prints its banner)."""
        t = t_s if t_s is not None else (self.clock.now_s() if self.clock is not None else self._t_now)
        self.advance_to(t)
        self.faults.append((t, fault))
        if fault == "hard_limit":
            if self.settings[21] and self.state != "Alarm" and self._home_leg is None:
                self._hard_limit(t)
        elif fault == "homing_fail":
            self._fail_next_homing = True
        elif fault == "reset":
            self._power_up(t)
        else:
            raise ValueError(f"jig mock: unknown fault {fault!r}; known: hard_limit, homing_fail, reset")

    def _say(self, text: str, t_s: float, delay_s: float = _LINE_DELAY_S) -> None:
        self.emit(text.encode() + b"\r\n", t_s, delay_s=delay_s)

    # == bytes in (serial.c's receive interrupt) ================================================
    def on_bytes(self, data: bytes, t_s: float) -> None:
        if t_s < self._booted_at:
            return  # the bootloader eats it
        self._t_now = max(self._t_now, t_s)
        for b in data:
            if b in (0x18, 0x3F, 0x7E, 0x21) or b >= 0x80:
                self._realtime(b, t_s)
            elif len(self.rx) < gp.RX_BUFFER_SIZE:
                self.rx.append(b)
                self.rx_high_water = max(self.rx_high_water, len(self.rx))
            else:
                self._consume(t_s)  # the main loop empties the ring while bytes arrive
                if len(self.rx) < gp.RX_BUFFER_SIZE:
                    self.rx.append(b)
                else:
                    self.rx_overflow_bytes += 1  # the ring is full: the AVR drops the byte
        self._consume(t_s)

    def _realtime(self, b: int, t_s: float) -> None:
        if b == 0x18:
            self._soft_reset(t_s)
            return
        if self._critical:
            return  # a critical alarm: only a reset is heard (no status either)
        if b == 0x3F:
            self._status_pending = True
            self._maybe_report(t_s)
            return
        if self._home_leg is not None or self._asleep:
            return
        if b == 0x21:
            self._feed_hold(t_s)
        elif b == 0x7E:
            self._cycle_start(t_s)
        elif b == RT_JOG_CANCEL:
            if self.state == "Jog":
                self._feed_hold(t_s)
        elif 0x90 <= b <= 0x9D:
            self._override(b, t_s)

    def _maybe_report(self, t_s: float) -> None:
        """Print a pending status report unless the firmware is busy (homing, an alarm pause)."""
        if not self._status_pending or self._home_leg is not None or t_s < self._busy_until - 1e-12:
            return
        self._status_pending = False
        self.emit(self._status_report(t_s).encode() + b"\r\n", t_s, delay_s=_STATUS_DELAY_S)

    def _override(self, b: int, t_s: float) -> None:
        f, r, s = self.feed_ovr, self.rapid_ovr, self.spindle_ovr
        if b <= 0x94:
            step = {0x90: None, 0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[b]
            f = 100 if step is None else int(min(200, max(10, f + step)))
        elif b <= 0x97:
            r = {0x95: 100, 0x96: 50, 0x97: 25}[b]
        elif 0x99 <= b <= 0x9D:
            step = {0x99: None, 0x9A: 10, 0x9B: -10, 0x9C: 1, 0x9D: -1}[b]
            s = 100 if step is None else int(min(200, max(10, s + step)))
        if (f, r) != (self.feed_ovr, self.rapid_ovr):
            self.feed_ovr, self.rapid_ovr = f, r
            self.counters.ovr = 0
            self._sync_active(t_s)
            self.planner.update_overrides(f, r)
            if self.planner.blocks and self._active is not None and not self._hold:
                self.planner.blocks[0].entry_sqr = self._speed_now(t_s) ** 2
            self.planner.recalculate()
            self._rebuild_active(t_s)
        if s != self.spindle_ovr:
            self.spindle_ovr = s
            self.counters.ovr = 0

    # == the protocol loop =========================================================================
    def _blocked(self, t_s: float) -> bool:
        suspended = (self._hold and self.state in ("Hold", "Jog")) or self._cancel is not None
        return self._critical or self._asleep or suspended or t_s < self._busy_until - 1e-12

    def _consume(self, t_s: float) -> None:
        """protocol_main_loop: resume the executing line, then read bytes while nothing blocks."""
        self._t_now = max(self._t_now, t_s)
        while True:
            if self._job is not None:
                if not self._resume_job(t_s):
                    break
                continue
            if self._blocked(t_s) or not self.rx:
                break
            c = self.rx.popleft()
            if c in (0x0A, 0x0D):
                line = "".join(self._line)
                overflow = "overflow" in self._line_flags
                self._line, self._line_flags = [], set()
                self._start_line(line, overflow, t_s)
            elif self._line_flags:
                if c == 0x29 and "paren" in self._line_flags:
                    self._line_flags.discard("paren")
            elif c <= 0x20 or c == 0x2F:
                pass  # whitespace, control characters and block delete are thrown away
            elif c == 0x28:
                self._line_flags.add("paren")
            elif c == 0x3B:
                self._line_flags.add("semicolon")
            elif len(self._line) >= LINE_BUFFER_SIZE - 1:
                self._line_flags.add("overflow")
            else:
                ch = chr(c)
                self._line.append(ch.upper() if "a" <= ch <= "z" else ch)
        self._auto_cycle_start(t_s)

    def _start_line(self, line: str, overflow: bool, t_s: float) -> None:
        if overflow:
            self._reply(11, t_s)
        elif not line:
            self._reply(OK, t_s)
        elif line[0] == "$":
            self._job, self._wait, self._job_kind = system.system_line(self, line), None, "line"
        elif self.state in ("Alarm", "Jog"):
            self._reply(9, t_s)
        else:
            self._job, self._wait, self._job_kind = self._gcode_job(line, jog=False), None, "line"

    def _reply(self, status: int, t_s: float) -> None:
        if status >= 0:
            self.lines_executed += 1
            self._say("ok" if status == OK else f"error:{status}", t_s)
        after, self._after_reply = self._after_reply, None
        if after is not None:
            after(t_s)  # a reset or sleep that system.c flags for after the reply

    def _sleep(self, t_s: float) -> None:
        """EXEC_SLEEP: ``[MSG:Sleeping]``, then nothing but realtime bytes until a reset."""
        self._halt(t_s)
        self.state = "Sleep"
        self._asleep = True
        self._say(report.message("sleeping"), t_s)

    def _ready(self, wait: Wait | None, t_s: float) -> bool:
        if wait is None:
            return True
        kind = wait[0]
        if kind == "space":
            return not self.planner.full()
        if kind == "idle":
            return not self.planner.blocks and self.state != "Run" and self._active is None
        if kind == "time":
            return t_s >= wait[1] - 1e-12
        if kind == "resume":
            return not self._hold
        if kind == "stopped":
            return self.state == "Idle" and self._active is None
        return False  # forever

    def _resume_job(self, t_s: float) -> bool:
        """Run the executing line until it waits; True when it is over (its reply sent, or a reset)."""
        job = self._job
        assert job is not None
        while True:
            if not self._ready(self._wait, t_s):
                if self._wait is not None and self._wait[0] == "space":
                    self._auto_cycle_start(t_s)  # mc_line starts the cycle when the planner is full
                return False
            try:
                wait = next(job)
            except StopIteration as done:
                if self._job is job:
                    self._job, self._wait = None, None
                    self._reply(int(done.value if done.value is not None else OK), t_s)
                return True
            if self._job is not job:
                return True  # a reset replaced it
            self._wait = wait

    def _auto_cycle_start(self, t_s: float) -> None:
        if self.planner.blocks and self.state == "Idle" and self._active is None and not self._hold:
            self.state = "Run"
            self._start_block(t_s)

    # == alarms and resets ====================================================================================
    def _halt(self, t_s: float) -> None:
        """Steppers off now: the position is where the motion was."""
        if self._active is not None:
            self.pos = self._active.point(self._active.at(t_s)[0])
        if self._home_leg is not None:
            self.pos = self._home_leg.position_at(t_s) - self.origin
            self._home_leg = None
        self._active = None
        if hasattr(self, "planner"):
            self.planner.blocks.clear()
        self._hold = self._hold_done = False
        self.pos = self._quantize(self.pos)

    def _alarm(self, code: int, t_s: float, *, critical: bool) -> None:
        """report_alarm_message: ``ALARM:N`` then a 500 ms pause; a critical one waits for a reset."""
        self.state = "Alarm"
        self._critical = critical
        self.emit(f"ALARM:{code}\r\n".encode(), t_s, reply=False)
        self._busy_until = max(self._busy_until, t_s + ALARM_PAUSE_S)
        if critical:
            self._status_pending = False
            self._say(report.message("critical"), t_s, delay_s=ALARM_PAUSE_S)

    def _hard_limit(self, t_s: float) -> None:
        self._halt(t_s)
        self._cancel = None
        self._alarm(1, t_s, critical=True)

    def _soft_reset(self, t_s: float) -> None:
        """Ctrl-X (mc_reset): ALARM:3 when moving (6 while homing), the blocked line's ok, reboot."""
        self.advance_to(t_s)
        alarm = None
        if self._home_leg is not None:
            alarm = 6
        elif self.state in ("Run", "Jog") or (self._hold and not self._hold_done):
            alarm = 3
        self._abort(t_s, alarm)

    def _abort(self, t_s: float, alarm: int | None) -> None:
        """A reset (mc_reset and the abort): the alarm, the blocked line's ``ok``, then the reboot."""
        self._halt(t_s)
        t_out = t_s
        if alarm is not None:
            self.state = "Alarm"
            self.emit(f"ALARM:{alarm}\r\n".encode(), t_s, reply=False)
            t_out = t_s + ALARM_PAUSE_S
        if self._job is not None and self._job_kind == "line":
            self._say("ok", t_out, delay_s=0.0)  # the executing line returns once the abort is seen
            self.lines_executed += 1
        self._critical = False
        self._asleep = False
        self._boot(t_out)

    # == time ========================================================================================
    def next_event_s(self) -> float | None:
        times = []
        if self._active is not None and self._event_t is not None:
            times.append(self._event_t)
        if self._job is not None and self._wait is not None and self._wait[0] == "time":
            times.append(self._wait[1])
        if self._busy_until > self._t_now:
            times.append(self._busy_until)
        return min(times) if times else None

    def on_tick(self, t_s: float) -> None:
        for _ in range(1_000_000):
            nxt = self.next_event_s()
            if nxt is None or nxt > t_s:
                break
            self._event(max(nxt, self._t_now))
        self._t_now = max(self._t_now, t_s)
        if self._active is not None:
            self.pos = self._active.point(self._active.at(t_s)[0])
        elif self._home_leg is not None:
            self.pos = self._home_leg.position_at(t_s) - self.origin
        self._write_stage(t_s)

    def _event(self, t_s: float) -> None:
        self._t_now = max(self._t_now, t_s)
        if self._active is not None and self._event_t is not None and self._event_t <= t_s:
            self._on_motion_event(t_s)
        if self._busy_until <= t_s:
            self._maybe_report(t_s)
        self._consume(t_s)

    # == reports =====================================================================================
    def _status_report(self, t_s: float) -> str:
        state = self.state
        if state == "Hold" and self._cancel is None:
            state = f"Hold:{0 if self._hold_done else 1}"
        elif state == "Hold":
            state = "Hold:1"
        pos = self.pos
        speed = 0.0
        if self._active is not None:
            d, v = self._active.at(t_s)
            pos, speed = self._active.point(d), v
        elif self._home_leg is not None:
            pos = self._home_leg.position_at(t_s) - self.origin
            speed = self._home_leg.profile.at(t_s)[1]
        pins = ("P" if self._probe_closed(pos) else "") + "".join(self.letters[i] for i in sorted(self._pressed(pos)))
        spindle_on = self.gc.modal.spindle in (3, 4) and self.gc.spindle_rpm > 0
        rpm = self.gc.spindle_rpm * self.spindle_ovr / 100.0 if spindle_on else 0.0
        acc = ("S" if self.gc.modal.spindle == 3 else "C") if spindle_on else ""
        acc += "F" if self.gc.modal.coolant_flood else ""
        snap = report.StatusSnapshot(
            state=state, mpos=self._quantize(pos), wco=self.wco, mask=int(self.settings[10]),
            inches=bool(self.settings[13]), planner_free=self.planner.available(), rx_free=gp.RX_BUFFER_SIZE - len(self.rx),
            feed_mm_per_min=speed * 60.0, spindle_rpm=rpm, pins=pins,
            overrides=(self.feed_ovr, self.rapid_ovr, self.spindle_ovr), accessories=acc,
            busy=self.state in ("Home", "Run", "Hold", "Jog"))
        return report.status_report(snap, self.counters)

    def describe(self) -> dict[str, Any]:
        return {"axes": self.n_axes, "theta_axis": self.letters[self.theta_index], "firmware": self.firmware,
                "homing": bool(self.settings[22]), "travel": [self.settings[130 + i] for i in range(self.n_axes)]}
