"""MX-64 control tables as data, shared by the driver and the firmware mock.

Two firmwares of the same servo: Protocol 2.0 "MX-64(2.0)" (model 311) and Protocol 1.0 (model 310),
from the ROBOTIS e-manual (``mx-64-2.md``, ``mx-64.md``). Each :class:`Item` states its address,
size in bytes, access (``"R"`` or ``"RW"``), whether it lives in EEPROM (writable only with torque
off on Protocol 2.0), its default, the static range the firmware accepts (Data Range error
outside it), whether it is signed, and its unit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Item:
    """One control-table item; ``low``/``high`` are raw register values."""

    name: str
    address: int
    size: int
    access: str  # "R" or "RW"
    default: int | None
    low: int
    high: int
    unit: str = ""
    eeprom: bool = False
    signed: bool = False

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    @property
    def end(self) -> int:
        return self.address + self.size

    def to_raw(self, value: int) -> int:
        """Signed value → unsigned register bytes value."""
        return value & ((1 << (8 * self.size)) - 1)

    def from_raw(self, raw: int) -> int:
        """Unsigned register value → the item's value (two's complement when signed)."""
        if self.signed and raw >= 1 << (8 * self.size - 1):
            return raw - (1 << (8 * self.size))
        return raw


class ControlTable:
    """The items of one firmware, looked up by name or address."""

    def __init__(self, name: str, model_number: int, protocol: int, size: int, items: list[Item]) -> None:
        self.name = name
        self.model_number = model_number
        self.protocol = protocol
        self.size = size  # bytes of register memory (addresses 0 .. size-1)
        self.items = sorted(items, key=lambda it: it.address)
        self._by_name = {it.name: it for it in self.items}
        self._by_address = {it.address: it for it in self.items}
        self._owner: list[Item | None] = [None] * size  # address → item covering it
        for it in self.items:
            for a in range(it.address, it.end):
                other = self._owner[a]
                if other is not None:
                    raise ValueError(f"{name}: items {other.name} and {it.name} overlap at {a}")
                self._owner[a] = it

    def __getitem__(self, name: str) -> Item:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.name} has no item {name!r}; items: {', '.join(self._by_name)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __iter__(self):
        return iter(self.items)

    def block(self, first: str, last: str) -> tuple[int, int]:
        """(address, length) of one contiguous read from item ``first`` through item ``last``."""
        a, b = self[first], self[last]
        if b.end <= a.address:
            raise ValueError(f"{self.name}: {last!r} (address {b.address}) does not follow {first!r} "
                             f"(address {a.address})")
        return a.address, b.end - a.address

    def value_in(self, raw: bytes, base: int, name: str) -> int:
        """Item ``name``'s value from ``raw``, a block read that started at address ``base``."""
        it = self[name]
        lo = it.address - base
        if lo < 0 or lo + it.size > len(raw):
            raise ValueError(f"{self.name}: {name!r} (address {it.address}, {it.size} B) is not inside the "
                             f"{len(raw)} B read from address {base}")
        return it.from_raw(int.from_bytes(raw[lo:lo + it.size], "little"))

    def at(self, address: int) -> Item | None:
        """The item starting at ``address`` (None if no item starts there)."""
        return self._by_address.get(address)

    def covering(self, address: int) -> Item | None:
        """The item whose bytes include ``address`` (None for a gap or beyond the table)."""
        if 0 <= address < self.size:
            return self._owner[address]
        return None

    def __repr__(self) -> str:
        return f"ControlTable({self.name!r}, model={self.model_number}, {len(self.items)} items)"


U8, U16, U32 = (0, 255), (0, 65535), (0, 2**32 - 1)
S16 = (-32768, 32767)
S32 = (-(2**31), 2**31 - 1)


def _i(name: str, address: int, size: int, access: str, default: int | None, rng: tuple[int, int],
       unit: str = "", *, eeprom: bool = False, signed: bool = False) -> Item:
    return Item(name, address, size, access, default, rng[0], rng[1], unit, eeprom, signed)


