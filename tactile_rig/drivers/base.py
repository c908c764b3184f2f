"""The driver template: lifecycle, one call at a time, a port that may vanish, and the counters.

:class:`Driver` owns the lifecycle, after ros2_control's hardware interfaces::

    connected ──activate()──▶ active ──a device fault──▶ fault
        ▲                        │                          │
        └──────deactivate()──────┘◀────────activate()───────┘   (and close() ▶ closed from anywhere)

A driver is ``connected`` once its constructor has opened and identified the device. Drivers of
things that move (the gripper, the jig) are ``active`` when they may move; a latched device fault
(a servo overload, a GRBL alarm) puts them in ``fault``, where motion is refused until
``activate()`` clears the fault and starts again from the measured state (no jump). Sensors (scale,
camera) never need activation: they stay ``connected`` until closed. Subclasses implement
``_close()`` and, when they move, ``_activate()`` / ``_deactivate()``. A driver used from several
threads marks its public methods :func:`locked`: one call at a time holds the driver's re-entrant
lock for its whole exchange, so two threads never interleave their bytes or steal each other's replies.

:class:`PortDriver` adds what every driver on a serial port shares, written once as python-can's
``BusABC`` owns a bus's public behaviour: an unplugged port fails fast with ``NotConnected`` while
it is away and is reopened when :class:`~tactile_rig.drivers.reconnect.Reconnect` allows, and
:attr:`PortDriver.stats` counts it under the same names in every driver (:class:`DriverStats`).
A driver implements two primitives, ``_reopen()`` and ``_release_port()``. The line pump of
line-oriented devices is :class:`tactile_rig.drivers.lines.LineDriver`.
"""

from __future__ import annotations

import enum
import functools
import threading
from dataclasses import asdict, dataclass
from typing import Any, Callable, TypeVar

from tactile_rig.core.errors import DeviceFault, DeviceTimeout, NotConnected
from tactile_rig.drivers.reconnect import Reconnect


F = TypeVar("F", bound=Callable[..., Any])


def locked(method: F) -> F:
    """Run ``method`` holding the driver's call lock (re-entrant: a locked method may call another).

    A closed driver refuses the call with :class:`NotConnected` (nothing it buffered is handed out after
    ``close()``). Around the call the driver's hooks run: ``_before_call()`` (a driver whose port vanished
    fails fast or reconnects there) and, when the call raises :class:`NotConnected`, ``_on_not_connected``
    (the port is gone: release it and start the reconnect backoff)."""

    @functools.wraps(method)
    def wrapper(self: "Driver", *args: Any, **kwargs: Any) -> Any:
        with self.call_lock:
            self.require_open()
            self._before_call()
            try:
                return method(self, *args, **kwargs)
            except NotConnected as exc:
                if self.lifecycle is not Lifecycle.CLOSED:
                    self._on_not_connected(exc)
                raise

    return wrapper  # type: ignore[return-value]


class Lifecycle(str, enum.Enum):
    """Where a driver is in its lifecycle."""

    CONNECTED = "connected"
    ACTIVE = "active"
    FAULT = "fault"
    CLOSED = "closed"


class Driver:
    """Base of every driver: ``device`` (a name for messages), ``lifecycle``, idempotent ``close()``."""

    device: str
    lifecycle: Lifecycle = Lifecycle.CONNECTED

    def __init__(self, device: str) -> None:
        self.device = device
        self.lifecycle = Lifecycle.CONNECTED
        self.last_fault: DeviceFault | None = None
        #: held for the whole of each :func:`locked` call (one exchange with the device at a time)
        self.call_lock = threading.RLock()

    # -- lifecycle ---------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        return self.lifecycle is Lifecycle.CLOSED

    def activate(self) -> None:
        """Make the device ready to act (torque on, unlocked); clears a fault, starting from the
        measured state. A driver without activation has nothing to do."""
        self.require_open()
        self._activate()
        self.lifecycle = Lifecycle.ACTIVE
        self.last_fault = None

    def deactivate(self) -> None:
        """Stop acting (torque off); allowed in ``fault``."""
        self.require_open()
        self._deactivate()
        if self.lifecycle is Lifecycle.ACTIVE:
            self.lifecycle = Lifecycle.CONNECTED

    def fault(self, error: DeviceFault) -> DeviceFault:
        """Record a latched device fault: the driver goes to ``fault``; returns ``error`` to raise."""
        if self.lifecycle is not Lifecycle.CLOSED:
            self.lifecycle = Lifecycle.FAULT
        self.last_fault = error
        return error

    def close(self) -> None:
        """Release the device; safe to call twice and from ``__exit__`` after an error."""
        if self.lifecycle is Lifecycle.CLOSED:
            return
        with self.call_lock:  # after the call in progress, never under it
            if self.lifecycle is Lifecycle.CLOSED:
                return
            try:
                self._close()
            finally:
                self.lifecycle = Lifecycle.CLOSED

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- guards for subclasses -----------------------------------------------------------------------
    def require_open(self) -> None:
        """``NotConnected`` once closed."""
        if self.lifecycle is Lifecycle.CLOSED:
            raise NotConnected(f"{type(self).__name__} was closed", device=self.device)

    def require_not_faulted(self, what: str) -> None:
        """Refuse ``what`` (e.g. a move) while a fault is latched: ``DeviceFault`` naming the fault."""
        self.require_open()
        if self.lifecycle is Lifecycle.FAULT:
            cause = f": {self.last_fault}" if self.last_fault is not None else ""
            raise DeviceFault(f"{what} refused: the device is in fault{cause}; call activate() to clear it "
                              f"and continue from the measured state", device=self.device,
                              code=getattr(self.last_fault, "code", None))

    # -- hooks -------------------------------------------------------------------------------------
    def _activate(self) -> None:
        """Subclass hook: make the device ready (default: nothing to do)."""

    def _deactivate(self) -> None:
        """Subclass hook: stop acting (default: nothing to do)."""

    def _close(self) -> None:
        """Subclass hook: release the port (default: nothing to release)."""

    def _before_call(self) -> None:
        """Subclass hook run before each :func:`locked` call (default: nothing)."""

    def _on_not_connected(self, error: NotConnected) -> None:
        """Subclass hook: a :func:`locked` call found the port gone (default: nothing)."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.device!r}, {self.lifecycle.value})"


@dataclass
class DriverStats:
    """Counters every port driver keeps, under these names; a driver's own counters extend it."""

    disconnects: int = 0  #: the port vanished (USB unplugged, EIO)
    reconnects: int = 0  #: ... and was reopened

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


