"""One MX-64's firmware: register memory, access rules, instructions' effects and hardware errors.

The servo keeps its control table in a byte array initialised from the shared table data
(:mod:`tactile_rig.devices.dynamixel.control_table`), refreshes the present-value registers from
its plant (:class:`~tactile_rig.sim.world.fingers.Fingers`) before every read, checks every
write against the table (read-only or undefined address → Access Error; EEPROM while torque is on
→ Access Error; partial item → Data Length Error; outside the item's range → Data Range Error;
beyond a limit register → Data Limit Error) and latches Overheating / Overload when the plant's
winding overheats or stalls at full current: Alert bit on every status, torque off, until reboot.
"""

from __future__ import annotations

import math
import struct

from tactile_rig.devices.dynamixel import control_table as ct
from tactile_rig.devices.dynamixel import error_codes as de
from tactile_rig.devices.dynamixel import packets as pk
from tactile_rig.sim.world.fingers import STALL_CURRENT_A, TICKS_PER_REV, Fingers

#: an overload latches after this long at >= OVERLOAD_FRACTION of the stall current
OVERLOAD_TIME_S = 2.0
OVERLOAD_FRACTION = 0.95
_FAULT_CHECK_S = 0.01  # the firmware's protection loop period
_TPS_PER_RPM = TICKS_PER_REV / 60.0
# P2 live registers 120-143: tick, moving, moving status, PWM, current, velocity, position,
# velocity trajectory, position trajectory (addresses from control_table.MX64_P2)
_P2_LIVE = struct.Struct("<HBBhhiiii")
_HOMING_OFFSET = ct.MX64_P2["Homing Offset"].address
_MOVING_THRESHOLD = ct.MX64_P2["Moving Threshold"].address
_P2_OFFSET = struct.Struct("<i")
_P2_U32 = struct.Struct("<I")