# --- Protocol 2.0, model 311 --------------------------------------------------------------
MX64_P2_MODEL = 311
MX64_P2_FIRMWARE = 45
_P2_ITEMS = [
    _i("Model Number", 0, 2, "R", MX64_P2_MODEL, U16, eeprom=True),
    _i("Model Information", 2, 4, "R", 0, U32, eeprom=True),
    _i("Firmware Version", 6, 1, "R", MX64_P2_FIRMWARE, U8, eeprom=True),
    _i("ID", 7, 1, "RW", 1, (0, 252), eeprom=True),
    _i("Baud Rate", 8, 1, "RW", 1, (0, 7), "code", eeprom=True),
    _i("Return Delay Time", 9, 1, "RW", 250, (0, 254), "2 us", eeprom=True),
    _i("Drive Mode", 10, 1, "RW", 0, (0, 5), "bits", eeprom=True),
    _i("Operating Mode", 11, 1, "RW", 3, (0, 16), "mode", eeprom=True),
    _i("Secondary(Shadow) ID", 12, 1, "RW", 255, (0, 255), eeprom=True),
    _i("Protocol Type", 13, 1, "RW", 2, (1, 2), eeprom=True),
    _i("Homing Offset", 20, 4, "RW", 0, (-1044479, 1044479), "0.088 deg", eeprom=True, signed=True),
    _i("Moving Threshold", 24, 4, "RW", 10, (0, 1023), "0.229 rpm", eeprom=True),
    _i("Temperature Limit", 31, 1, "RW", 80, (0, 100), "degC", eeprom=True),
    _i("Max Voltage Limit", 32, 2, "RW", 160, (95, 160), "0.1 V", eeprom=True),
    _i("Min Voltage Limit", 34, 2, "RW", 95, (95, 160), "0.1 V", eeprom=True),
    _i("PWM Limit", 36, 2, "RW", 885, (0, 885), "0.113 %", eeprom=True),
    _i("Current Limit", 38, 2, "RW", 1941, (0, 1941), "3.36 mA", eeprom=True),
    _i("Acceleration Limit", 40, 4, "RW", 32767, (0, 32767), "214.577 rev/min^2", eeprom=True),
    _i("Velocity Limit", 44, 4, "RW", 435, (0, 1023), "0.229 rpm", eeprom=True),
    _i("Max Position Limit", 48, 4, "RW", 4095, (0, 4095), "0.088 deg", eeprom=True),
    _i("Min Position Limit", 52, 4, "RW", 0, (0, 4095), "0.088 deg", eeprom=True),
    _i("Shutdown", 63, 1, "RW", 52, U8, "bits", eeprom=True),
    _i("Torque Enable", 64, 1, "RW", 0, (0, 1)),
    _i("LED", 65, 1, "RW", 0, (0, 1)),
    _i("Status Return Level", 68, 1, "RW", 2, (0, 2)),
    _i("Registered Instruction", 69, 1, "R", 0, (0, 1)),
    _i("Hardware Error Status", 70, 1, "R", 0, U8, "bits"),
    _i("Velocity I Gain", 76, 2, "RW", 1920, (0, 16383)),
    _i("Velocity P Gain", 78, 2, "RW", 100, (0, 16383)),
    _i("Position D Gain", 80, 2, "RW", 0, (0, 16383)),
    _i("Position I Gain", 82, 2, "RW", 0, (0, 16383)),
    _i("Position P Gain", 84, 2, "RW", 850, (0, 16383)),
    _i("Feedforward 2nd Gain", 88, 2, "RW", 0, (0, 16383)),
    _i("Feedforward 1st Gain", 90, 2, "RW", 0, (0, 16383)),
    _i("Bus Watchdog", 98, 1, "RW", 0, (0, 127), "20 ms"),
    _i("Goal PWM", 100, 2, "RW", 885, (-885, 885), "0.113 %", signed=True),
    _i("Goal Current", 102, 2, "RW", 1941, (-1941, 1941), "3.36 mA", signed=True),
    _i("Goal Velocity", 104, 4, "RW", 0, (-1023, 1023), "0.229 rpm", signed=True),
    _i("Profile Acceleration", 108, 4, "RW", 0, (0, 32767), "214.577 rev/min^2"),
    _i("Profile Velocity", 112, 4, "RW", 0, (0, 32767), "0.229 rpm"),
    _i("Goal Position", 116, 4, "RW", None, (-1048575, 1048575), "0.088 deg", signed=True),
    _i("Realtime Tick", 120, 2, "R", 0, (0, 32767), "ms"),
    _i("Moving", 122, 1, "R", 0, (0, 1)),
    _i("Moving Status", 123, 1, "R", 0, U8, "bits"),
    _i("Present PWM", 124, 2, "R", 0, S16, "0.113 %", signed=True),
    _i("Present Current", 126, 2, "R", 0, S16, "3.36 mA", signed=True),
    _i("Present Velocity", 128, 4, "R", 0, S32, "0.229 rpm", signed=True),
    _i("Present Position", 132, 4, "R", 0, S32, "0.088 deg", signed=True),
    _i("Velocity Trajectory", 136, 4, "R", 0, S32, "0.229 rpm", signed=True),
    _i("Position Trajectory", 140, 4, "R", 0, S32, "0.088 deg", signed=True),
    _i("Present Input Voltage", 144, 2, "R", 120, U16, "0.1 V"),
    _i("Present Temperature", 146, 1, "R", 30, U8, "degC"),
]
_P2_ITEMS += [_i(f"Indirect Address {n + 1}", 168 + 2 * n, 2, "RW", 224 + n, (64, 661)) for n in range(28)]
_P2_ITEMS += [_i(f"Indirect Data {n + 1}", 224 + n, 1, "RW", 0, U8) for n in range(28)]
_P2_ITEMS += [_i(f"Indirect Address {n + 29}", 578 + 2 * n, 2, "RW", 634 + n, (64, 661)) for n in range(28)]
_P2_ITEMS += [_i(f"Indirect Data {n + 29}", 634 + n, 1, "RW", 0, U8) for n in range(28)]

