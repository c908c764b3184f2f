"""Dynamixel MX-64 driver: control tables as data, the bus on dynamixel-sdk, the gripper.

``from tactile_rig.drivers.dynamixel import DynamixelBus, DynamixelGripper`` (imported lazily so
the mock can read the control tables without loading the SDK).
"""

from __future__ import annotations

from typing import Any

_EXPORTS = {
    "DynamixelBus": "tactile_rig.drivers.dynamixel.bus",
    "UrlPortHandler": "tactile_rig.drivers.dynamixel.bus",
    "check_latency_timer": "tactile_rig.drivers.dynamixel.bus",
    "CommandRejected": "tactile_rig.drivers.dynamixel.errors",
    "DynamixelGripper": "tactile_rig.drivers.dynamixel.gripper",
    "GripperCalibration": "tactile_rig.drivers.dynamixel.gripper",
    "Lifecycle": "tactile_rig.drivers.dynamixel.gripper",
    "MX64_P1": "tactile_rig.drivers.dynamixel.control_table",
    "MX64_P2": "tactile_rig.drivers.dynamixel.control_table",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        import importlib

        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
