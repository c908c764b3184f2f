"""GRBL 1.1h's motion_control.c and gcode.c step 4, as jobs of the firmware's protocol loop.

A line's job is a generator: it runs a checked block the way ``gc_execute_line`` does (modal state,
spindle/coolant syncs, dwell, WCO syncs, EEPROM writes, G28/G30, motion, program flow) and yields
whenever the firmware would wait: for planner room (``mc_line``), for the buffer to empty
(``protocol_buffer_synchronize``), for time (dwell, homing), for a resume (M0) or for ever (a
critical alarm, until the reset ends it). Its return value is the line's status code. Homing
(``mc_homing_cycle``) and probing (``mc_probe_cycle``) are jobs too. Mixed into
:class:`~tactile_rig.mocks.grbl.firmware.GrblMock`, whose state it uses.
"""

from __future__ import annotations

from typing import Generator

import numpy as np

import tactile_rig.mocks.grbl.gcode as gcode
import tactile_rig.mocks.grbl.homing as homing
import tactile_rig.mocks.grbl.report as report
from tactile_rig.mocks.grbl.planner import arc_points
from tactile_rig.mocks.grbl.host import GrblHost

OK = 0
Wait = tuple  # ("space",) ("idle",) ("stopped",) ("time", t) ("resume",) ("forever",)
Job = Generator[Wait, None, int]


