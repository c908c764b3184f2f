"""A parallel gripper on one MX-64: ``gripper_go(opening_m, effort_frac)``, ``state()``, calibration.

The opening between the fingertips is in metres (:meth:`DynamixelGripper.gripper_go`) or a fraction
of the calibrated range, 0 closed to 1 open (:meth:`DynamixelGripper.gripper_go_frac`), mapped
linearly onto servo ticks between the calibrated closed and open positions. Effort is the fraction
of the servo's current limit: on Protocol 2.0 the Goal Current of current-based position mode (5),
on Protocol 1.0 the Torque Limit. A blocking move ends as reached, stalled on an object (no
progress while the current is at the cap), timed out, or faulted (a latched overload/overheating
error, torque off).

Lifecycle (after ros2_control): ``connected`` → ``activate()`` → ``active`` → a hardware fault →
``fault``; ``reboot()`` → ``connected``. Only :meth:`DynamixelGripper.activate` enables torque, and
it first sets the goal to the measured position so re-activation never jumps.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any, Callable

from tactile_rig.core.clock import Deadline
from tactile_rig.core.deprecation import renamed_kwargs, warn_renamed
from tactile_rig.core.errors import (
    CalibrationError,
    DeviceFault,
    LimitError,
    NotConnected,
    check_range,
)
from tactile_rig.core.types import GripperOutcome, GripperState
from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.drivers.base import Driver, Lifecycle
from tactile_rig.drivers.dynamixel.bus import DynamixelBus
from tactile_rig.drivers.dynamixel.port import DEFAULT_LATENCY_TIMER_MS

log = logging.getLogger("tactile_rig.dynamixel.gripper")

STALL_CURRENT_A = ct.STALL_CURRENT_A
# ``reached`` needs the fingers within the position tolerance AND slower than this (m/s): at full
# speed (0.21 m/s) a finger crosses the 2 mm tolerance band within one 20 ms poll, so a position
# check alone reports a move as done while it still overshoots. 2 mm/s is a few velocity units
# (0.229 rpm each) above the encoder's noise at rest.
SETTLED_SPEED_MPS = 0.002
_REBOOT_WAIT_S = 0.1


@dataclass
class GripperCalibration:
    """Servo ticks at the closed and fully open fingertips, and the opening there in metres."""

    closed_ticks: int = 1024
    open_ticks: int = 3072
    max_opening_m: float = 0.10

    def __post_init__(self) -> None:
        if self.closed_ticks == self.open_ticks:
            raise CalibrationError(f"closed_ticks and open_ticks are both {self.closed_ticks}: no range")
        if not self.max_opening_m > 0:
            raise CalibrationError(f"max_opening_m={self.max_opening_m!r} must be > 0")

    @property
    def span_ticks(self) -> int:
        return self.open_ticks - self.closed_ticks

    def frac_from_ticks(self, ticks: float) -> float:
        return (ticks - self.closed_ticks) / self.span_ticks

    def ticks_from_frac(self, frac: float) -> int:
        return round(self.closed_ticks + frac * self.span_ticks)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "GripperCalibration":
        try:
            return cls(int(d["closed_ticks"]), int(d["open_ticks"]), float(d.get("max_opening_m", 0.10)))
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationError(f"gripper calibration {d!r} is invalid: {exc}") from None


class DynamixelGripper(Driver):
    """A gripper on one MX-64 (Protocol 2.0 model 311 or Protocol 1.0 model 310).

    ``port`` is a device path or URL, or an open :class:`DynamixelBus` shared with other servos.
    Connecting pings the servo and checks its model; it never enables torque. ``normalized=True``
    (deprecated: use :meth:`gripper_go_frac`) makes :meth:`gripper_go` read its opening as 0-1.
    """

    def __init__(
        self,
        port: str | DynamixelBus,
        *,
        dxl_id: int = 1,
        protocol: int = 2,
        baudrate: int | None = None,
        calibration: GripperCalibration | None = None,
        normalized: bool = False,
        position_tolerance_m: float = 0.002,
        poll_period_s: float = 0.02,
        default_timeout_s: float = 5.0,
        stall_window: int = 5,
        settled_speed_mps: float = SETTLED_SPEED_MPS,
        latency_timer_ms: float = DEFAULT_LATENCY_TIMER_MS,
        retries: int = 2,
    ) -> None:
        if isinstance(port, DynamixelBus):
            self.bus = port
            self._owns_bus = False
        else:
            self.bus = DynamixelBus(port, baudrate=baudrate or (1_000_000 if protocol == 2 else 57600),
                                    protocol=protocol, latency_timer_ms=latency_timer_ms, retries=retries)
            self._owns_bus = True
        self.protocol = self.bus.protocol
        self.id = dxl_id
        super().__init__(self.bus.name(dxl_id))
        self.clock = self.bus.clock
        self.calibration = calibration or GripperCalibration()
        if normalized:
            warn_renamed("DynamixelGripper(normalized=True)", "gripper_go_frac(opening_frac, effort_frac)")
        self.normalized = normalized
        self.position_tolerance_m = position_tolerance_m
        self.poll_period_s = poll_period_s
        self.default_timeout_s = default_timeout_s
        self.stall_window = max(2, stall_window)
        self.settled_speed_mps = check_range("settled_speed_mps", settled_speed_mps, 0.0, 10.0, "m/s")
        self.effort = 0.3
        self._speed_mps = 0.0
        #: the bus's reconnect count when torque was last known on (a reopened port may front a
        #: servo that lost power with it: torque off, RAM at defaults)
        self._reconnects_seen = self.bus.stats.reconnects
        self._connect()

    # -- lifecycle ------------------------------------------------------------------------------
    def _connect(self) -> None:
        try:
            model = self.bus.ping(self.id)
        except Exception:
            if self._owns_bus:
                self.bus.close()
            raise
        expected = self.bus.table.model_number
        if model != expected:
            raise NotConnected(f"model number {model} is not an MX-64 on Protocol {self.protocol} "
                               f"(expected {expected})", device=self.device)
        if self.protocol == 2:
            self.current_limit_a = self.bus.read(self.id, "Current Limit") * ct.P2_CURRENT_A_PER_UNIT
        else:
            self.max_torque = self.bus.read(self.id, "Max Torque", verify=True)  # P1's checksum is weak
            self.current_limit_a = STALL_CURRENT_A * self.max_torque / 1023
        if self.bus.hardware_errors.get(self.id):
            self.lifecycle = Lifecycle.FAULT

    def activate(self, effort: float | None = None) -> None:
        """Enable torque holding the measured position (current-based position mode on P2)."""
        self.require_open()
        if self.lifecycle == Lifecycle.FAULT or self.bus.hardware_errors.get(self.id):
            self.lifecycle = Lifecycle.FAULT
            raise self.bus.fault_error(self.id, "activate")
        if effort is not None:
            self.effort = check_range("effort", effort, 0.0, 1.0)
        b, i = self.bus, self.id
        b.write(i, "Torque Enable", 0)
        # torque is off, so the position is still: on P1 (weak checksum) read it twice, as a wrong
        # value here would be the goal the gripper jumps to
        present = b.read(i, "Present Position", verify=self.protocol == 1)
        if self.protocol == 2:
            if b.read(i, "Operating Mode") != ct.MODE_CURRENT_POSITION:
                b.write(i, "Operating Mode", ct.MODE_CURRENT_POSITION)
            b.write(i, "Goal Current", self._goal_current_units(self.effort))
            b.write(i, "Goal Position", present)
        else:
            b.write(i, "Torque Ctrl Mode Enable", 0)
            b.write(i, "Goal Position", min(4095, max(0, present)))
            b.write(i, "Torque Limit", self._torque_limit_units(self.effort))
        b.write(i, "Torque Enable", 1)
        self._reconnects_seen = b.stats.reconnects
        self.lifecycle = Lifecycle.ACTIVE

    def _torque_lost(self, what: str) -> NotConnected | None:
        """After the bus reopened its port: the servo may have lost power with it (torque off, RAM at
        defaults). Reads Torque Enable once per reconnect; when it is off the driver is ``connected``
        again and the error says to activate() (a move would otherwise wait for motion that never
        comes and time out)."""
        if self.lifecycle != Lifecycle.ACTIVE:
            return None
        policy = self.bus.reconnect_policy
        if not (policy is not None and policy.away) and self.bus.stats.reconnects == self._reconnects_seen:
            return None
        torque = self.bus.read(self.id, "Torque Enable")  # reopens the port when it is due
        self._reconnects_seen = self.bus.stats.reconnects
        if torque:
            return None
        self.lifecycle = Lifecycle.CONNECTED
        log.warning("%s: torque is off after the port came back (the servo lost power): activate() again",
                    self.device)
        return NotConnected(f"{what}: the port came back after an unplug and the servo's torque is off (it "
                            "lost power with it); call activate() again", device=self.device)

    def _deactivate(self) -> None:
        """Torque off (allowed while faulted)."""
        self.bus.write(self.id, "Torque Enable", 0, fault_ok=True)

    def reboot(self) -> None:
        """Reboot the servo: clears a latched fault; torque is off and the state is ``connected``."""
        self.require_open()
        self.bus.reboot(self.id)
        self.clock.sleep(_REBOOT_WAIT_S)
        self.bus.ping(self.id)
        self.lifecycle = Lifecycle.CONNECTED

    def _close(self) -> None:
        if self._owns_bus:
            self.bus.close()

    # -- units ------------------------------------------------------------------------------------
    def _goal_current_units(self, effort: float) -> int:
        limit = self.bus.table["Current Limit"]
        return round(effort * self.current_limit_a / ct.P2_CURRENT_A_PER_UNIT) if self.current_limit_a else limit.low

    def _torque_limit_units(self, effort: float) -> int:
        return round(effort * self.max_torque)

    def goal_ticks(self, opening_m: float) -> int:
        """Servo ticks of an opening in metres (0-1 with the deprecated ``normalized``); LimitError
        outside the calibrated range."""
        if self.normalized:
            return self.goal_ticks_frac(opening_m)
        cal = self.calibration
        # A measured opening fed back as a goal may lie a hair outside the calibrated range (an
        # object squeezed past the closed stop's calibration): within the tolerance it is clamped.
        tol = self.position_tolerance_m
        if not -tol <= opening_m <= cal.max_opening_m + tol:
            raise LimitError(f"opening_m={opening_m!r} m is outside the calibrated opening [0, {cal.max_opening_m}] m",
                             device=self.device)
        return cal.ticks_from_frac(min(1.0, max(0.0, opening_m / cal.max_opening_m)))

    def goal_ticks_frac(self, opening_frac: float) -> int:
        """Servo ticks of an opening as a fraction of the calibrated range (0 closed, 1 open)."""
        cal = self.calibration
        tol = self.position_tolerance_m / cal.max_opening_m
        if not -tol <= opening_frac <= 1.0 + tol:
            raise LimitError(f"opening_frac={opening_frac!r} is outside [0, 1] (0 closed, 1 open)", device=self.device)
        return cal.ticks_from_frac(min(1.0, max(0.0, opening_frac)))

    # -- motion -----------------------------------------------------------------------------------
    @renamed_kwargs(position="opening_m", effort="effort_frac")
    def gripper_go(self, opening_m: float, effort_frac: float, *, blocking: bool = True,
                   timeout_s: float | None = None) -> GripperOutcome:
        """Move the fingertips to ``opening_m`` metres apart with at most ``effort_frac`` × the
        current limit; see the module doc for how the move ends."""
        return self._go(lambda: self.goal_ticks(opening_m), effort_frac, blocking, timeout_s)

    def gripper_go_frac(self, opening_frac: float, effort_frac: float, *, blocking: bool = True,
                        timeout_s: float | None = None) -> GripperOutcome:
        """:meth:`gripper_go` to an opening given as a fraction of the calibrated range (0 closed, 1 open)."""
        return self._go(lambda: self.goal_ticks_frac(opening_frac), effort_frac, blocking, timeout_s)

    def _go(self, goal_of: Callable[[], int], effort: float, blocking: bool, timeout_s: float | None) -> GripperOutcome:
        self.require_open()
        check_range("effort_frac", effort, 0.0, 1.0)
        goal = goal_of()
        if self.lifecycle == Lifecycle.FAULT:
            raise self.bus.fault_error(self.id, "gripper_go")
        lost = self._torque_lost("gripper_go")
        if lost is not None:
            raise lost
        if self.lifecycle != Lifecycle.ACTIVE:
            raise NotConnected("gripper_go before activate(): torque is off", device=self.device)
        self.effort = effort
        try:
            if self.protocol == 2:
                self.bus.write(self.id, "Goal Current", self._goal_current_units(effort))
            else:
                self.bus.write(self.id, "Torque Limit", self._torque_limit_units(effort))
            self.bus.write(self.id, "Goal Position", goal)
        except DeviceFault:
            self.lifecycle = Lifecycle.FAULT
            return GripperOutcome.FAULT
        if not blocking:
            return GripperOutcome.MOVING
        return self.wait(goal, timeout_s)

    def wait(self, goal_ticks: int, timeout_s: float | None = None) -> GripperOutcome:
        """Poll the state until the move to ``goal_ticks`` ends; return how it ended.

        ``reached``: within the position tolerance and moving slower than ``settled_speed_mps``
        (the servo's Present Velocity / Speed, read in the same transaction as the position)."""
        deadline = Deadline(self.clock, self.default_timeout_s if timeout_s is None else timeout_s)
        cal = self.calibration
        tol_ticks = max(1.0, self.position_tolerance_m / cal.max_opening_m * abs(cal.span_ticks))
        cap_a = min(self.effort * self.current_limit_a, STALL_CURRENT_A)
        recent: deque[int] = deque(maxlen=self.stall_window)
        while True:
            ticks, current_a, hw = self._poll()
            if hw:
                self.lifecycle = Lifecycle.FAULT
                return GripperOutcome.FAULT
            if abs(ticks - goal_ticks) <= tol_ticks and abs(self._speed_mps) <= self.settled_speed_mps:
                return GripperOutcome.REACHED
            recent.append(ticks)
            if (len(recent) == recent.maxlen and max(recent) - min(recent) <= tol_ticks / 2
                    and abs(current_a) >= 0.5 * cap_a):
                return GripperOutcome.STALLED
            if deadline.expired():
                return GripperOutcome.TIMEOUT
            self.clock.sleep(self.poll_period_s)

    def _poll(self) -> tuple[int, float, int]:
        """(present ticks, current A, hardware error bits) in one read."""
        t = self.bus.table
        if self.protocol == 2:
            base, n = t.block("Present Current", "Present Position")
            raw = self.bus.read_bytes(self.id, base, n, what="read present current/velocity/position")
            current = t.value_in(raw, base, "Present Current") * ct.P2_CURRENT_A_PER_UNIT
            ticks = t.value_in(raw, base, "Present Position")
            tps = t.value_in(raw, base, "Present Velocity") * ct.P2_RPM_PER_VELOCITY_UNIT * ct.TICKS_PER_REV / 60
        else:
            base, n = t.block("Present Position", "Present Load")
            raw = self.bus.read_bytes(self.id, base, n, what="read present position/speed/load")
            ticks = t.value_in(raw, base, "Present Position")
            load = t.value_in(raw, base, "Present Load")
            current = (-1 if load & 0x400 else 1) * (load & 0x3FF) / 1023 * STALL_CURRENT_A
            speed = t.value_in(raw, base, "Present Speed")
            tps = (-1 if speed & 0x400 else 1) * (speed & 0x3FF) * ct.P1_RPM_PER_SPEED_UNIT * ct.TICKS_PER_REV / 60
        cal = self.calibration
        self._speed_mps = tps * cal.max_opening_m / abs(cal.span_ticks)  # the speed of this poll, for wait()
        return ticks, current, self.bus.hardware_errors.get(self.id, 0)

    def state(self) -> GripperState:
        """Position, velocity, current, effort, temperature and error bits, in one transaction."""
        self.require_open()
        cal = self.calibration
        m_per_tick = cal.max_opening_m / cal.span_ticks
        t = self.bus.table
        if self.protocol == 2:
            base, n = t.block("Torque Enable", "Present Temperature")
            raw = self.bus.read_bytes(self.id, base, n, what="read state")

            def f(name: str) -> int:
                return t.value_in(raw, base, name)

            torque, moving = f("Torque Enable"), f("Moving")
            current_a = f("Present Current") * ct.P2_CURRENT_A_PER_UNIT
            tps = f("Present Velocity") * ct.P2_RPM_PER_VELOCITY_UNIT * ct.TICKS_PER_REV / 60
            ticks, temp = f("Present Position"), f("Present Temperature")
            hw = f("Hardware Error Status")
            self.bus.hardware_errors[self.id] = hw
        else:
            base, n = t.block("Torque Enable", "Current")
            raw = self.bus.read_bytes(self.id, base, n, what="read state")

            def f(name: str) -> int:
                return t.value_in(raw, base, name)

            torque, moving, ticks, temp = f("Torque Enable"), f("Moving"), f("Present Position"), f("Present Temperature")
            speed = f("Present Speed")
            tps = (-1 if speed & 0x400 else 1) * (speed & 0x3FF) * ct.P1_RPM_PER_SPEED_UNIT * ct.TICKS_PER_REV / 60
            current_a = (f("Current") - ct.P1_CURRENT_OFFSET) * ct.P1_CURRENT_A_PER_UNIT
            hw = self.bus.hardware_errors.get(self.id, 0)
        if hw and self.lifecycle == Lifecycle.ACTIVE:
            self.lifecycle = Lifecycle.FAULT
        elif not torque and self.lifecycle == Lifecycle.ACTIVE:
            # Torque went off with no fault latched: the servo lost power (or was rebooted by
            # someone else); it holds nothing until activate().
            self.lifecycle = Lifecycle.CONNECTED
            log.warning("%s: torque is off with no fault latched (power lost?): activate() again", self.device)
        frac = cal.frac_from_ticks(ticks)
        return GripperState(
            t_s=self.clock.now_s(),
            opening_m=frac * cal.max_opening_m,
            opening_frac=frac,
            velocity_mps=tps * m_per_tick,
            current_a=current_a,
            effort_frac=abs(current_a) / self.current_limit_a if self.current_limit_a else 0.0,
            temperature_c=float(temp),
            hardware_error=hw,
            moving=bool(moving),
            active=bool(torque) and self.lifecycle == Lifecycle.ACTIVE,
        )

    # -- calibration -------------------------------------------------------------------------------
    def calibrate(self, *, effort: float = 0.2, max_opening_m: float | None = None, closing_sign: int = -1,
                  timeout_s: float = 10.0) -> GripperCalibration:
        """Find the closed and open stops by driving into each with a low ``effort``.

        ``closing_sign`` is the tick direction that closes the fingers (-1: decreasing ticks).
        ``max_opening_m`` is the measured opening at the open stop (default: the current one).
        Leaves the gripper active at the open stop.
        """
        if closing_sign not in (-1, 1):
            raise ValueError(f"closing_sign={closing_sign!r} must be -1 or 1")
        check_range("effort", effort, 0.01, 1.0)
        if self.lifecycle != Lifecycle.ACTIVE:
            self.activate(effort)
        closed = self._drive_to_stop(closing_sign, effort, timeout_s)
        opened = self._drive_to_stop(-closing_sign, effort, timeout_s)
        if abs(opened - closed) < 50:
            raise CalibrationError(f"the stops found are only {abs(opened - closed)} ticks apart "
                                   f"(closed {closed}, open {opened}): is something blocking the fingers?",
                                   device=self.device)
        self.calibration = GripperCalibration(closed, opened, max_opening_m or self.calibration.max_opening_m)
        return self.calibration

    def _drive_to_stop(self, sign: int, effort: float, timeout_s: float) -> int:
        present = self.bus.read(self.id, "Present Position")
        if self.protocol == 2:
            goal = present + sign * ct.TICKS_PER_REV
            self.bus.write(self.id, "Goal Current", self._goal_current_units(effort))
        else:
            goal = 0 if sign < 0 else 4095
            self.bus.write(self.id, "Torque Limit", self._torque_limit_units(effort))
        self.effort = effort
        self.bus.write(self.id, "Goal Position", goal)
        outcome = self.wait(goal, timeout_s)
        if outcome == GripperOutcome.FAULT:
            raise self.bus.fault_error(self.id, "calibrate")
        if outcome != GripperOutcome.STALLED:
            raise CalibrationError(f"driving toward the {'closed' if sign < 0 else 'open'} stop ended as "
                                   f"{outcome.value}, not on the stop", device=self.device)
        stop = self.bus.read(self.id, "Present Position")
        self.bus.write(self.id, "Goal Position", stop)  # hold there instead of pushing
        return stop
