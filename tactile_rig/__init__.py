"""tactile-rig: driver stack and hardware-in-the-loop test rig for vision-based tactile grippers.

Subpackages: :mod:`tactile_rig.drivers` (host side of every device), :mod:`tactile_rig.mocks`
(firmware emulations and the simulated world), :mod:`tactile_rig.perception` (GelSight and
FingerVision, pure numpy), :mod:`tactile_rig.control` (closed-loop controllers against protocols),
:mod:`tactile_rig.rig` (bench config, sessions, recording, reports) and :mod:`tactile_rig.testing`
(public helpers to test drivers byte by byte).
"""

from tactile_rig.errors import (
    CalibrationError,
    DeviceFault,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
)

__version__ = "0.1.0"

__all__ = [
    "CalibrationError",
    "DeviceFault",
    "DeviceTimeout",
    "LimitError",
    "LinkCorrupt",
    "NotConnected",
    "RigError",
    "__version__",
]
