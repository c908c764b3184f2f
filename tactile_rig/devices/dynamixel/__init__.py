"""Dynamixel MX-64 facts: the control tables of both firmwares (:mod:`.control_table`), the
status error numbers and hardware error bits (:mod:`.error_codes`), and the packet headers and
instruction codes both wire codecs read (:mod:`.packets`)."""

from tactile_rig.devices.dynamixel.control_table import MX64_P1, MX64_P2

__all__ = ["MX64_P1", "MX64_P2"]
