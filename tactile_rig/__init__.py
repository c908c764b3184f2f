"""tactile-rig: driver stack and hardware-in-the-loop test rig for vision-based tactile grippers.

Layers, bottom up (imports only run downward; ``tests/test_architecture.py`` enforces it):

- :mod:`tactile_rig.core`: errors, clocks, geometry and the data types every layer shares;
- :mod:`tactile_rig.devices`: device facts as data, shared by driver and mock (control tables,
  error tables, line formats, UVC control names);
- :mod:`tactile_rig.perception` (GelSight, FingerVision: pure numpy) and :mod:`tactile_rig.control`
  (closed-loop controllers against protocols), on ``core`` only;
- :mod:`tactile_rig.drivers`: the host side of every device, on ``core`` and ``devices``;
- :mod:`tactile_rig.sim`: world models, renderers, scenes and byte-free fakes;
- :mod:`tactile_rig.mocks`: firmware emulations that speak each device's bytes, reading ``sim``;
- :mod:`tactile_rig.rig`: the bench, sessions, recordings, reports, trade studies;
- :mod:`tactile_rig.cli`: the ``tactile-rig`` command; :mod:`tactile_rig.testing`: public test helpers.
"""

import serial as _serial

from tactile_rig import _compat
from tactile_rig.core.errors import (
    CalibrationError,
    CommandRejected,
    DeviceFault,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
)

__version__ = "0.2.0"

# rigsim:// and rigfault:// for pyserial's serial_for_url: registered by name, so a driver opening
# such a URL never imports a mock itself; pyserial imports the handler module on first use.
if "tactile_rig.mocks.urlhandlers" not in _serial.protocol_handler_packages:
    _serial.protocol_handler_packages.append("tactile_rig.mocks.urlhandlers")

_compat.install()

__all__ = [
    "CalibrationError",
    "CommandRejected",
    "DeviceFault",
    "DeviceTimeout",
    "LimitError",
    "LinkCorrupt",
    "NotConnected",
    "RigError",
    "__version__",
]