class Servo:
    """The firmware of one servo on the mock bus (Protocol 2.0 or 1.0 MX-64)."""

    def __init__(self, dxl_id: int, protocol: int, plant: Fingers, *, return_delay_us: int = 500,
                 baud: int | None = None, t_s: float = 0.0) -> None:
        self.protocol = protocol
        self.table = ct.TABLES[protocol]
        self._temp_limit_addr = self.table["Temperature Limit"].address
        self._shutdown_addr = self.table["Shutdown"].address
        self._overheat_bit = de.HW_OVERHEATING if protocol == 2 else de.P1_OVERHEATING
        self._overload_bit = de.HW_OVERLOAD if protocol == 2 else de.P1_OVERLOAD
        self.plant = plant
        self.mem = bytearray(self.table.size)
        plant.advance_to(t_s)  # a scene's plant may start at 0 while a real clock is far ahead
        self.t_s = max(plant.t_s, t_s)
        self.registered: tuple[int, bytes] | None = None
        self.latched = 0  # P2 Hardware Error Status bits / P1 hardware error bits
        self.stall_s = 0.0
        self.booted_at_s = self.t_s
        self._factory_defaults(keep_id=False, keep_baud=False)
        self._write_raw_item("ID", dxl_id)
        self._write_raw_item("Return Delay Time", min(254, round(return_delay_us / 2)))
        if baud is not None:
            self._write_raw_item("Baud Rate", ct.code_from_baud(protocol, baud))
        self._sync_plant_from_registers()
        self.refresh()

    # -- registers ------------------------------------------------------------------------------
    @property
    def id(self) -> int:
        return self.mem[self.table["ID"].address]

    @property
    def baud(self) -> int:
        return ct.baud_from_code(self.protocol, self.item("Baud Rate"))

    @property
    def return_delay_s(self) -> float:
        return self.item("Return Delay Time") * 2e-6

    @property
    def status_return_level(self) -> int:
        return self.item("Status Return Level")

    @property
    def torque_on(self) -> bool:
        return bool(self.item("Torque Enable"))

    @property
    def alert(self) -> bool:
        return bool(self.latched)

    def item(self, name: str) -> int:
        it = self.table[name]
        return it.from_raw(int.from_bytes(self.mem[it.address:it.end], "little"))

    def _write_raw_item(self, name: str, value: int) -> None:
        it = self.table[name]
        self.mem[it.address:it.end] = it.to_raw(int(value)).to_bytes(it.size, "little")

    def _factory_defaults(self, *, keep_id: bool, keep_baud: bool, ram_only: bool = False) -> None:
        keep = {}
        for name, flag in (("ID", keep_id), ("Baud Rate", keep_baud)):
            if flag:
                keep[name] = self.item(name)
        for it in self.table:
            if ram_only and it.eeprom:
                continue
            default = it.default
            if it.name == "Goal Position":
                default = round(self.plant.position_ticks)
                if self.protocol == 2:
                    default += self.item("Homing Offset")  # EEPROM precedes RAM in address order
            if it.name in ("Goal Current", "Goal PWM"):
                default = self._limit_for(it.name)
            elif it.name == "Torque Limit":
                default = self.item("Max Torque")
            if it.name == "Goal Position" and self.protocol == 1:
                default = max(0, min(4095, default))
            if default is not None:
                self.mem[it.address:it.end] = it.to_raw(default).to_bytes(it.size, "little")
        for name, v in keep.items():
            self._write_raw_item(name, v)

    def _limit_for(self, name: str) -> int:
        limit = {"Goal Current": "Current Limit", "Goal PWM": "PWM Limit"}[name]
        it = self.table[limit]
        return int.from_bytes(self.mem[it.address:it.end], "little")

    # -- time ----------------------------------------------------------------------------------
    def advance_to(self, t_s: float) -> None:
        """Integrate the plant and run the protection loop up to ``t_s``."""
        # Long idle gaps (a real clock far ahead of a new device) are integrated in at most a few
        # hundred steps; the plant's formulas are exact for piecewise-constant commands.
        step = max(_FAULT_CHECK_S, (t_s - self.t_s) / 200)
        while self.t_s < t_s:
            t = min(t_s, self.t_s + step)
            dt = t - self.t_s
            self.plant.advance_to(t)
            self.t_s = t
            self._protect(dt)

    def _protect(self, dt: float) -> None:
        p = self.plant
        stalled = abs(p.current_a) >= OVERLOAD_FRACTION * STALL_CURRENT_A and abs(p.velocity_tps) < 1.0
        self.stall_s = self.stall_s + dt if stalled and p.torque_on else 0.0
        # single-byte registers read straight from memory: this runs every 10 ms of device time
        found = 0
        if p.temperature_c > self.mem[self._temp_limit_addr]:
            found |= self._overheat_bit
        if self.stall_s >= OVERLOAD_TIME_S:
            found |= self._overload_bit
        found &= self.mem[self._shutdown_addr]
        if found:
            self._latch(found)

    def inject_hardware_error(self, bits: int) -> None:
        """Latch hardware error ``bits`` now (P2 Hardware Error Status / P1 error bits), as the
        protection loop would: torque off, Alert bit until reboot. For fault-injection tests."""
        self._latch(bits)

    def _latch(self, bits: int) -> None:
        new = bits & ~self.latched
        if not new:
            return
        self.latched |= bits
        if self.protocol == 2:
            self._write_raw_item("Hardware Error Status", self.latched)
        else:
            self._write_raw_item("Torque Limit", 0)  # P1 shutdown: Torque Limit drops to 0
        self._write_raw_item("Torque Enable", 0)
        self.plant.command(torque_on=False)
        self.stall_s = 0.0

    def status_error(self, error: int = 0) -> int:
        """The error byte of a status packet: ``error`` plus the Alert bit / latched hardware bits."""
        if self.protocol == 2:
            return error | (de.ALERT_BIT if self.latched else 0)
        return error | self.latched

    # -- present values -----------------------------------------------------------------------
    def refresh(self) -> None:
        """Write the plant's present values into the registers (before a read)."""
        p = self.plant
        rpm = p.velocity_tps / _TPS_PER_RPM
        tick_ms = int(self.t_s * 1000) % 32768
        if self.protocol == 2:
            # One pack into the live block 120-143 (this runs on every position read).
            offset = _P2_OFFSET.unpack_from(self.mem, _HOMING_OFFSET)[0]
            threshold = _P2_U32.unpack_from(self.mem, _MOVING_THRESHOLD)[0]
            moving = int(abs(rpm) > ct.P2_RPM_PER_VELOCITY_UNIT * threshold)
            vel = round(rpm / ct.P2_RPM_PER_VELOCITY_UNIT)
            in_pos = abs(p.goal_ticks - p.position_ticks) < 2
            profile = p.trajectory_ticks != p.goal_ticks
            _P2_LIVE.pack_into(
                self.mem, 120, tick_ms, moving, int(in_pos) | int(profile) << 1,
                round(885 * max(-1.0, min(1.0, p.current_a / STALL_CURRENT_A))),
                round(p.current_a / ct.P2_CURRENT_A_PER_UNIT), vel, round(p.position_ticks) + offset,
                vel, round(p.trajectory_ticks) + offset)
            self.mem[146] = max(0, min(255, round(p.temperature_c)))
        else:
            self._write_raw_item("Present Position", max(0, min(4095, round(p.position_ticks))))
            self._write_raw_item("Present Speed", _p1_signed(rpm / ct.P1_RPM_PER_SPEED_UNIT))
            self._write_raw_item("Present Load", _p1_signed(p.current_a / STALL_CURRENT_A * 1023))
            self._write_raw_item("Current", max(0, min(4095, ct.P1_CURRENT_OFFSET + round(p.current_a / ct.P1_CURRENT_A_PER_UNIT))))
            self._write_raw_item("Present Temperature", round(p.temperature_c))
            self._write_raw_item("Realtime Tick", tick_ms)
            self._write_raw_item("Moving", int(abs(rpm) > ct.P1_RPM_PER_SPEED_UNIT))

    # -- read / write ---------------------------------------------------------------------------
    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error, data) of a Read: the error is a P2 error number or P1 error bits."""
        if length < 1 or address < 0 or address + length > self.table.size:
            return (de.DATA_LENGTH if address + length <= self.table.size else de.ACCESS_ERROR) \
                if self.protocol == 2 else de.P1_RANGE, b""
        end = address + length
        indirect = self.protocol == 2 and any(address < d0 + n and d0 < end for d0, _, n in ct.P2_INDIRECT_BLOCKS)
        if indirect or any(address < hi and lo < end for lo, hi in self._live):
            self.refresh()
        out = bytearray(self.mem[address:end])
        if indirect:
            for k in range(length):
                src = self._indirect_source(address + k)
                if src is not None:
                    out[k] = self.mem[src]
        return 0, bytes(out)

    @property
    def _live(self) -> tuple[tuple[int, int], ...]:
        """Address ranges of the present-value registers (refreshed from the plant on read)."""
        return ((120, 147),) if self.protocol == 2 else ((36, 52), (68, 70))

    def _indirect_source(self, address: int) -> int | None:
        for data0, addr0, count in ct.P2_INDIRECT_BLOCKS:
            if data0 <= address < data0 + count:
                a = addr0 + 2 * (address - data0)
                return int.from_bytes(self.mem[a:a + 2], "little")
        return None

    def check_write(self, address: int, data: bytes) -> int:
        """The error a Write of ``data`` at ``address`` gets (0: accepted), without applying it."""
        p2 = self.protocol == 2
        if not data:
            return de.DATA_LENGTH if p2 else de.P1_INSTRUCTION
        a = address
        end = address + len(data)
        while a < end:
            it = self.table.covering(a)
            if it is None or not it.writable:
                return de.ACCESS_ERROR if p2 else de.P1_RANGE
            if it.address != a or it.end > end:
                return de.DATA_LENGTH if p2 else de.P1_RANGE
            if it.eeprom and self.torque_on and p2:
                return de.ACCESS_ERROR
            if not p2 and self.item("Lock") and it.eeprom:
                return de.P1_INSTRUCTION
            value = it.from_raw(int.from_bytes(data[a - address:it.end - address], "little"))
            if not it.low <= value <= it.high:
                return de.DATA_RANGE if p2 else de.P1_RANGE
            err = self._check_limit(it.name, value, data, address)
            if err:
                return err
            a = it.end
        return 0

    def _check_limit(self, name: str, value: int, data: bytes, address: int) -> int:
        if self.protocol == 2:
            mode = self.item("Operating Mode")
            if name == "Operating Mode" and value not in ct.P2_VALID_MODES:
                return de.DATA_RANGE
            if name == "Goal Current" and abs(value) > self.item("Current Limit"):
                return de.DATA_LIMIT
            if name == "Goal PWM" and abs(value) > self.item("PWM Limit"):
                return de.DATA_LIMIT
            if name == "Goal Velocity" and abs(value) > self.item("Velocity Limit"):
                return de.DATA_LIMIT
            if name == "Goal Position" and mode == ct.MODE_POSITION and not (
                    self.item("Min Position Limit") <= value <= self.item("Max Position Limit")):
                return de.DATA_LIMIT
            return 0
        if name == "Goal Position":
            cw, ccw = self.item("CW Angle Limit"), self.item("CCW Angle Limit")
            joint = not (cw == 0 and ccw == 0) and not (cw == 4095 and ccw == 4095)
            if joint and not cw <= value <= ccw:
                return de.P1_ANGLE_LIMIT
        if name == "Torque Limit" and value > self.item("Max Torque"):
            return de.P1_RANGE
        return 0

    def write(self, address: int, data: bytes) -> int:
        """Check and apply a Write; return the error (0: done)."""
        err = self.check_write(address, data)
        if err:
            return err
        self.apply_write(address, data)
        return 0

    def apply_write(self, address: int, data: bytes) -> None:
        old_mode = self.item("Operating Mode") if self.protocol == 2 else None
        # writes to indirect data land at the addresses they point to
        for k, b in enumerate(data):
            src = self._indirect_source(address + k) if self.protocol == 2 else None
            self.mem[address + k] = b
            if src is not None and 0 <= src < self.table.size:
                self.mem[src] = b
        if self.protocol == 2:
            tq = self.table["Torque Enable"]
            if address <= tq.address < address + len(data) and self.latched and self.item("Torque Enable"):
                self._write_raw_item("Torque Enable", 0)  # a latched fault keeps torque off
            if self.item("Operating Mode") != old_mode:
                self._write_raw_item("Profile Velocity", 0)
                self._write_raw_item("Profile Acceleration", 0)
                self._write_raw_item("Goal Current", self.item("Current Limit"))
                self._write_raw_item("Goal PWM", self.item("PWM Limit"))
        elif self.latched and self.item("Torque Enable"):
            self._write_raw_item("Torque Enable", 0)
        self._sync_plant_from_registers()

    def _sync_plant_from_registers(self) -> None:
        """Hand the drive's commands to the plant (called after every write)."""
        p = self.plant
        p.advance_to(self.t_s)
        if self.protocol == 2:
            mode = self.item("Operating Mode")
            limit_a = self.item("Current Limit") * ct.P2_CURRENT_A_PER_UNIT
            goal = float(self.item("Goal Position") - self.item("Homing Offset"))
            cap = limit_a
            rpm = self.item("Profile Velocity") * ct.P2_RPM_PER_VELOCITY_UNIT
            if mode == ct.MODE_CURRENT_POSITION:
                cap = abs(self.item("Goal Current")) * ct.P2_CURRENT_A_PER_UNIT
            elif mode in (ct.MODE_CURRENT, ct.MODE_PWM):
                g = self.item("Goal Current") if mode == ct.MODE_CURRENT else self.item("Goal PWM")
                full = limit_a if mode == ct.MODE_CURRENT else STALL_CURRENT_A / 885 * self.item("PWM Limit")
                cap = abs(g) * (ct.P2_CURRENT_A_PER_UNIT if mode == ct.MODE_CURRENT else STALL_CURRENT_A / 885)
                cap = min(cap, full)
                goal = math.copysign(1e7, g)
                rpm = 0.0
            elif mode == ct.MODE_VELOCITY:
                v = self.item("Goal Velocity")
                goal = math.copysign(1e7, v)
                rpm = abs(v) * ct.P2_RPM_PER_VELOCITY_UNIT
            p.command(torque_on=self.torque_on, goal_ticks=goal, speed_limit_tps=rpm * _TPS_PER_RPM,
                      current_cap_a=cap)
        else:
            cap = self.item("Torque Limit") / 1023 * STALL_CURRENT_A
            goal = float(self.item("Goal Position"))
            rpm = self.item("Moving Speed") * ct.P1_RPM_PER_SPEED_UNIT
            if self.item("Torque Ctrl Mode Enable"):
                gt = self.item("Goal Torque")
                mag = min((gt & 0x3FF) * ct.P1_CURRENT_A_PER_UNIT, cap)
                goal = -1e7 if gt & 0x400 else 1e7
                cap, rpm = mag, 0.0
            p.command(torque_on=self.torque_on, goal_ticks=goal, speed_limit_tps=rpm * _TPS_PER_RPM,
                      current_cap_a=cap)

    # -- instructions with side effects ----------------------------------------------------------
    def reboot(self, t_s: float, boot_s: float) -> None:
        """Clear latched errors, RAM back to defaults, torque off; deaf until ``t_s + boot_s``."""
        self.latched = 0
        self.stall_s = 0.0
        self.plant.reset_drive()
        self._factory_defaults(keep_id=True, keep_baud=True, ram_only=True)
        self._write_raw_item("Hardware Error Status", 0) if self.protocol == 2 else None
        self.registered = None
        self.booted_at_s = t_s + boot_s
        self._sync_plant_from_registers()

    def factory_reset(self, option: int, t_s: float, boot_s: float) -> None:
        keep_id = option in (pk.RESET_ALL_BUT_ID, pk.RESET_ALL_BUT_ID_AND_BAUD)
        keep_baud = option == pk.RESET_ALL_BUT_ID_AND_BAUD
        self.latched = 0
        self.plant.reset_drive()
        self._factory_defaults(keep_id=keep_id, keep_baud=keep_baud)
        self.registered = None
        self.booted_at_s = t_s + boot_s
        self._sync_plant_from_registers()


def _p1_signed(value: float) -> int:
    """P1 sign-magnitude: bit 10 set for the CW (negative) direction, magnitude 0-1023."""
    mag = min(1023, round(abs(value)))
    return mag | (0x400 if value < 0 and mag else 0)
