"""Seeded, counted fault injection for any byte stream (the ``rigfault://`` transport).

``rigfault://<inner-url>#drop=0.01&flip=0.001&seed=3`` wraps any port pyserial can open (a mock
URL or a real device path) and corrupts the bytes the host receives. Every injected fault is
logged in :attr:`FaultInjector.events` so a test can assert on exactly what happened.

Faults (probabilities are per byte unless noted):

==================  ===========================================================================
``drop``            a byte vanishes (UART overrun, noise)
``flip``            one bit of a byte flips (EMI on a long cable)
``dup``             a byte is delivered twice (RS-485 echo)
``garbage``         per read call: a burst of 1-8 random bytes is inserted before the data
``stall_after``     after this many bytes the device goes silent forever (hung firmware)
``disconnect_after``  after this many bytes every call raises EIO (USB unplugged)
``seed``            the RNG seed (default 0)
==================  ===========================================================================
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from urllib.parse import parse_qsl

import numpy as np

_KNOWN = {"drop", "flip", "dup", "garbage", "stall_after", "disconnect_after", "seed"}


@dataclass
class FaultEvent:
    kind: str
    byte_index: int
    detail: str = ""


@dataclass
class FaultInjector:
    """Applies the configured faults to a byte stream, deterministically from ``seed``."""

    drop: float = 0.0
    flip: float = 0.0
    dup: float = 0.0
    garbage: float = 0.0
    stall_after: int | None = None
    disconnect_after: int | None = None
    seed: int = 0
    events: list[FaultEvent] = field(default_factory=list)

    def __post_init__(self) -> None:
        for name in ("drop", "flip", "dup", "garbage"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault {name}={p!r} must be a probability in [0, 1]")
        self._rng = np.random.default_rng(self.seed)
        self.bytes_seen = 0

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
            try:
                kw[key] = int(value) if key in ("stall_after", "disconnect_after", "seed") else float(value)
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

    def apply(self, data: bytes) -> bytes:
        """Return ``data`` as the host would receive it."""
        self.check_connected()
        out = bytearray()
        if data and self.garbage and self._rng.random() < self.garbage:
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
            if self.drop and self._rng.random() < self.drop:
                self.events.append(FaultEvent("drop", idx, f"{b:02x}"))
                continue
            if self.flip and self._rng.random() < self.flip:
                bit = int(self._rng.integers(0, 8))
                self.events.append(FaultEvent("flip", idx, f"{b:02x}->{b ^ (1 << bit):02x}"))
                b ^= 1 << bit
            out.append(b)
            if self.dup and self._rng.random() < self.dup:
                self.events.append(FaultEvent("dup", idx, f"{b:02x}"))
                out.append(b)
        return bytes(out)

    def counts(self) -> dict[str, int]:
        """Number of injected faults of each kind."""
        c: dict[str, int] = {}
        for e in self.events:
            c[e.kind] = c.get(e.kind, 0) + 1
        return c
