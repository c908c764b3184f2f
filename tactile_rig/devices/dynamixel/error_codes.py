"""Dynamixel error numbers and bits as data (the driver raises :class:`~tactile_rig.core.errors.CommandRejected`).

Protocol 2.0 status packets carry an error *number* (bits 6-0) plus the Alert bit (bit 7: read
Hardware Error Status, address 70). Protocol 1.0 status packets carry a *bit field* that mixes
command errors (range, checksum, instruction, angle limit) with hardware errors (voltage,
overheating, overload).
"""

from __future__ import annotations

ALERT_BIT = 0x80

#: Protocol 2.0 status error numbers (bits 6-0 of the error byte)
P2_ERROR_NUMBERS = {
    1: "Result Fail",
    2: "Instruction Error",
    3: "CRC Error",
    4: "Data Range Error",
    5: "Data Length Error",
    6: "Data Limit Error",
    7: "Access Error",
}
RESULT_FAIL, INSTRUCTION_ERROR, CRC_ERROR, DATA_RANGE, DATA_LENGTH, DATA_LIMIT, ACCESS_ERROR = range(1, 8)

#: Hardware Error Status (P2 address 70) and Shutdown (63) bits
HARDWARE_ERROR_BITS = {
    0: "Input Voltage Error",
    2: "Overheating Error",
    3: "Motor Encoder Error",
    4: "Electrical Shock Error",
    5: "Overload Error",
}
HW_INPUT_VOLTAGE, HW_OVERHEATING, HW_ENCODER, HW_SHOCK, HW_OVERLOAD = 0x01, 0x04, 0x08, 0x10, 0x20

#: Protocol 1.0 status error bits
P1_ERROR_BITS = {
    0: "Input Voltage Error",
    1: "Angle Limit Error",
    2: "Overheating Error",
    3: "Range Error",
    4: "Checksum Error",
    5: "Overload Error",
    6: "Instruction Error",
}
P1_INPUT_VOLTAGE, P1_ANGLE_LIMIT, P1_OVERHEATING, P1_RANGE, P1_CHECKSUM, P1_OVERLOAD, P1_INSTRUCTION = (
    0x01, 0x02, 0x04, 0x08, 0x10, 0x20, 0x40)
#: P1 bits that are hardware conditions (latched faults), vs. rejections of one command
P1_HARDWARE_MASK = P1_INPUT_VOLTAGE | P1_OVERHEATING | P1_OVERLOAD
P1_COMMAND_MASK = P1_ANGLE_LIMIT | P1_RANGE | P1_CHECKSUM | P1_INSTRUCTION


def decode_bits(bits: int, table: dict[int, str]) -> list[str]:
    """Names of the set bits of ``bits`` according to ``table`` (unknown bits as ``bit N``)."""
    return [table.get(b, f"bit {b}") for b in range(8) if bits >> b & 1]


def decode_hardware_error(bits: int) -> list[str]:
    """Hardware Error Status (P2 address 70) → names of the latched errors."""
    return decode_bits(bits, HARDWARE_ERROR_BITS)


def p1_hardware_to_status_bits(p1_bits: int) -> int:
    """Protocol 1.0 hardware error bits expressed as P2 Hardware Error Status bits."""
    out = 0
    if p1_bits & P1_INPUT_VOLTAGE:
        out |= HW_INPUT_VOLTAGE
    if p1_bits & P1_OVERHEATING:
        out |= HW_OVERHEATING
    if p1_bits & P1_OVERLOAD:
        out |= HW_OVERLOAD
    return out
