"""The exception hierarchy of tactile-rig: the whole tree, in this one module.

One root, :class:`RigError`; every leaf also inherits the builtin a caller would naturally catch
(``TimeoutError``, ``OSError``, ``ValueError``, ``ConnectionError``), so generic code keeps working.
Every error names the device it concerns (``device``), and messages say the value that was seen and
what was expected. One event has one parent, whatever the device:

==============================  =====================================  =====================
event                           class (parent)                         CLI exit code
==============================  =====================================  =====================
no answer before the deadline   DeviceTimeout (TimeoutError)           2
bytes that are not a message    LinkCorrupt (OSError)                  2
device absent or unplugged      NotConnected (ConnectionError)         2
the device refused a command    CommandRejected (ValueError)           2
  ... a GRBL ``error:N``        GrblError (CommandRejected)            2
the device latched a fault      DeviceFault                            3
  ... a GRBL ``ALARM:N``        GrblAlarm (DeviceFault)                3
  ... an unasked reset          GrblReset (DeviceFault)                3
outside a configured limit      LimitError (ValueError)                2
a calibration unusable          CalibrationError (ValueError)          2
  ... would replace a file      CalibrationExists (CalibrationError)   2
  ... no markers to calibrate   MarkersNotFound (CalibrationError)     2
frame outside the valid input   InvalidFrame (ValueError)              2
a camera kept no setting        ControlReadbackError (ValueError)      2
a camera stream frozen          FrozenStream (DeviceTimeout)           2
a bench file unusable           BenchError (ValueError)                2
perception input out of range   PerceptionError (ValueError)           2
  ... nothing touches the gel   NoContact (PerceptionError)            2
  ... clipped (black/white)     SaturatedFrame (PerceptionError)       2
  ... beyond the calibration    GradientOutOfRange (PerceptionError)   2
  ... not a gel surface         HeightOutOfRange (PerceptionError)     2
  ... a squashed transform      DegenerateTransform (PerceptionError)  2
a run folder of another run     RunConflict (ValueError)               2
several devices failed          ConnectErrors                          2
an answer lost on the wire      ReplyLost (LinkCorrupt)                2
a port another handle holds     PortInUse (NotConnected)               2
a scale zero no longer true     ZeroLost (ValueError)                  2
a file that cannot be used      BadFile (ValueError)                   2
a file that does not exist      MissingFile (FileNotFoundError)        2
a bug in tactile-rig itself     (any other exception)                  70
==============================  =====================================  =====================

Device-specific texts (GRBL's messages, Dynamixel error names) are device facts and live in
:mod:`tactile_rig.devices`; the errors here take them as arguments.
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


class ReplyLost(LinkCorrupt):
    """A device executed a request but its answer was lost on the wire (a GRBL ``ok``/``error`` the
    host never received, detected from a later status report). ``line`` is what was sent; whether
    the device accepted it is unknown, so read the state back before relying on it."""

    def __init__(self, message: str, *, device: str | None = None, line: str | None = None) -> None:
        super().__init__(message, device=device)
        self.line = line


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


class CommandRejected(RigError, ValueError):
    """The device answered but refused the command; the device itself is fine and nothing moved.

    ``code`` is the device's own number (a Dynamixel P2 status error number or P1 command bits, a
    GRBL ``error:N``); ``detail`` its meaning (e.g. ``"Access Error"`` for an EEPROM write with
    torque on).
    """

    def __init__(self, message: str, *, device: str | None = None, code: int | None = None,
                 detail: Any = None) -> None:
        super().__init__(message, device=device)
        self.code = code
        self.detail = detail

    @property
    def error_number(self) -> int | None:
        """The Dynamixel status error number (alias of ``code``)."""
        return self.code

    @property
    def error_name(self) -> Any:
        """The meaning of the error number (alias of ``detail``)."""
        return self.detail


class GrblError(CommandRejected):
    """GRBL answered ``error:N`` to a line; ``code`` is N, ``name`` GRBL's short name, ``line`` the
    line it rejected. Build it with :func:`tactile_rig.devices.grbl.error`, which knows GRBL's table."""

    def __init__(self, code: int, name: str, meaning: str, *, device: str | None = None,
                 line: str | None = None) -> None:
        where = f" for line {line!r}" if line is not None else ""
        super().__init__(f"error:{code} ({name}){where}: {meaning}", device=device, code=code, detail=meaning)
        self.name = name
        self.line = line


