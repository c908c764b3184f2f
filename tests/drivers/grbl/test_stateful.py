"""A stateful test: random jig command sequences against a model never lose position or state.

Positions are G54 work coordinates: the mock's EEPROM holds G54 at the middle of the travel (as a
commissioned jig's would), so after homing (which ends −$27 from the switches, machine space
negative as in limits.c) the work position is the stage pose.
"""

from __future__ import annotations

import pytest
from hypothesis import settings, strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from tactile_rig.core.clock import VirtualClock
from tactile_rig.core.errors import GrblAlarm
from tactile_rig.drivers.grbl import Jig
from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.mocks.registry import register_instance, unregister_instance
from tactile_rig.sim.world.stage import Stage

REPORT_RES = 0.001  # status reports print 3 decimals
STEP_MM = 1 / 1600 + REPORT_RES
STEP_DEG = 1 / 35.556 + REPORT_RES
xy = st.integers(-150, 150).map(lambda v: v / 10.0)
theta = st.integers(-170, 170).map(float)


class JigMachine(RuleBasedStateMachine):
    @initialize()
    def connect(self) -> None:
        self.clock = VirtualClock()
        self.stage = Stage()
        self.mock = GrblMock(clock=self.clock, stage=self.stage)
        self.url = register_instance("jig-stateful", self.mock, self.clock)
        self.jig = Jig(self.url)
        self.jig.home()
        self.jig.move_to(0.0, 0.0, 0.0, wait=True, timeout_s=60.0)
        self.model = [0.0, 0.0, 0.0]

    def teardown(self) -> None:
        if hasattr(self, "jig"):
            self.jig.close()
            unregister_instance("jig-stateful")

    @rule(x=xy, y=xy, th=theta)
    def move(self, x: float, y: float, th: float) -> None:
        self.jig.move_to(x, y, th, wait=True, timeout_s=60.0)
        self.model = [x, y, th]

    @rule(x=st.sampled_from([-25.0, 21.0, 40.0]))
    def move_past_soft_limit(self, x: float) -> None:
        with pytest.raises(GrblAlarm) as info:
            self.jig.move_to(x, 0.0, 0.0, wait=True)
        assert info.value.code == 2
        with pytest.raises(GrblAlarm):
            self.jig.status()  # protocol.c: a critical alarm answers no '?' until a reset
        self.jig.soft_reset()
        before = self.jig.status()
        assert before.state == "Alarm"
        self.jig.unlock()  # the machine never moved: the position is still known
        assert self.jig.status().wpos == before.wpos
        self._sync_to_steps()

    def _sync_to_steps(self) -> None:
        # The machine must not have moved beyond a step from what the model knows before syncing.
        wpos = self.jig.status().wpos
        assert wpos[0] == pytest.approx(self.model[0], abs=STEP_MM)
        assert wpos[1] == pytest.approx(self.model[1], abs=STEP_MM)
        assert wpos[2] == pytest.approx(self.model[2], abs=STEP_DEG)
        # A reset makes GRBL's parser start from the step counters (gc_sync_position), so later
        # relative moves build on the whole-step position, exactly as the firmware does.
        self.model = list(self.jig.status().wpos)

    @rule(dx=st.integers(-30, 30).map(lambda v: v / 10.0), dth=st.integers(-20, 20).map(float))
    def jog(self, dx: float, dth: float) -> None:
        if abs(self.model[0] + dx) > 20 or abs(self.model[2] + dth) > 180:
            return
        self.jig.jog(dx_mm=dx, dtheta_deg=dth, feed_mm_per_min=600.0)
        self.jig.wait_idle(30.0)
        self.model = [self.model[0] + dx, self.model[1], self.model[2] + dth]

    @rule(x=xy, th=theta, after_s=st.floats(0.05, 1.0))
    def hold_then_resume(self, x: float, th: float, after_s: float) -> None:
        self.jig.move_to(x, self.model[1], th)
        self.clock.advance(after_s)
        self.jig.feed_hold()
        self.clock.advance(2.0)
        st_ = self.jig.status()
        assert st_.state in ("Hold", "Idle")
        self.jig.resume()
        self.jig.wait_idle(60.0)
        self.model = [x, self.model[1], th]

    @rule(x=xy, after_s=st.floats(0.05, 1.0))
    def stop_part_way(self, x: float, after_s: float) -> None:
        start = self.model[0]
        self.jig.move_to(x, self.model[1], self.model[2])
        self.clock.advance(after_s)
        self.jig.stop()
        p = self.jig.pose()
        lo, hi = sorted((start, x))
        assert lo - STEP_MM <= p.x_mm <= hi + STEP_MM  # stopped on the way, not past the target
        self.model[0] = p.x_mm
        self._sync_to_steps()

    @rule()
    def soft_reset_when_idle(self) -> None:
        self.jig.soft_reset()
        assert self.jig.status().state == "Idle"  # homed and not moving: no alarm
        self._sync_to_steps()

    @invariant()
    def position_and_state_agree(self) -> None:
        if not hasattr(self, "jig"):
            return
        st_ = self.jig.status()
        assert st_.state == "Idle"
        assert st_.wpos[0] == pytest.approx(self.model[0], abs=STEP_MM)
        assert st_.wpos[1] == pytest.approx(self.model[1], abs=STEP_MM)
        assert st_.wpos[2] == pytest.approx(self.model[2], abs=STEP_DEG)
        self.stage.advance_to(self.clock.now_s())
        assert self.stage.pose() == pytest.approx(st_.wpos, abs=2e-3)


JigMachine.TestCase.settings = settings(max_examples=15, stateful_step_count=10, deadline=None)
TestJigStateful = JigMachine.TestCase
