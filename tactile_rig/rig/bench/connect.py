"""Connecting a bench: every device's driver, mocks on one virtual clock and one world, and every
failure reported together with its port."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping
from urllib.parse import parse_qsl, urlsplit

from tactile_rig.core.clock import RealClock, VirtualClock
from tactile_rig.core.errors import (
    CalibrationError,
    ConnectErrors,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
)
from tactile_rig.mocks.registry import (
    Params,
    create_device,
    register_instance,
    unregister_instance,
)
from tactile_rig.rig.bench.devices import ConnectContext, DeviceConfig
from tactile_rig.rig.bench.load import Bench
from tactile_rig.sim.scenes import load_scene


@dataclass
class Rig:
    """A connected bench: the driver objects by device name, the clock and (mocks) the world."""

    bench: Bench
    devices: dict[str, Any]
    clock: Any
    world: Any = None
    mock_instances: list[str] = field(default_factory=list)

    def __getitem__(self, name: str) -> Any:
        return self.devices[name]

    @property
    def gripper(self) -> Any:
        return self.devices.get("gripper")

    @property
    def scale(self) -> Any:
        return self.devices.get("scale")

    @property
    def jig(self) -> Any:
        return self.devices.get("jig")

    @property
    def cameras(self) -> dict[str, Any]:
        return {k: v for k, v in self.devices.items() if k in self.bench.cameras}

    def close(self) -> None:
        """Close every device (errors while closing are ignored: the rig is going away)."""
        for dev in self.devices.values():
            _close_quietly(dev)

        for name in self.mock_instances:
            unregister_instance(name)

    def __enter__(self) -> "Rig":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _close_quietly(dev: Any) -> None:
    close = getattr(dev, "close", None)
    if callable(close):
        try:
            close()
        except Exception:  # noqa: BLE001 - closing must not mask the error being reported
            pass


Connector = Callable[[DeviceConfig, ConnectContext], Any]


def _port_for(cfg: DeviceConfig, ctx: ConnectContext, instances: list[str]) -> str:
    """A rigsim://KIND?... port becomes an instance on the bench's shared clock and world."""
    if not cfg.port.startswith("rigsim://") or cfg.port.startswith("rigsim://@"):
        return cfg.port
    parts = urlsplit(cfg.port)
    kind = parts.netloc or parts.path.lstrip("/")
    raw = dict(parse_qsl(parts.query, keep_blank_values=True))
    raw.pop("clock", None)  # the bench's clock wins: one time for every device
    raw.pop("scene", None)
    raw.pop("seed", None)
    # The mock is set up as the bench says the real device is (a servo's ID, protocol, baud), unless
    # the URL says otherwise; a firmware's fixed settings stay the firmware's.
    for key, value in cfg.mock_params().items():
        raw.setdefault(key, value)
    device = create_device(kind, Params(raw, source=f"{ctx.bench.source} [{cfg.name}] port"),
                           clock=ctx.clock, world=ctx.world)
    name = f"{ctx.bench.name}.{cfg.name}"
    instances.append(name)
    return register_instance(name, device, ctx.clock)


def connect_bench(bench: Bench, *, connectors: Mapping[str, Connector] | None = None,
                  clock: Any = None) -> Rig:
    """Connect every device of ``bench``; raise :class:`ConnectErrors` naming EVERY device that failed.

    Mock devices (``rigsim://KIND?...``) share one VirtualClock and the ``[bench] scene`` world.
    Devices that did connect are closed again when any fails. ``connectors`` maps a device kind to
    ``fn(config, context) -> driver`` replacing that kind's own :meth:`DeviceConfig.connect`.
    """
    table = dict(connectors or {})
    any_sim = any(d.port.startswith("rigsim://") for d in bench.devices.values())
    if clock is None:
        clock = VirtualClock() if any_sim else RealClock()
    world = None
    if any_sim and bench.scene:
        world = load_scene(bench.scene, clock=clock, seed=bench.seed).world
    ctx = ConnectContext(bench=bench, clock=clock, world=world)
    devices: dict[str, Any] = {}
    errors: dict[str, BaseException] = {}
    instances: list[str] = []
    for name, cfg in bench.devices.items():
        try:
            if cfg.kind != "camera":
                cfg = _with_port(cfg, _port_for(cfg, ctx, instances))
            connect = table.get(cfg.kind)
            devices[name] = connect(cfg, ctx) if connect is not None else cfg.connect(ctx)
        except ModuleNotFoundError as exc:
            errors[name] = RigError(f"driver not available ({exc})", device=name)
        except Exception as exc:  # noqa: BLE001 - every failure is collected and reported together
            errors[name] = exc
    rig = Rig(bench=bench, devices=devices, clock=clock, world=world, mock_instances=instances)
    if errors:
        rig.close()
        raise ConnectErrors({n: _name_port(bench.devices[n], e) for n, e in errors.items()})
    return rig


def _with_port(cfg: DeviceConfig, port: str) -> DeviceConfig:
    if port == cfg.port:
        return cfg
    c = copy.copy(cfg)
    c.port = port
    return c


def _name_port(cfg: DeviceConfig, exc: BaseException) -> BaseException:
    """Make sure the reported error says which port the device was on (keeping the error's class
    when it is one of the plain ones, so callers can still tell a timeout from a missing port)."""

    if cfg.port in str(exc):
        return exc
    plain = (RigError, NotConnected, DeviceTimeout, LinkCorrupt, LimitError, CalibrationError)
    if type(exc) in plain:
        assert isinstance(exc, RigError)
        wrapped: RigError = type(exc)(f"{exc} (port {cfg.port})", device=exc.device or cfg.name)
    else:
        wrapped = RigError(f"{type(exc).__name__}: {exc} (port {cfg.port})", device=cfg.name)
    wrapped.__cause__ = exc
    return wrapped