class GrblAlarm(DeviceFault):
    """GRBL reported ``ALARM:N``: motion has stopped and G-code is locked until ``$X`` or a reset.
    Build it with :func:`tactile_rig.devices.grbl.alarm`, which knows GRBL's table."""

    def __init__(self, code: int, name: str, meaning: str, *, device: str | None = None, hint: str = "") -> None:
        super().__init__(f"ALARM:{code} ({name}): {meaning}" + (f" ({hint})" if hint else ""),
                         device=device, code=code, detail=meaning)
        self.name = name


class GrblReset(DeviceFault):
    """GRBL printed its banner when no reset was asked for (power glitch, DTR, watchdog)."""


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


class ZeroLost(RigError, ValueError):
    """A scale's zero can no longer be trusted (its sketch re-tared with an unknown load on it and
    sends no raw counts the host could correct with); ``tare()`` sets a new zero."""


class CalibrationExists(CalibrationError, FileExistsError):
    """Writing a calibration would replace an existing file (a version, or an unversioned file at the
    stable name); pass ``force=True`` (``--force``) to overwrite it."""


class MarkersNotFound(CalibrationError):
    """A marker sensor's calibration frames hold no marker lattice (black, white, flat, covered)."""


class InvalidFrame(RigError, ValueError):
    """A frame outside a perception entry point's valid input: shape, channels, dtype or size."""


class ControlReadbackError(RigError, ValueError):
    """The camera did not keep a format or control value we wrote (read back differs)."""


class FrozenStream(DeviceTimeout):
    """Frames keep arriving but their content does not change: the stream is frozen."""


class BenchError(RigError, ValueError):
    """A bench file that cannot be used; ``problems`` lists every ``(line, message)`` found."""

    def __init__(self, source: str, problems: list[tuple[int | None, str]]) -> None:
        self.source = source
        self.problems = sorted(problems, key=lambda p: p[0] or 0)
        lines = [f"{source} line {ln}: {msg}" if ln else f"{source}: {msg}" for ln, msg in self.problems]
        super().__init__("\n".join(lines) if len(lines) == 1 else
                         f"{len(lines)} problems in {source}:\n  " + "\n  ".join(lines))


class RunConflict(RigError, ValueError):
    """A run folder holds a run with another configuration (or an unreadable one)."""


class PerceptionError(RigError, ValueError):
    """A perception input outside the range its function can turn into a physical result.

    ``value`` is what was seen (a fraction, a slope, a height in mm, a determinant) and ``limit`` the
    bound it broke; the message names both and the component (``device``).
    """

    def __init__(self, message: str, *, device: str | None = None, value: float | None = None,
                 limit: float | None = None) -> None:
        super().__init__(message, device=device)
        self.value = value
        self.limit = limit


class NoContact(PerceptionError):
    """Nothing presses the gel (a flat map), where the function needs a contact."""


class SaturatedFrame(PerceptionError):
    """Too much of a frame is clipped at 0 or 255 (covered lens, lights off, over-exposure)."""


class GradientOutOfRange(PerceptionError):
    """Colours or slopes beyond what the calibration was fitted on (its heights would be invented)."""


class HeightOutOfRange(PerceptionError):
    """Heights no gel can show (beyond its range of a few mm): the input is not a gel surface."""


class DegenerateTransform(PerceptionError):
    """Two maps are related by a squashing transform (det R far from 1), not a rigid move."""


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


class PortInUse(NotConnected):
    """The port is held by another process or handle (opened exclusively); ``port`` names it."""

    def __init__(self, message: str, *, device: str | None = None, port: str | None = None) -> None:
        super().__init__(message, device=device)
        self.port = port


class BadFile(RigError, ValueError):
    """A file that cannot be used as it is: ``path`` names it, ``problem`` says what is wrong with it
    and ``expected`` what was expected (a directory given for a file, zero bytes, a truncated
    archive, a pickle or complex ``.npy``, a 65535 x 65535 image header, JSON nested too deep)."""

    def __init__(self, path: Any, problem: str, expected: str = "") -> None:
        self.path = str(path)
        self.problem = problem
        self.expected = expected
        super().__init__(f"{self.path}: {problem}" + (f"; expected {expected}" if expected else ""))


class MissingFile(RigError, FileNotFoundError):
    """A file the command needs does not exist; ``path`` names it and ``what`` says what it was for."""

    def __init__(self, path: Any, what: str = "file") -> None:
        self.path = str(path)
        self.what = what
        RigError.__init__(self, f"{self.path}: the {what} does not exist")
