"""When to try reopening a port that vanished: exponential backoff, no threads.

A driver whose port fails (USB unplugged: EIO) calls :meth:`Reconnect.lost`; from then on every
call asks :meth:`Reconnect.due` and, when it is not yet time, fails fast with ``NotConnected``
(:meth:`Reconnect.not_connected` builds the message: the port, how long it has been gone, why, and
when the next attempt is). When it is time the driver tries to reopen and reports
:meth:`Reconnect.failed` or :meth:`Reconnect.succeeded`. The waits grow from ``initial_s`` by
``factor`` up to ``max_s``; with a VirtualClock they pass in virtual time. The choreography that
uses it is written once, in :class:`tactile_rig.drivers.base.PortDriver`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tactile_rig.core.clock import Clock, RealClock
from tactile_rig.core.errors import NotConnected


@dataclass
class Reconnect:
    """Backoff state of one port; ``clock`` is the driver's (virtual for in-process mocks)."""

    clock: Clock = field(default_factory=RealClock)
    initial_s: float = 0.05
    factor: float = 2.0
    max_s: float = 2.0
    #: seconds until the next attempt after the latest failure
    wait_s: float = 0.0
    away: bool = False
    since_s: float | None = None
    next_attempt_s: float = 0.0
    attempts: int = 0
    reconnects: int = 0
    reason: str = ""

    def __post_init__(self) -> None:
        if not (self.initial_s >= 0 and self.factor >= 1 and self.max_s >= self.initial_s):
            raise ValueError(f"Reconnect: initial_s={self.initial_s!r} must be >= 0, factor={self.factor!r} >= 1 "
                             f"and max_s={self.max_s!r} >= initial_s")

    def lost(self, reason: str = "") -> None:
        """The port just failed: the first reconnect attempt is due after ``initial_s``."""
        now = self.clock.now_s()
        if not self.away:
            self.away = True
            self.since_s = now
            self.wait_s = self.initial_s
        self.reason = reason or self.reason
        self.next_attempt_s = now + self.wait_s

    def due(self) -> bool:
        """Whether a reconnect attempt may be made now."""
        return self.away and self.clock.now_s() >= self.next_attempt_s

    def failed(self, reason: str = "") -> None:
        """An attempt failed: wait longer before the next one."""
        self.attempts += 1
        self.reason = reason or self.reason
        self.wait_s = min(self.max_s, max(self.initial_s, self.wait_s * self.factor))
        self.next_attempt_s = self.clock.now_s() + self.wait_s

    def succeeded(self) -> None:
        """The port is back."""
        self.attempts += 1
        if self.away:
            self.reconnects += 1
        self.away = False
        self.since_s = None
        self.wait_s = 0.0
        self.reason = ""

    def not_connected(self, device: str, port: str) -> NotConnected:
        """The fail-fast error while the port is away (names the port and when the next try is)."""
        now = self.clock.now_s()
        gone = f" for {now - self.since_s:.3g} s" if self.since_s is not None else ""
        why = f" ({self.reason})" if self.reason else ""
        return NotConnected(f"port {port!r} is gone{gone}{why}; next reconnect attempt in "
                            f"{max(0.0, self.next_attempt_s - now):.3g} s", device=device)