class PortDriver(Driver):
    """A driver on one port that may vanish: fail fast while it is away, reopen it with backoff.

    ``reconnect_port`` is the path or URL reopened (the scale's stable ``/dev/serial/by-id`` link).
    ``reconnect_policy`` (a :class:`Reconnect` on the port's clock) is set by the subclass once the
    port is open and its clock known; until then nothing is retried. Primitives:

    * ``_reopen()``: open the port again and make the device usable; ``NotConnected`` or
      ``DeviceTimeout`` while it is still gone;
    * ``_release_port()``: close the port quietly (it may already be gone).

    Hooks: ``_on_port_lost(reason)`` after the port is released, ``_on_port_back()`` after a reopen.
    :func:`locked` methods get both for free; a driver that is not :func:`locked` (the Dynamixel
    bus, whose lock is the bus's) calls :meth:`_ensure_port` and :meth:`_port_lost` itself.
    """

    stats: DriverStats

    def __init__(self, device: str, *, reconnect_port: str, stats: DriverStats | None = None) -> None:
        super().__init__(device)
        self.reconnect_port = reconnect_port
        self.stats = stats if stats is not None else DriverStats()
        #: when to try reopening a port that vanished (backoff on the port's clock)
        self.reconnect_policy: Reconnect | None = None
        self._reopening = False

    # -- the template ------------------------------------------------------------------------------
    def _port_lost(self, reason: str) -> None:
        """The port failed under a call (unplugged): release it; calls fail fast until the backoff
        allows a reopen. A second report while it is away changes nothing."""
        policy = self.reconnect_policy
        if policy is None or policy.away:
            return
        self._release_port()
        policy.lost(reason)
        self.stats.disconnects += 1
        self._on_port_lost(reason)

    def _ensure_port(self) -> None:
        """While the port is away: ``NotConnected`` naming the port and the next attempt, or, when
        the backoff allows, one reopen (a failed one waits longer before the next)."""
        policy = self.reconnect_policy
        if policy is None or not policy.away or self.closed or self._reopening:
            return
        if not policy.due():
            raise policy.not_connected(self.device, self.reconnect_port)
        self._reopening = True  # the reopen may call locked methods (identify the device)
        try:
            self._reopen()
        except (NotConnected, DeviceTimeout) as exc:
            self._release_port()
            policy.failed(str(exc))
            raise policy.not_connected(self.device, self.reconnect_port) from exc
        finally:
            self._reopening = False
        self._port_back()

    def _port_back(self) -> None:
        """The port is open again: count it, end the backoff, let the driver react."""
        policy = self.reconnect_policy
        if policy is not None:
            policy.succeeded()
        self.stats.reconnects += 1
        self._on_port_back()

    # -- Driver hooks ---------------------------------------------------------------------------------
    def _before_call(self) -> None:
        self._ensure_port()

    def _on_not_connected(self, error: NotConnected) -> None:
        self._port_lost(str(error))

    # -- primitives and hooks for subclasses -----------------------------------------------------------
    def _reopen(self) -> None:
        raise NotImplementedError(f"{type(self).__name__} does not implement _reopen(): it cannot reconnect")

    def _release_port(self) -> None:
        raise NotImplementedError(f"{type(self).__name__} does not implement _release_port()")

    def _on_port_lost(self, reason: str) -> None:
        """Hook: the port was just released after a failure (default: nothing)."""

    def _on_port_back(self) -> None:
        """Hook: the port was just reopened (default: nothing)."""
