"""What every driver shares: a device name, a lifecycle, ``close()`` and the context manager.

The lifecycle follows ros2_control's hardware interfaces::

    connected ──activate()──▶ active ──a device fault──▶ fault
        ▲                        │                          │
        └──────deactivate()──────┘◀────────activate()───────┘   (and close() ▶ closed from anywhere)

A driver is ``connected`` once its constructor has opened and identified the device. Drivers of
things that move (the gripper, the jig) are ``active`` when they may move; a latched device fault
(a servo overload, a GRBL alarm) puts them in ``fault``, where motion is refused until
``activate()`` clears the fault and starts again from the measured state (no jump). Sensors (scale,
camera) never need activation: they stay ``connected`` until closed.

Subclasses implement ``_close()`` (release the port; called once) and, when they move,
``_activate()`` / ``_deactivate()``. A driver used from several threads marks its public methods
:func:`locked`: one call at a time holds the driver's re-entrant lock for its whole exchange, so two
threads never interleave their bytes or steal each other's replies.
"""

from __future__ import annotations

import enum
import functools
import threading
from typing import Any, Callable, TypeVar

from tactile_rig.core.errors import DeviceFault, NotConnected


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
