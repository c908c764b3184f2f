"""The exception hierarchy of tactile-rig.

One root, :class:`RigError`; every leaf also inherits the builtin a caller would naturally catch
(``TimeoutError``, ``OSError``, ``ValueError``, ``ConnectionError``), so generic code keeps working.
Every error names the device it concerns (``device``), and messages say the value that was seen and
what was expected.
"""

from __future__ import annotations

from typing import Any


class RigError(Exception):
    """Root of every error raised by tactile-rig.

    ``device`` names the device or component (``"dynamixel[1]@/dev/ttyUSB0"``, ``"scale"``,
    ``"gelsight.registration"``); it is ``None`` when no device is concerned.
    """

    def __init__(self, message: str, *, device: str | None = None) -> None:
        super().__init__(message)
        self.device = device

    def __str__(self) -> str:
        msg = super().__str__()
        if self.device and not msg.startswith(f"{self.device}:"):
            return f"{self.device}: {msg}"
        return msg


class DeviceTimeout(RigError, TimeoutError):
    """A device did not answer before its deadline.

    Examples: a servo ID that is not on the bus; a client at the wrong baud rate; a scale that
    stopped streaming; a jig that did not reach Idle within ``wait_idle(timeout_s)``.
    """


class LinkCorrupt(RigError, IOError):
    """Bytes arrived but do not form a valid message.

    Examples: a CRC or checksum mismatch, a packet cut off mid-way, a status packet from the wrong
    ID, a line that does not parse.
    """


class DeviceFault(RigError):
    """The device reports a fault of its own; motion must stop.

    ``code`` is the device's own error number or bit field (a Dynamixel Hardware Error Status, a
    GRBL ``ALARM:N`` or ``error:N``); ``detail`` the decoded meaning.
    """

    def __init__(
        self,
        message: str,
        *,
        device: str | None = None,
        code: int | None = None,
        detail: Any = None,
    ) -> None:
        super().__init__(message, device=device)
        self.code = code
        self.detail = detail


class LimitError(RigError, ValueError):
    """A command is outside what the device or the configuration allows.

    Examples: a goal position beyond the gripper's calibrated range, a jig move past the soft
    limits, a speed above the collision-stop cap.
    """


class NotConnected(RigError, ConnectionError):
    """The device is absent, unplugged, or the driver is not in a state that allows the call.

    Examples: a port that does not exist, EIO from an unplugged USB adapter, ``gripper_go`` before
    ``activate()``.
    """


class CalibrationError(RigError, ValueError):
    """A calibration is missing, of the wrong version or sensor, or cannot be fitted from the data."""


class ConnectErrors(RigError):
    """Several devices failed to connect; ``errors`` maps each device name to its exception."""

    def __init__(self, errors: dict[str, BaseException]) -> None:
        lines = [f"{name}: {err}" for name, err in errors.items()]
        super().__init__(f"{len(errors)} device(s) failed to connect:\n  " + "\n  ".join(lines))
        self.errors = errors


def check_range(name: str, value: float, low: float, high: float, unit: str = "") -> float:
    """Return ``value`` if ``low <= value <= high``, else raise ``ValueError`` naming ``name`` and the range."""
    if not (low <= value <= high):  # also rejects NaN
        u = f" {unit}" if unit else ""
        raise ValueError(f"{name}={value!r}{u} is outside the allowed range [{low}, {high}]{u}")
    return value
