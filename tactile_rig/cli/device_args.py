"""The arguments of a command that opens one device, and the device they name.

Every device command (``gripper``, ``scale``, ``jig``) takes the same ones: ``--port`` (a device
path or URL), ``--bench FILE`` / ``--mock`` (the device of a bench file, or of the built-in bench of
mocks; ``$TACTILE_RIG_BENCH`` when neither is given), ``--baud`` and ``--json``. :func:`open_device`
opens the device they name.

With a bench, the device is its table (``[gripper]``, ``[scale]``, ``[jig]``: a bench has one of
each), with the bench's settings and limits (servo IDs, latency
timer, calibration, a jig's travel); ``--port`` and ``--baud`` replace only the port and the baud
rate. Without one, ``--port`` is required and the kind's defaults apply (:mod:`tactile_rig.rig.bench`:
a jig's ±20 mm and θ ±180°). A bench device is connected as every session connects it
(:func:`~tactile_rig.rig.bench.connect_bench`), so a ``rigsim://`` mock gets the bench's IDs, protocol
and baud, and its clock and world.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Generic, Iterator, TypeVar

from tactile_rig.cli.args import BAUD
from tactile_rig.cli.bench_args import add_bench_arguments, bench_from_args
from tactile_rig.cli.common import add_json_flag
from tactile_rig.core.errors import ConnectErrors, DeviceFault
from tactile_rig.rig.bench import Bench, ConnectContext, DeviceConfig, connect_bench

__all__ = ["DeviceTarget", "add_device_arguments", "device_target", "open_device"]

C = TypeVar("C", bound=DeviceConfig)


@dataclass(frozen=True)
class DeviceTarget(Generic[C]):
    """The one device a command opens: its configuration (the bench's table with ``--port``/``--baud``
    applied, or a bare port with the kind's defaults), where its settings come from, and the bench."""

    config: C
    source: str
    bench: Bench | None = None


def add_device_arguments(parser: argparse.ArgumentParser, kind: str, *, port_example: str,
                         baud_default: str) -> None:
    """Add ``--port``, ``--bench``/``--mock``, ``--baud`` and ``--json`` for a device of ``kind`` (a
    bench device kind: gripper, scale, jig); ``baud_default`` says the bare port's default."""
    parser.add_argument("--port", help=f"device path or URL ({port_example}); default: the bench's [{kind}]")
    add_bench_arguments(parser)
    parser.add_argument("--baud", type=BAUD, help=f"baud rate (default: the bench's; with a bare --port {baud_default})")
    add_json_flag(parser)


def _uses_bench(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "mock", False) or getattr(args, "bench", None) or os.environ.get("TACTILE_RIG_BENCH"))


def device_target(args: argparse.Namespace, cls: type[C], **overrides: Any) -> DeviceTarget[C]:
    """The device of the kind ``cls`` configures (:class:`~tactile_rig.rig.bench.JigConfig`, ...) that
    the command line names. ``overrides`` are further fields the command's own options set (``ids``,
    ``protocol``, ...; None: not given), applied like ``--port`` and ``--baud`` on top of the bench's
    table or the kind's defaults."""
    kind = cls.kind
    given = {k: v for k, v in {"port": args.port, "baud": args.baud, **overrides}.items() if v is not None}
    if not _uses_bench(args):
        if not args.port:
            raise ValueError(f"{kind}: pass --port DEVICE, or --bench FILE / --mock to use the bench's [{kind}]")
        return DeviceTarget(cls(name=kind, **given), f"the default {kind} limits and settings (no bench given)")
    bench = bench_from_args(args, check_files=False)
    cfg = bench.device(kind)  # a BenchError naming the tables the bench has when it has none
    if not isinstance(cfg, cls):
        raise TypeError(f"{bench.source}: [{kind}] configures a {type(cfg).__name__}; expected a {cls.__name__}")
    return DeviceTarget(dataclasses.replace(cfg, **given), bench.source, bench)


@contextmanager
def open_device(target: DeviceTarget[C], build: Callable[[C], Any]) -> Iterator[Any]:
    """Open ``target`` with ``build(config)`` (the command's driver with its own options) and close it
    on leaving. A bench device connects through its bench (mocks on the bench's clock and world); a
    bare port is opened directly."""
    if target.bench is None:
        with build(target.config) as driver:
            yield driver
        return
    cfg = target.config
    bench = target.bench
    one = Bench(name=bench.name, devices={cfg.name: cfg}, source=bench.source, path=bench.path, text=bench.text,
                scene=bench.scene, seed=bench.seed)

    def connect(config: Any, ctx: ConnectContext) -> Any:  # the table, its mock port resolved
        return build(config)

    try:
        rig = connect_bench(one, connectors={cfg.kind: connect})
    except ConnectErrors as exc:
        (err,) = exc.errors.values()
        # One device: its own error, not "1 device(s) failed"; a fault stays a fault (exit 3).
        cause = err.__cause__
        raise (cause if isinstance(cause, DeviceFault) and not isinstance(err, DeviceFault) else err) from None
    try:
        yield rig[cfg.name]
    finally:
        rig.close()
