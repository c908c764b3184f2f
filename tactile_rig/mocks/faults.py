"""Seeded, counted fault injection for any byte stream (the ``rigfault://`` transport and the pty relay).

``rigfault://<inner-url>#drop=0.01&flip=0.001&seed=3`` wraps any port pyserial can open (a mock
URL or a real device path) and corrupts what the host receives; :mod:`tactile_rig.mocks.relay` does
the same between a driver and a mock served on a pty. Every injected fault is logged in
:attr:`FaultInjector.events` so a test can assert on exactly what happened.

Byte faults (probability per byte, except ``garbage``):

==================  ===========================================================================
``drop``            a byte vanishes (UART overrun, noise)
``flip``            one bit of a byte flips (EMI on a long cable)
``dup``             a byte is delivered twice (RS-485 echo); ``duplicate`` is the same key
``garbage``         per chunk: a burst of 1-8 random bytes is inserted before the data
==================  ===========================================================================

Chunk faults (probability per chunk of device output, as it reaches the host side):

==================  ===========================================================================
``split``           the chunk reaches the host in two reads (a USB adapter's packetising)
``late``            the chunk (and everything behind it) is held ``late_s`` (default 0.06 s):
                    an adapter's latency timer, a loaded host
``stall``           the device goes silent for ``stall_s`` (default 1.0 s): output in that window
                    is lost (a firmware busy-loop, a watchdog about to fire)
``unplug``          the USB cable is pulled: every call on the open handle fails with EIO, and the
                    port cannot be opened for ``away_s`` (default 2.0 s); then it is back (and
                    the device, powered from USB, has rebooted)
``replug``          the same for ``replug_s`` (default 0.1 s): a connector that bounces
``reboot``          the device reboots now (brown-out, watchdog): the mock's own reset
==================  ===========================================================================

Fixed-point faults: ``stall_after=N`` (after N bytes the device is silent forever),
``disconnect_after=N`` (after N bytes every call raises EIO), and ``seed`` (default 0).
"""

from __future__ import annotations

import errno
import math
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qsl

import numpy as np

_PROBABILITIES = ("drop", "flip", "dup", "garbage", "split", "late", "stall", "unplug", "replug", "reboot")
_DURATIONS = ("late_s", "stall_s", "away_s", "replug_s")
_COUNTS = ("stall_after", "disconnect_after", "seed")
_ALIASES = {"duplicate": "dup"}
_KNOWN = set(_PROBABILITIES) | set(_DURATIONS) | set(_COUNTS) | set(_ALIASES)

#: the fault kinds of the soak, each with the query that injects it at a rate one operation in a few sees
KINDS = ("drop", "flip", "duplicate", "garbage", "split", "late", "stall", "unplug", "replug", "reboot")


@dataclass
class FaultEvent:
    kind: str
    byte_index: int
    detail: str = ""
    t_s: float | None = None


@dataclass
class ChunkFate:
    """What happens to one chunk of device output: the bytes that arrive (after byte faults), when
    (``release_s``), whether it arrives in two reads (``split_at``), whether the cable is pulled now
    (``unplug_s``: for how long) and whether the device reboots now."""

    data: bytes
    release_s: float
    split_at: int | None = None
    unplug_s: float | None = None
    reboot: bool = False


