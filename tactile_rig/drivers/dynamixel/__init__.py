"""Dynamixel MX-64 driver: the bus on dynamixel-sdk and the gripper.

``from tactile_rig.drivers.dynamixel import DynamixelBus, DynamixelGripper``. The control tables the
driver reads are device facts in :mod:`tactile_rig.devices.dynamixel`; :mod:`.wire` checks every
status packet before the bus uses it.
"""

from tactile_rig.devices.dynamixel.control_table import MX64_P1, MX64_P2
from tactile_rig.drivers.dynamixel.bus import (
    BusStats,
    DynamixelBus,
    UrlPortHandler,
    check_latency_timer,
)
from tactile_rig.drivers.dynamixel.gripper import (
    DynamixelGripper,
    GripperCalibration,
    Lifecycle,
)

__all__ = [
    "BusStats", "DynamixelBus", "DynamixelGripper", "GripperCalibration", "Lifecycle", "MX64_P1", "MX64_P2",
    "UrlPortHandler", "check_latency_timer",
]
