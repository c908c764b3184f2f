"""Camera faults, seeded and counted like the serial mocks' (:mod:`tactile_rig.mocks.faults`), written
the same way (``key=value&...``, as ``tactile-rig mock serve camera --v4l2 --fault`` takes them).

==================  ===========================================================================
``stall``           per frame: the camera sends nothing for ``stall_s`` (default 1.0 s); the
                    host's select() times out, the sequence does not advance
``freeze``          per frame: the camera sends the same image for ``freeze_s`` (default 1.0 s),
                    new buffers, timestamps and sequence numbers, identical bytes
``unplug``          per frame: the cable is pulled: open handles fail with ENODEV, poll reports
                    POLLERR, the node is gone for ``away_s`` (default 2.0 s), then back with its
                    controls at their power-on values
``replug``          the same for ``replug_s`` (default 0.1 s): a connector that bounces
==================  ===========================================================================

Fixed points: ``stall_after=N``, ``freeze_after=N``, ``unplug_after=N`` (after frame N of a stream,
counted from 0), and ``seed`` (default 0). Each injected fault is logged in
:attr:`CameraFaults.events`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl

import numpy as np

_PROBABILITIES = ("stall", "freeze", "unplug", "replug")
_DURATIONS = ("stall_s", "freeze_s", "away_s", "replug_s")
_COUNTS = ("stall_after", "freeze_after", "unplug_after", "seed")
_KNOWN = set(_PROBABILITIES) | set(_DURATIONS) | set(_COUNTS)


@dataclass
class CameraFaultEvent:
    kind: str
    sequence: int
    duration_s: float | None
    t_s: float


@dataclass
class CameraFaults:
    """Which faults to inject and when; :meth:`on_frame` is called after every delivered frame.

    ``stall``, ``freeze``, ``unplug``, ``replug``: the chance per delivered frame (0..1, as in a
    ``rigfault://`` query); ``*_s``: how long each lasts, in seconds; ``*_after``: a fault that
    comes once, after this many frames."""

    stall: float = 0.0
    freeze: float = 0.0
    unplug: float = 0.0
    replug: float = 0.0
    stall_s: float = 1.0
    freeze_s: float = 1.0
    away_s: float = 2.0
    replug_s: float = 0.1
    stall_after: int | None = None
    freeze_after: int | None = None
    unplug_after: int | None = None
    seed: int = 0
    events: list[CameraFaultEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in _PROBABILITIES:
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"camera fault {name}={p!r} must be a probability in [0, 1]")
        for name in _DURATIONS:
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 3600.0):
                raise ValueError(f"camera fault {name}={v!r} must be a duration in [0, 3600] s")
        for name in ("stall_after", "freeze_after", "unplug_after"):
            v = getattr(self, name)
            if v is not None and v < 0:
                raise ValueError(f"camera fault {name}={v!r} must be a frame number >= 0")
        self._rng = np.random.default_rng(self.seed)
        self._fired: set[str] = set()

    @classmethod
    def from_query(cls, query: str, *, source: str = "--fault") -> "CameraFaults":
        raw = dict(parse_qsl(query, keep_blank_values=True))
        unknown = set(raw) - _KNOWN
        if unknown:
            raise ValueError(f"{source}: unknown camera fault(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(sorted(_KNOWN))}")
        kw: dict[str, Any] = {}
        for key, value in raw.items():
            try:
                kw[key] = int(value) if key in _COUNTS else float(value)
            except ValueError:
                raise ValueError(f"{source}: camera fault {key}={value!r} is not a number") from None
        return cls(**kw)

    def _chance(self, p: float) -> bool:
        return bool(p) and self._rng.random() < p

    def _fixed(self, name: str, sequence: int) -> bool:
        at = getattr(self, name)
        if at is None or name in self._fired or sequence < at:
            return False
        self._fired.add(name)
        return True

    def on_frame(self, sequence: int, now_s: float, camera: Any) -> None:
        """Decide the faults due after frame ``sequence`` and inject them into ``camera`` (a
        :class:`~tactile_rig.mocks.v4l2.server.V4L2Camera`)."""
        if self._fixed("unplug_after", sequence) or self._chance(self.unplug):
            self.events.append(CameraFaultEvent("unplug", sequence, self.away_s, now_s))
            camera.unplug(self.away_s)
            return
        if self._chance(self.replug):
            self.events.append(CameraFaultEvent("replug", sequence, self.replug_s, now_s))
            camera.unplug(self.replug_s)
            return
        if self._fixed("stall_after", sequence) or self._chance(self.stall):
            self.events.append(CameraFaultEvent("stall", sequence, self.stall_s, now_s))
            camera.stall(self.stall_s)
        if self._fixed("freeze_after", sequence) or self._chance(self.freeze):
            self.events.append(CameraFaultEvent("freeze", sequence, self.freeze_s, now_s))
            camera.freeze(self.freeze_s)

    def counts(self) -> dict[str, int]:
        c: dict[str, int] = {}
        for e in self.events:
            c[e.kind] = c.get(e.kind, 0) + 1
        return c