MX64_P2 = ControlTable("MX-64(2.0)", MX64_P2_MODEL, 2, 662, _P2_ITEMS)
P2_EEPROM_END = 64  # addresses below are EEPROM: Access Error while Torque Enable = 1
#: indirect data ranges (first data address, first address item, count)
P2_INDIRECT_BLOCKS = ((224, 168, 28), (634, 578, 28))

# --- Protocol 1.0, model 310 --------------------------------------------------------------
MX64_P1_MODEL = 310
MX64_P1_FIRMWARE = 41
_P1_ITEMS = [
    _i("Model Number", 0, 2, "R", MX64_P1_MODEL, U16, eeprom=True),
    _i("Firmware Version", 2, 1, "R", MX64_P1_FIRMWARE, U8, eeprom=True),
    _i("ID", 3, 1, "RW", 1, (0, 253), eeprom=True),
    _i("Baud Rate", 4, 1, "RW", 34, (0, 254), "2e6/(v+1) bps", eeprom=True),
    _i("Return Delay Time", 5, 1, "RW", 250, (0, 254), "2 us", eeprom=True),
    _i("CW Angle Limit", 6, 2, "RW", 0, (0, 4095), "0.088 deg", eeprom=True),
    _i("CCW Angle Limit", 8, 2, "RW", 4095, (0, 4095), "0.088 deg", eeprom=True),
    _i("Temperature Limit", 11, 1, "RW", 80, (0, 99), "degC", eeprom=True),
    _i("Min Voltage Limit", 12, 1, "RW", 60, (50, 160), "0.1 V", eeprom=True),
    _i("Max Voltage Limit", 13, 1, "RW", 160, (50, 160), "0.1 V", eeprom=True),
    _i("Max Torque", 14, 2, "RW", 1023, (0, 1023), "0.1 %", eeprom=True),
    _i("Status Return Level", 16, 1, "RW", 2, (0, 2), eeprom=True),
    _i("Alarm LED", 17, 1, "RW", 36, (0, 127), "bits", eeprom=True),
    _i("Shutdown", 18, 1, "RW", 36, (0, 127), "bits", eeprom=True),
    _i("Multi Turn Offset", 20, 2, "RW", 0, (-24576, 24576), "0.088 deg", eeprom=True, signed=True),
    _i("Resolution Divider", 22, 1, "RW", 1, (1, 4), eeprom=True),
    _i("Torque Enable", 24, 1, "RW", 0, (0, 1)),
    _i("LED", 25, 1, "RW", 0, (0, 1)),
    _i("D Gain", 26, 1, "RW", 0, (0, 254)),
    _i("I Gain", 27, 1, "RW", 0, (0, 254)),
    _i("P Gain", 28, 1, "RW", 32, (0, 254)),
    _i("Goal Position", 30, 2, "RW", None, (0, 4095), "0.088 deg"),
    _i("Moving Speed", 32, 2, "RW", 0, (0, 1023), "0.114 rpm"),
    _i("Torque Limit", 34, 2, "RW", 1023, (0, 1023), "0.1 %"),
    _i("Present Position", 36, 2, "R", 0, U16, "0.088 deg"),
    _i("Present Speed", 38, 2, "R", 0, (0, 2047), "0.114 rpm, bit10 = CW"),
    _i("Present Load", 40, 2, "R", 0, (0, 2047), "0.1 %, bit10 = CW"),
    _i("Present Voltage", 42, 1, "R", 120, U8, "0.1 V"),
    _i("Present Temperature", 43, 1, "R", 30, U8, "degC"),
    _i("Registered", 44, 1, "R", 0, (0, 1)),
    _i("Moving", 46, 1, "R", 0, (0, 1)),
    _i("Lock", 47, 1, "RW", 0, (0, 1)),
    _i("Punch", 48, 2, "RW", 0, (0, 1023)),
    _i("Realtime Tick", 50, 2, "R", 0, (0, 32767), "ms"),
    _i("Current", 68, 2, "R", 2048, (0, 4095), "4.5 mA offset 2048"),
    _i("Torque Ctrl Mode Enable", 70, 1, "RW", 0, (0, 1)),
    _i("Goal Torque", 71, 2, "RW", 0, (0, 2047), "4.5 mA, bit10 = CW"),
    _i("Goal Acceleration", 73, 1, "RW", 0, (0, 254), "8.583 deg/s^2"),
]
MX64_P1 = ControlTable("MX-64(1.0)", MX64_P1_MODEL, 1, 74, _P1_ITEMS)
P1_EEPROM_END = 24

