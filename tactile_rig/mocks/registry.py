"""Which mock devices exist, and how a URL or a CLI line builds one.

A device kind (``dynamixel``, ``scale``, ``jig``) registers a factory
``factory(params: Params, *, clock, world) -> SerialDevice``. ``rigsim://KIND?key=value&...``
builds a fresh device on its own :class:`~tactile_rig.core.clock.VirtualClock` (or ``clock=real``);
``rigsim://@NAME`` connects to an instance that a test or a scene registered with
:func:`register_instance` (so a driver and the test share one device, clock and world).
"""

from __future__ import annotations

import importlib
import threading
from dataclasses import dataclass
from typing import Any, Callable, overload
from urllib.parse import parse_qsl, urlsplit

from tactile_rig.core.clock import Clock, RealClock, VirtualClock
from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.sim.scenes import load_scene

_BUILTIN_KIND_MODULES = {
    "dynamixel": "tactile_rig.mocks.dynamixel",
    "scale": "tactile_rig.mocks.scale",
    "jig": "tactile_rig.mocks.grbl",
}


class Params:
    """String parameters from a URL query or a CLI, read with types; unknown keys are an error."""

    def __init__(self, raw: dict[str, str], *, source: str) -> None:
        self.raw = dict(raw)
        self.source = source
        self._used: set[str] = set()

    def _get(self, key: str) -> str | None:
        self._used.add(key)
        return self.raw.get(key)

    def has(self, key: str) -> bool:
        return key in self.raw

    @overload
    def text(self, key: str, default: str) -> str: ...
    @overload
    def text(self, key: str, default: None = None) -> str | None: ...
    def text(self, key: str, default: str | None = None) -> str | None:
        """The parameter as a string, or ``default`` when absent."""
        v = self._get(key)
        return default if v is None else v

    @overload
    def integer(self, key: str, default: int) -> int: ...
    @overload
    def integer(self, key: str, default: None = None) -> int | None: ...
    def integer(self, key: str, default: int | None = None) -> int | None:
        """The parameter as an integer (decimal, ``0x`` hex or ``0b`` binary), or ``default`` when absent."""
        v = self._get(key)
        if v is None:
            return default
        try:
            return int(v, 0)
        except ValueError:
            raise ValueError(f"{self.source}: {key}={v!r} is not an integer") from None

    @overload
    def number(self, key: str, default: float) -> float: ...
    @overload
    def number(self, key: str, default: None = None) -> float | None: ...
    def number(self, key: str, default: float | None = None) -> float | None:
        """The parameter as a float, or ``default`` when absent."""
        v = self._get(key)
        if v is None:
            return default
        try:
            return float(v)
        except ValueError:
            raise ValueError(f"{self.source}: {key}={v!r} is not a number") from None

    def flag(self, key: str, default: bool = False) -> bool:
        """The parameter as a boolean (1/0, true/false, yes/no, on/off), or ``default`` when absent."""
        v = self._get(key)
        if v is None:
            return default
        s = v.strip().lower()
        if s in ("1", "true", "yes", "on"):
            return True
        if s in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"{self.source}: {key}={v!r} is not a boolean (use 1/0, true/false, on/off)")

    def integers(self, key: str, default: list[int] | None = None) -> list[int]:
        """The parameter as a comma- or semicolon-separated list of integers, or ``default`` when absent."""
        v = self._get(key)
        if v is None:
            return list(default or [])
        try:
            return [int(x, 0) for x in v.replace(";", ",").split(",") if x.strip()]
        except ValueError:
            raise ValueError(f"{self.source}: {key}={v!r} is not a comma-separated list of integers") from None

    def check_unused(self, accepted: list[str] | None = None) -> None:
        """Raise ValueError naming any parameter nobody read (a typo, most often)."""
        unknown = sorted(set(self.raw) - self._used)
        if unknown:
            known = ", ".join(sorted(accepted or self._used))
            raise ValueError(f"{self.source}: unknown parameter(s) {', '.join(unknown)}; accepted: {known}")


DeviceFactory = Callable[..., SerialDevice]


@dataclass(frozen=True)
class DeviceKind:
    name: str
    factory: DeviceFactory
    default_baud: int
    description: str


_KINDS: dict[str, DeviceKind] = {}
_INSTANCES: dict[str, tuple[SerialDevice, Clock]] = {}
_LOCK = threading.Lock()


def register_kind(name: str, factory: DeviceFactory, *, default_baud: int, description: str) -> None:
    """Register a mock device kind (done by each mock module at import)."""
    _KINDS[name] = DeviceKind(name, factory, default_baud, description)


def kinds() -> dict[str, DeviceKind]:
    """Every registered kind, importing the built-in mock modules first."""
    for kind, module in _BUILTIN_KIND_MODULES.items():
        if kind not in _KINDS:
            try:
                importlib.import_module(module)
            except ModuleNotFoundError as exc:
                if exc.name != module:
                    raise
    return dict(_KINDS)


def create_device(kind: str, params: Params, *, clock: Clock, world: Any = None) -> SerialDevice:
    """Build a device of ``kind`` from ``params``; unknown kinds and parameters are a ValueError."""
    known = kinds()
    if kind not in known:
        raise ValueError(
            f"unknown mock device {kind!r}; known devices: {', '.join(sorted(known)) or '(none)'}"
        )
    device = known[kind].factory(params, clock=clock, world=world)
    params.check_unused()
    return device


def register_instance(name: str, device: SerialDevice, clock: Clock) -> str:
    """Make ``device`` reachable as ``rigsim://@name``; return that URL."""
    with _LOCK:
        _INSTANCES[name] = (device, clock)
    return f"rigsim://@{name}"


def unregister_instance(name: str) -> None:
    with _LOCK:
        _INSTANCES.pop(name, None)


def device_from_url(url: str) -> tuple[SerialDevice, Clock]:
    """Resolve ``rigsim://KIND?...`` (a new device) or ``rigsim://@NAME`` (a registered one)."""
    parts = urlsplit(url)
    if parts.scheme != "rigsim":
        raise ValueError(f"expected a rigsim:// URL, got {url!r}")
    target = parts.netloc or parts.path.lstrip("/")
    if target.startswith("@"):
        name = target[1:]
        with _LOCK:
            if name not in _INSTANCES:
                raise ValueError(
                    f"{url}: no mock instance named {name!r} is registered "
                    f"(registered: {', '.join(_INSTANCES) or 'none'})"
                )
            return _INSTANCES[name]
    params = Params(dict(parse_qsl(parts.query, keep_blank_values=True)), source=url)
    clock_name = params.text("clock", "virtual")
    if clock_name == "virtual":
        clock: Clock = VirtualClock()
    elif clock_name == "real":
        clock = RealClock()
    else:
        raise ValueError(f"{url}: clock={clock_name!r} must be 'virtual' or 'real'")
    world = None
    scene = params.text("scene")
    if scene:

        world = load_scene(scene, clock=clock, seed=params.integer("seed")).world
    return create_device(target, params, clock=clock, world=world), clock
