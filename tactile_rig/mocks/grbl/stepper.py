"""GRBL 1.1h's stepper, as the GRBL mock traces it: the executing planner block as a profile in time.

``planner.blocks[0]`` runs as a trapezoid from its entry to its exit speed; a new block or an
override re-plans it from where it is and how fast it goes (as ``st_update_plan_block_parameters``
does). A feed hold decelerates along the path, across blocks if it must, and ends in Hold:0; a jog
cancel or a probe's motion cancel ends in Idle with the rest flushed (protocol.c EXEC_CYCLE_STOP).
Each profile knows the next thing it runs into: a limit switch (hard limits: pin change interrupt),
the probe (the stepper's probe monitor) or its end. Mixed into
:class:`~tactile_rig.mocks.grbl.firmware.GrblMock`, whose state it uses.
"""

from __future__ import annotations

import math

import numpy as np

from tactile_rig.mocks.grbl.planner import Planner, Profile, block_phases
from tactile_rig.mocks.grbl.host import GrblHost


class Stepper(GrblHost):
    """Motion execution of the GRBL mock (a mixin of ``GrblMock``)."""

    def _speed_now(self, t_s: float) -> float:
        if self._active is None:
            return 0.0
        return self._active.at(t_s)[1]

    def _sync_active(self, t_s: float) -> None:
        """The executing block as the planner sees it: what remains of it, at the current speed."""
        if self._active is None or not self.planner.blocks:
            return
        d, v = self._active.at(t_s)
        self.pos = self._active.point(d)
        b = self.planner.blocks[0]
        b.millimeters = max(0.0, float(np.linalg.norm(b.target_mm - self.pos)))
        if not self._hold:
            b.entry_sqr = v * v

    def _rebuild_active(self, t_s: float) -> None:
        if self._active is None or self._hold or not self.planner.blocks:
            return
        self._start_block(t_s, v0=self._speed_now(t_s), from_pos=self.pos.copy())

    def _start_block(self, t_s: float, *, v0: float | None = None, from_pos: np.ndarray | None = None) -> None:
        """Trace ``planner.blocks[0]`` from ``from_pos`` (its start) at ``v0`` (its planned entry)."""
        b = self.planner.blocks[0]
        start = b.start_mm if from_pos is None else from_pos
        length = float(np.linalg.norm(b.target_mm - start))
        v_entry = math.sqrt(b.entry_sqr) if v0 is None else v0
        accel = b.accel
        if self._hold:
            stop = v_entry * v_entry / (2 * accel)
            if stop < length:
                phases = [(v_entry / accel, v_entry, -accel)] if v_entry > 0 else []
                length_run = stop
            else:
                length_run = length
                phases = block_phases(length, v_entry, v_entry, math.sqrt(max(v_entry ** 2 - 2 * accel * length, 0)),
                                      accel)
            self._active = Profile(np.array(start, float), b.unit, length_run, t_s, phases)
        else:
            v_nom = Planner.nominal_speed(b, self.feed_ovr, self.rapid_ovr)
            v_exit = math.sqrt(self.planner.exit_speed_sqr())
            self._active = Profile(np.array(start, float), b.unit, length, t_s,
                                   block_phases(length, v_entry, v_nom, v_exit, accel))
        self._find_event()

    def _find_event(self) -> None:
        """The next thing the executing profile runs into: a limit switch, the probe, or its end."""
        prof = self._active
        assert prof is not None
        self._event_t, self._trip = prof.t_end_s, ("end", 0)
        if self.settings[21]:
            ph0 = self.phys(prof.p0)
            pressed_at_start = set(self._pressed(prof.p0))
            for i in range(self.n_axes):
                u = prof.u[i]
                if abs(u) < 1e-12:
                    continue
                if i in pressed_at_start:
                    d = 1.0 / self._steps()[i] / abs(u)  # leaving a closed switch changes the pin too
                else:
                    bound = self.phys_hi[i] if u > 0 else self.phys_lo[i]
                    d = (bound - ph0[i]) / u + 1.0 / self._steps()[i] / abs(u)
                if 0 <= d <= prof.length:
                    te = prof.time_at_distance(d)
                    if te < self._event_t:
                        self._event_t, self._trip = te, ("limit", i)
        if self._probe_active is not None and self.planner.blocks and self.planner.blocks[0].kind == "probe":
            d = self._probe_distance(prof)
            if d is not None:
                te = prof.time_at_distance(d)
                if te <= self._event_t:
                    self._event_t, self._trip = te, ("probe", 0)

    def _probe_distance(self, prof: Profile) -> float | None:
        away = self._probe_active[0] if self._probe_active else False
        n = max(2, min(20000, int(prof.length / 0.005) + 2))
        ds = np.linspace(0.0, prof.length, n)
        prev = 0.0
        for d in ds[1:]:
            if self._probe_closed(prof.point(d), away=away):
                lo, hi = prev, float(d)
                for _ in range(40):
                    mid = 0.5 * (lo + hi)
                    if self._probe_closed(prof.point(mid), away=away):
                        hi = mid
                    else:
                        lo = mid
                return hi
            prev = float(d)
        return None

    def _on_motion_event(self, t_s: float) -> None:
        prof = self._active
        assert prof is not None
        kind, axis = self._trip or ("end", 0)
        d, _ = prof.at(t_s)
        if kind == "limit":
            self.pos = self._quantize(prof.point(d))
            if axis not in self._pressed():  # land on the closed switch, a step past its edge
                self.pos = prof.point(d)
            self._write_stage(t_s)
            self._hard_limit(t_s)
            return
        if kind == "probe":
            self.probe_pos = self._quantize(prof.point(d))
            self._probe_active = None
            self._cancel = "motion"
            self._feed_hold(t_s)
            return
        # the profile has run out
        self.pos = prof.point(prof.length)
        b = self.planner.blocks[0]
        finished = np.linalg.norm(b.target_mm - self.pos) < 1e-9 or not self._hold
        if finished:
            self.pos = b.target_mm.copy()
            self.planner.blocks.pop(0)
        else:
            b.millimeters = float(np.linalg.norm(b.target_mm - self.pos))
            b.entry_sqr = 0.0
        self._active = None
        v_end = prof.at(prof.t_end_s)[1]
        if self._hold and (v_end <= 1e-9 or not self.planner.blocks):
            self._cycle_stop(t_s)
            return
        if self.planner.blocks:
            if self._hold:
                b = self.planner.blocks[0]
                b.entry_sqr = v_end * v_end
            self._start_block(t_s)
        else:
            self._cycle_stop(t_s)

    def _cycle_stop(self, t_s: float) -> None:
        """EXEC_CYCLE_STOP: motion has come to rest."""
        self._active = None
        self.pos = self._quantize(self.pos)
        if self._hold and self._cancel is None and self.state == "Hold":
            self._hold_done = True  # hold complete: Hold:0 until '~'
            self.planner.recalculate()
            return
        if self._cancel == "jog":
            self.planner.reset(np.round(self.pos * self._steps()).astype(np.int64))
            self.gc.position = self.pos.copy()
        elif self._cancel == "motion":
            if self.planner.blocks:
                self.planner.blocks.pop(0)
        self._hold = self._hold_done = False
        if self._cancel in ("jog", "motion"):
            self._cancel = None
        self.state = "Idle"

    def _feed_hold(self, t_s: float) -> None:
        """EXEC_FEED_HOLD (and jog cancel, motion cancel): decelerate along the path."""
        if self.state in ("Alarm", "Check", "Sleep", "Home") or self._hold:
            return
        if self.state == "Idle":
            if self._cancel is None:
                self.state, self._hold, self._hold_done = "Hold", True, True
            return
        if self.state == "Jog":
            self._cancel = "jog"
        elif self._cancel is None:
            self.state = "Hold"
        self._sync_active(t_s)
        v = self._speed_now(t_s)
        self._hold, self._hold_done = True, False
        if self._active is not None and self.planner.blocks:
            self._start_block(t_s, v0=v, from_pos=self.pos.copy())
        else:
            self._cycle_stop(t_s)

    def _cycle_start(self, t_s: float) -> None:
        if self.state == "Hold" and self._hold_done:
            self._hold = self._hold_done = False
            if self.planner.blocks:
                self.planner.blocks[0].entry_sqr = 0.0
                self.planner.recalculate()
                self.state = "Run"
                self._start_block(t_s, from_pos=self.pos.copy())
            else:
                self.state = "Idle"
        elif self.state == "Idle":
            self._auto_cycle_start(t_s)