class MotionControl(GrblHost):
    """The G-code, homing and probing jobs of the GRBL mock (a mixin of ``GrblMock``)."""

    def _gcode_job(self, line: str, *, jog: bool) -> Job:
        block = gcode.parse_block(line, self.gc, self.coords, axes=self.axes_word, jog=jog)
        if isinstance(block, int):
            return block
        if jog:
            assert block.target is not None  # the parser gives every jog a target
            if self.settings[20] and self._beyond_travel(block.target):
                return 15
            yield from self._mc_line(block.target, block.feed_rate, kind="jog", no_feed_override=True)
            self.gc.position = np.array(block.target, float)
            if self.state == "Idle" and self.planner.blocks:
                self.state = "Jog"
                self._start_block(self._t_now)
            return OK
        before = self.gc
        self.gc = gcode.commit(self.gc, block)
        checking = self.state == "Check"
        speed_changed = block.spindle_rpm != before.spindle_rpm and before.modal.spindle != 5
        if (block.spindle_changed or block.coolant_changed or speed_changed) and not checking:
            yield ("idle",)  # spindle_sync / coolant_sync wait for the buffer to empty
        if block.non_modal == gcode.NM_DWELL and not checking:
            yield ("idle",)
            yield ("time", self._t_now + block.dwell_s)
        wco_changed = (block.tlo_mm is not None and block.tlo_mm != before.tlo_mm) or \
            block.modal.coord_select != before.modal.coord_select
        if wco_changed:
            self.counters.wco = 0
            yield ("idle",)  # FORCE_BUFFER_SYNC_DURING_WCO_CHANGE
        nm = block.non_modal
        if nm == gcode.NM_SET_COORD and block.coord_write is not None:
            yield ("idle",)  # FORCE_BUFFER_SYNC_DURING_EEPROM_WRITE
            slot, data = block.coord_write
            self.coords[slot] = np.array(data, float)
            if slot == block.modal.coord_select:
                self.counters.wco = 0
                yield ("idle",)
        elif nm in (gcode.NM_HOME0, gcode.NM_HOME1) and block.home_target is not None:
            if block.home_via_target:
                yield from self._mc_line(np.array(block.target, float), None)
            yield from self._mc_line(np.array(block.home_target, float), None)
            self.gc.position = np.array(block.home_target, float)
        elif nm in (gcode.NM_SET_HOME0, gcode.NM_SET_HOME1):
            yield ("idle",)
            self.coords[gcode.G28_INDEX if nm == gcode.NM_SET_HOME0 else gcode.G30_INDEX] = self.gc.position.copy()
        elif nm in (gcode.NM_SET_OFFSET, gcode.NM_RESET_OFFSET):
            self.counters.wco = 0
            yield ("idle",)
        if block.motion is not None:
            yield from self._motion(block, before)
        flow = block.modal.program_flow
        if flow:
            yield ("idle",)
            if flow == gcode.FLOW_PAUSED:
                if self.state != "Check":
                    self._feed_hold(self._t_now)
                    yield ("resume",)
            else:
                self.gc = gcode.program_end(self.gc, self.coords[0])
                self.feed_ovr, self.rapid_ovr, self.spindle_ovr = 100, 100, 100
                if self.state != "Check":
                    self.counters.wco = 0
                self._say(report.message("program_end"), self._t_now)
        return OK

    def _motion(self, block: gcode.Block, before: gcode.ParserState) -> Generator[Wait, None, None]:
        m = block.motion
        target = np.array(block.target, float)
        inverse = block.modal.inverse_time
        if m == gcode.SEEK:
            yield from self._mc_line(target, None)
        elif m == gcode.LINEAR:
            yield from self._mc_line(target, block.feed_rate, inverse_time=inverse)
        elif m in (gcode.CW_ARC, gcode.CCW_ARC):
            assert block.arc_offset is not None
            points = arc_points(before.position, target, block.arc_offset, block.arc_radius_mm, block.arc_axes,
                                block.clockwise, float(self.settings[12]))
            feed = block.feed_rate * (len(points) if inverse and len(points) > 1 else 1)
            seg_inverse = inverse and len(points) == 1
            for p in points:
                yield from self._mc_line(p, feed, inverse_time=seg_inverse)
                if self._critical:
                    return
        else:
            found = yield from self._probe_cycle(block)
            if found is None:
                return  # the parser keeps its position (probe check failed before moving)
            if found == "target":
                self.gc.position = target
            else:
                self.gc.position = self.pos.copy()
            return
        self.gc.position = target

    def _beyond_travel(self, target: np.ndarray) -> bool:
        """system_check_travel_limits: machine space is [−$13x, 0] on every axis."""
        return bool(np.any(target > 1e-9) or np.any(target < -self._travel() - 1e-9))

    def _mc_line(self, target: np.ndarray, feed: float | None, *, kind: str = "line", inverse_time: bool = False,
                 no_feed_override: bool = False) -> Generator[Wait, None, None]:
        """mc_line: soft limits, check mode, wait for planner space, plan."""
        if self.settings[20] and self.state != "Jog" and self._beyond_travel(target):
            yield from self._soft_limit()
            return
        if self.state == "Check":
            return
        while self.planner.full():
            yield ("space",)
        t = self._t_now
        self._sync_active(t)
        self.planner.buffer_line(target, feed, self._limits(), feed_ovr=self.feed_ovr, rapid_ovr=self.rapid_ovr,
                                 inverse_time=inverse_time, no_feed_override=no_feed_override, kind=kind)
        self._rebuild_active(t)

    def _soft_limit(self) -> Generator[Wait, None, None]:
        """limits_soft_check: a controlled stop first when moving, then ALARM:2 (critical)."""
        if self.state == "Run":
            self._cancel = "soft"
            self._feed_hold(self._t_now)
            while self.state != "Idle":
                yield ("stopped",)
        self._cancel = None
        self._halt(self._t_now)
        self._alarm(2, self._t_now, critical=True)
        while True:
            yield ("forever",)

    def _probe_cycle(self, block: gcode.Block) -> Generator[Wait, None, str | None]:
        """mc_probe_cycle: sync, check the probe is open, move until it closes, report [PRB:...]."""
        if self.state == "Check":
            return "target"
        yield ("idle",)
        self.probe_ok = False
        if self._probe_closed(away=block.probe_away):
            self._alarm(4, self._t_now, critical=False)
            yield ("time", self._busy_until)
            return None
        self._probe_active = (block.probe_away, block.probe_no_error)
        yield from self._mc_line(np.array(block.target, float), block.feed_rate, kind="probe", no_feed_override=True)
        if self.state == "Idle" and self.planner.blocks:
            self.state = "Run"
            self._start_block(self._t_now)
        yield ("idle",)
        if self._probe_active is not None:  # nothing touched
            self._probe_active = None
            if block.probe_no_error:
                self.probe_pos = self.pos.copy()
            else:
                self._alarm(5, self._t_now, critical=False)
                yield ("time", self._busy_until)
        else:
            self.probe_ok = True
        self.planner.reset(np.round(self.pos * self._steps()).astype(np.int64))
        self._say(report.probe_line(self.probe_pos, self.probe_ok, bool(self.settings[13])), self._t_now)
        return "system"

    def homing_job(self) -> Job:
        """mc_homing_cycle: cycle 0 (Z: θ), cycle 1 (X and Y), then A on four axes."""
        self.state = "Home"
        t = self._t_now
        setup = homing.HomingSetup(
            max_travel_mm=self._travel(),
            max_rate_mm_per_min=np.array([self.settings[110 + i] for i in range(self.n_axes)], float),
            accel_mm_per_s2=np.array([self.settings[120 + i] for i in range(self.n_axes)], float),
            seek_mm_per_min=float(self.settings[25]), feed_mm_per_min=float(self.settings[24]),
            pulloff_mm=float(self.settings[27]), debounce_s=float(self.settings[26]) / 1000.0,
            dir_negative=np.array([bool(int(self.settings[23]) >> i & 1) for i in range(self.n_axes)]),
            switch_at=np.array([self.phys_lo[i] if int(self.settings[23]) >> i & 1 else self.phys_hi[i]
                                for i in range(self.n_axes)]),
            switches_work=not self._fail_next_homing, steps_per_mm=self._steps())
        self._fail_next_homing = False
        cycles: list[tuple[int, ...]] = [(2,), (0, 1)] + ([(3,)] if self.n_axes == 4 else [])
        for axes in cycles:
            legs = homing.plan_cycle(self.phys(), axes, setup, t)
            for leg in legs:
                self._home_leg = leg
                yield ("time", leg.t_end_s)
                self.pos = leg.position_at(leg.t_end_s) - self.origin
                if leg.alarm is not None:
                    self._home_leg = None
                    self._abort(self._t_now, leg.alarm)
                    while True:
                        yield ("forever",)
                t = leg.t_end_s + setup.debounce_s
            yield ("time", t)
            for i in axes:
                ph = self.origin[i] + self.pos[i]
                self.pos[i] = self._quantize(np.full(self.n_axes, homing.homed_machine_position(i, setup)))[i]
                self.origin[i] = ph - self.pos[i]
        self._home_leg = None
        self._maybe_report(self._t_now)  # a '?' during homing is answered now, still in Home
        self.gc.position = self.pos.copy()
        self.planner.reset(np.round(self.pos * self._steps()).astype(np.int64))
        self.state = "Idle"
        for line in list(self.startup_lines):
            if line:
                status = yield from self._gcode_job(line, jog=False)
                self._say(report.startup_result(line, status), self._t_now)
        return OK
