"""Model-based test of DynamixelBus against a register model with faults; a noisy-link property."""

from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from tactile_rig.core.clock import VirtualClock
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.drivers.dynamixel.bus import CommandRejected, DynamixelBus
from tactile_rig.core.errors import DeviceFault
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.mocks.registry import register_instance, unregister_instance
from tactile_rig.testing import serve_in_process

IDS = st.sampled_from([1, 2])


class BusModel(RuleBasedStateMachine):
    """Expected register values per servo; ``None`` goal = "wherever the shaft was at reboot"."""

    @initialize()
    def start(self) -> None:
        self.clock = VirtualClock()
        self.dev = make_bus(ids=[1, 2], timing=True, return_delay_us=0)
        self.name = f"stateful-{id(self)}"
        self.bus = DynamixelBus(register_instance(self.name, self.dev, self.clock))
        self.model = {i: {"LED": 0, "Torque Enable": 0, "Return Delay Time": 0,
                          "Goal Position": self.dev.servo(i).item("Goal Position")} for i in (1, 2)}
        self.fault = {1: False, 2: False}

    def teardown(self) -> None:
        if hasattr(self, "bus"):
            self.bus.close()
            unregister_instance(self.name)

    def _write(self, i: int, name: str, value: int) -> None:
        if self.fault[i]:
            with pytest.raises(DeviceFault) as info:
                self.bus.write(i, name, value)
            assert info.value.code == de.HW_OVERHEATING
        else:
            self.bus.write(i, name, value)

    @rule(i=IDS, on=st.integers(0, 1))
    def led(self, i: int, on: int) -> None:
        self._write(i, "LED", on)
        self.model[i]["LED"] = on  # applied even while faulted: only torque stays off

    def _write_or_reject(self, i: int, name: str, value: int, rejected_with: int | None) -> None:
        """Write and update the model, or expect the servo's rejection ``rejected_with``."""
        if rejected_with is not None:
            with pytest.raises(CommandRejected) as info:
                self.bus.write(i, name, value)
            assert info.value.error_number == rejected_with
            return
        self._write(i, name, value)
        self.model[i][name] = value

    @rule(i=IDS, goal=st.one_of(st.integers(1100, 3000), st.integers(4096, 9000), st.integers(-5000, -1)))
    def goal(self, i: int, goal: int) -> None:
        # position mode: outside Min/Max Position Limit is a Data Limit error
        self._write_or_reject(i, "Goal Position", goal, None if 0 <= goal <= 4095 else de.DATA_LIMIT)

    @rule(i=IDS, v=st.integers(0, 254))
    def return_delay(self, i: int, v: int) -> None:
        # EEPROM: Access Error while torque is on
        self._write_or_reject(i, "Return Delay Time", v, de.ACCESS_ERROR if self.model[i]["Torque Enable"] else None)

    @rule(i=IDS, on=st.integers(0, 1))
    def torque(self, i: int, on: int) -> None:
        self._write(i, "Torque Enable", on)
        self.model[i]["Torque Enable"] = 0 if self.fault[i] else on

    @rule(i=IDS)
    def inject_fault(self, i: int) -> None:
        self.dev.servo(i).inject_hardware_error(de.HW_OVERHEATING)
        self.fault[i] = True
        self.model[i]["Torque Enable"] = 0

    @rule(i=IDS)
    def reboot(self, i: int) -> None:
        self.bus.reboot(i)
        self.clock.advance(0.1)
        self.fault[i] = False
        self.model[i].update({"LED": 0, "Torque Enable": 0, "Goal Position": None})

    @rule(dt=st.floats(0.0, 0.5))
    def advance(self, dt: float) -> None:
        self.clock.advance(dt)

    @rule(noise=st.binary(min_size=1, max_size=12))
    def line_noise(self, noise: bytes) -> None:
        self.bus.port.ser.write(noise)  # host-side glitch; the line then stays quiet a while
        self.clock.advance(0.05)

    @precondition(lambda self: hasattr(self, "bus"))
    @invariant()
    def registers_match_the_model(self) -> None:
        for i in (1, 2):
            for name, expected in self.model[i].items():
                got = self.bus.read(i, name)
                if expected is None:
                    self.model[i][name] = got  # fixed from now on
                else:
                    assert got == expected, (i, name)
            assert bool(self.bus.hardware_errors.get(i)) == self.fault[i]


TestBusModel = BusModel.TestCase
TestBusModel.settings = settings(max_examples=30, stateful_step_count=10, deadline=None)


@settings(max_examples=8, deadline=None)
@given(
    ops=st.lists(st.tuples(st.sampled_from(["led", "goal", "read", "ping"]), st.sampled_from([1, 2]),
                           st.integers(1100, 3000)), min_size=1, max_size=6),
    fault=st.sampled_from(["flip=0.03", "drop=0.03", "dup=0.03", "garbage=0.3"]),
    seed=st.integers(0, 1000),
)
def test_a_noisy_link_only_raises_rig_errors_and_the_bus_recovers(ops, fault: str, seed: int) -> None:
    from tactile_rig.core.errors import RigError

    dev = make_bus(ids=[1, 2], timing=True, return_delay_us=0)
    with serve_in_process(dev) as url, DynamixelBus(f"rigfault://{url}#{fault}&seed={seed}") as bus:
        for op, i, value in ops:
            try:
                if op == "led":
                    bus.write(i, "LED", value % 2)
                elif op == "goal":
                    bus.write(i, "Goal Position", value)
                elif op == "read":
                    assert bus.read(i, "Model Number") == 311  # a CRC never lets bad data through
                else:
                    assert bus.ping(i) == 311
            except RigError:
                pass  # a typed error is the contract; anything else fails the test
        faults = bus.port.ser.faults
        faults.flip = faults.drop = faults.dup = faults.garbage = 0.0
        for i in (1, 2):  # the link is clean again: the driver reads the servos' true state
            assert bus.read(i, "LED") == dev.servo(i).item("LED")
            assert bus.read(i, "Goal Position") == dev.servo(i).item("Goal Position")