@dataclass
class FaultInjector:
    """Applies the configured faults to a byte stream, deterministically from ``seed``."""

    drop: float = 0.0
    flip: float = 0.0
    dup: float = 0.0
    garbage: float = 0.0
    split: float = 0.0
    late: float = 0.0
    stall: float = 0.0
    unplug: float = 0.0
    replug: float = 0.0
    reboot: float = 0.0
    late_s: float = 0.06
    stall_s: float = 1.0
    away_s: float = 2.0
    replug_s: float = 0.1
    stall_after: int | None = None
    disconnect_after: int | None = None
    seed: int = 0
    events: list[FaultEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in _PROBABILITIES:
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault {name}={p!r} must be a probability in [0, 1]")
        for name in _DURATIONS:
            v = getattr(self, name)
            if not (0.0 <= v <= 3600.0 and math.isfinite(v)):
                raise ValueError(f"fault {name}={v!r} must be a duration in [0, 3600] s")
        self._rng = np.random.default_rng(self.seed)
        self.bytes_seen = 0
        self._stalled_until = -math.inf
        self._last_release = -math.inf

    @classmethod
    def from_query(cls, query: str, *, source: str = "rigfault") -> "FaultInjector":
        raw = dict(parse_qsl(query, keep_blank_values=True))
        unknown = set(raw) - _KNOWN
        if unknown:
            raise ValueError(
                f"{source}: unknown fault(s) {', '.join(sorted(unknown))}; known: {', '.join(sorted(_KNOWN))}"
            )
        kw: dict[str, float | int] = {}
        for key, value in raw.items():
            key = _ALIASES.get(key, key)
            try:
                kw[key] = int(value) if key in _COUNTS else float(value)
            except ValueError:
                raise ValueError(f"{source}: fault {key}={value!r} is not a number") from None
        return cls(**kw)  # type: ignore[arg-type]

    @property
    def disconnected(self) -> bool:
        return self.disconnect_after is not None and self.bytes_seen >= self.disconnect_after

    def check_connected(self) -> None:
        """Raise ``OSError(EIO)`` once the simulated unplug has happened."""
        if self.disconnected:
            raise OSError(errno.EIO, "Input/output error (rigfault: device unplugged)")

    def _chance(self, p: float) -> bool:
        return bool(p) and self._rng.random() < p

    def apply(self, data: bytes) -> bytes:
        """Return ``data`` as the host would receive it (the byte faults only)."""
        self.check_connected()
        out = bytearray()
        if data and self._chance(self.garbage):
            burst = self._rng.integers(0, 256, size=int(self._rng.integers(1, 9)), dtype=np.uint8)
            out += bytes(burst)
            self.events.append(FaultEvent("garbage", self.bytes_seen, bytes(burst).hex(" ")))
        for b in data:
            idx = self.bytes_seen
            self.bytes_seen += 1
            if self.stall_after is not None and idx >= self.stall_after:
                if idx == self.stall_after:
                    self.events.append(FaultEvent("stall", idx))
                continue
            if self.disconnect_after is not None and idx >= self.disconnect_after:
                self.events.append(FaultEvent("disconnect", idx))
                break
            if self._chance(self.drop):
                self.events.append(FaultEvent("drop", idx, f"{b:02x}"))
                continue
            if self._chance(self.flip):
                bit = int(self._rng.integers(0, 8))
                self.events.append(FaultEvent("flip", idx, f"{b:02x}->{b ^ (1 << bit):02x}"))
                b ^= 1 << bit
            out.append(b)
            if self._chance(self.dup):
                self.events.append(FaultEvent("dup", idx, f"{b:02x}"))
                out.append(b)
        return bytes(out)

    def chunk(self, data: bytes, now_s: float) -> ChunkFate:
        """The fate of a chunk of device output arriving on the host side at ``now_s``."""
        if not data:
            return ChunkFate(b"", now_s)
        idx = self.bytes_seen
        if now_s < self._stalled_until:
            self.bytes_seen += len(data)
            return ChunkFate(b"", now_s)
        if self._chance(self.reboot):
            self.events.append(FaultEvent("reboot", idx, t_s=now_s))
            self.bytes_seen += len(data)
            return ChunkFate(b"", now_s, reboot=True)
        for kind, p, away in (("unplug", self.unplug, self.away_s), ("replug", self.replug, self.replug_s)):
            if self._chance(p):
                self.events.append(FaultEvent(kind, idx, f"away {away:g} s", t_s=now_s))
                self.bytes_seen += len(data)
                return ChunkFate(b"", now_s, unplug_s=away)
        if self._chance(self.stall):
            self._stalled_until = now_s + self.stall_s
            self.events.append(FaultEvent("stall", idx, f"{self.stall_s:g} s", t_s=now_s))
            self.bytes_seen += len(data)
            return ChunkFate(b"", now_s)
        out = self.apply(data)
        release = now_s
        if self._chance(self.late):
            release = now_s + self.late_s
            self.events.append(FaultEvent("late", idx, f"{self.late_s:g} s", t_s=now_s))
        release = max(release, self._last_release)  # a held chunk holds everything behind it
        self._last_release = release
        split_at = None
        if len(out) > 1 and self._chance(self.split):
            split_at = int(self._rng.integers(1, len(out)))
            self.events.append(FaultEvent("split", idx, f"at {split_at}"))
        return ChunkFate(out, release, split_at)

    def counts(self) -> dict[str, int]:
        """Number of injected faults of each kind."""
        c: dict[str, int] = {}
        for e in self.events:
            c[e.kind] = c.get(e.kind, 0) + 1
        return c


def reboot_device(device: Any, t_s: float) -> bool:
    """Reboot an in-process mock now, as a brown-out would: the scale's and GRBL's MCU reset, every
    Dynamixel servo reboots. False if ``device`` has no way to (a real port)."""
    inject = getattr(device, "inject", None)
    servos = getattr(device, "servos", None)
    if servos is not None:
        for s in servos:
            s.reboot(t_s, getattr(device, "boot_s", 0.05))
        return True
    if inject is not None:
        inject("reset", t_s=t_s)
        return True
    return False