TABLES = {2: MX64_P2, 1: MX64_P1}
TABLES_BY_MODEL = {MX64_P2_MODEL: MX64_P2, MX64_P1_MODEL: MX64_P1}

# --- units ---------------------------------------------------------------------------------
TICKS_PER_REV = 4096
RAD_PER_TICK = 2 * math.pi / TICKS_PER_REV
P2_CURRENT_A_PER_UNIT = 0.00336
P1_CURRENT_A_PER_UNIT = 0.0045
P1_CURRENT_OFFSET = 2048
#: MX-64 at 12 V (e-manual): stall current (the current cannot exceed it, whatever the cap) and no-load speed
STALL_CURRENT_A = 4.1
NO_LOAD_RPM = 63.0
P2_RPM_PER_VELOCITY_UNIT = 0.229
P1_RPM_PER_SPEED_UNIT = 0.114
#: P2 Baud Rate register → bits per second
P2_BAUD_BY_CODE = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000,
                   6: 4_000_000, 7: 4_500_000}
#: P2 operating modes
MODE_CURRENT, MODE_VELOCITY, MODE_POSITION, MODE_EXTENDED, MODE_CURRENT_POSITION, MODE_PWM = 0, 1, 3, 4, 5, 16
P2_VALID_MODES = (0, 1, 3, 4, 5, 16)


def p1_baud_from_code(code: int) -> int:
    """Protocol 1.0 Baud Rate register → bits per second (2 Mbps/(v+1); 250-252 are 2.25/2.5/3 M)."""
    special = {250: 2_250_000, 251: 2_500_000, 252: 3_000_000}
    return special.get(code, round(2_000_000 / (code + 1)))


def baud_from_code(protocol: int, code: int) -> int:
    """The bits per second a Baud Rate register value selects."""
    if protocol == 2:
        return P2_BAUD_BY_CODE[code]
    return p1_baud_from_code(code)


def code_from_baud(protocol: int, baud: int) -> int:
    """The Baud Rate register value closest to ``baud`` (ValueError if none is within 3 %)."""
    cands = P2_BAUD_BY_CODE.items() if protocol == 2 else ((c, p1_baud_from_code(c)) for c in range(255))
    code, bps = min(cands, key=lambda kv: abs(kv[1] - baud))
    if abs(bps - baud) > 0.03 * baud:
        raise ValueError(f"baud={baud} is not a Protocol {protocol} MX-64 baud rate")
    return code
