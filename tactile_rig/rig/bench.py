"""The bench file: one TOML file that says which device is on which port, with what limits.

``bench.toml`` has an optional ``[bench]`` head and one table per device::

    [bench]
    name = "lab bench 1"
    scene = "jig-rotation-sweep"   # mocks only: the world the rigsim:// devices share
    seed = 0

    [gripper]                      # Dynamixel MX-64
    port = "/dev/serial/by-id/usb-FTDI_...-if00-port0"
    baud = 57600
    ids = [1]
    protocol = 2
    current_limit_frac = 0.5
    calibration = "calib/gripper.json"

    [scale]                        # Arduino HX711 load cell
    port = "rigsim://scale"
    baud = 115200
    max_force_n = 50.0
    calibration = "calib/scale.json"

    [jig]                          # GRBL x-y-θ stage
    port = "/dev/ttyACM0"
    baud = 115200
    x_limits_mm = [-20.0, 20.0]
    y_limits_mm = [-20.0, 20.0]
    theta_limits_deg = [-90.0, 90.0]

    [camera]                       # any table named camera or camera_<name>
    port = "/dev/video0"           # or "run.mcap#/camera/left/image": a recording as the camera
    sensor = "gelsight"            # gelsight | fingervision
    mm_per_px_x = 0.0634
    mm_per_px_y = 0.0634
    width = 320
    height = 240
    fps = 25.0
    calibration = "calib/gelsight.npz"

Every device table is optional. Relative calibration paths are relative to the bench file.
Errors name the file, the line, and the fix (a typo'd key gets a ``difflib`` suggestion; a port
that does not exist lists the ports that do; a missing calibration names the command that makes
it). Every problem in the file is reported at once, not just the first.

Environment overrides: ``TACTILE_RIG_<DEVICE>__<KEY>=value`` (e.g.
``TACTILE_RIG_SCALE__PORT=/dev/ttyUSB1``, ``TACTILE_RIG_CAMERA_LEFT__MM_PER_PX_X=0.05``) replace a key
after the file is read; the value is parsed as a TOML value when it parses (numbers, arrays,
booleans, quoted strings), else taken as a bare string.

Mocks: a port ``rigsim://KIND?key=value`` in a bench is **not** opened on its own clock. On
:func:`connect_bench` every such device is built on ONE :class:`~tactile_rig.core.clock.VirtualClock`
and ONE world (the ``[bench] scene``), registered as ``rigsim://@<bench>.<device>``, and the driver
opens that instance: the devices of a mock bench see the same time and the same world. A port
``rigsim://@NAME`` (an instance a test registered) is used as it is.
"""

from __future__ import annotations

import argparse
import difflib
import glob
import os
import re
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Mapping

import tomllib

from tactile_rig.core.clock import RealClock, VirtualClock
from tactile_rig.core.errors import (
    BenchError,
    CalibrationError,
    ConnectErrors,
    DeviceTimeout,
    LimitError,
    LinkCorrupt,
    NotConnected,
    RigError,
)
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.drivers.camera import FingertipCamera
from tactile_rig.drivers.dynamixel.gripper import DynamixelGripper, GripperCalibration
from tactile_rig.drivers.jig import Jig
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.camera import SimulatedCamera
from tactile_rig.mocks.registry import (
    Params,
    create_device,
    register_instance,
    unregister_instance,
)
from tactile_rig.rig.replay import RecordedFrameSource
from tactile_rig.sim.scenes import load_scene

ENV_PREFIX = "TACTILE_RIG_"
SENSOR_TYPES = ("gelsight", "fingervision")
MOCK_BENCH_NAME = "mock_bench.toml"

# The command that writes each kind of calibration file (the next engineer's calibration sessions).
CALIBRATION_COMMANDS = {
    "gripper": "tactile-rig calibrate gripper",
    "scale": "tactile-rig calibrate scale",
    "jig": "tactile-rig calibrate jig",
    "gelsight": "tactile-rig calibrate gelsight",
    "fingervision": "tactile-rig calibrate fingervision",
    "force_map": "tactile-rig calibrate force-map",
}


# -- typed configuration ----------------------------------------------------------------------
@dataclass
class DeviceConfig:
    """What every device table has: where it is and how to reach it."""

    name: str
    port: str
    baud: int
    calibration: Path | None = None
    timeout_s: float = 1.0
    line: int | None = None  # line of the [table] header in the bench file

    kind = "device"

    @property
    def is_mock(self) -> bool:
        return self.port.startswith(("rigsim://", "rigfault://", "loop://"))


@dataclass
class GripperConfig(DeviceConfig):
    """Dynamixel MX-64 gripper: servo IDs, protocol, current limit and opening range (m)."""

    baud: int = 57600
    ids: list[int] = field(default_factory=lambda: [1])
    protocol: int = 2
    current_limit_frac: float = 1.0
    min_opening_m: float = 0.0
    max_opening_m: float = 0.1

    kind = "gripper"


@dataclass
class ScaleConfig(DeviceConfig):
    """Arduino HX711 load cell."""

    baud: int = 115200
    max_force_n: float = 50.0
    rate_hz: float = 10.0

    kind = "scale"


@dataclass
class JigConfig(DeviceConfig):
    """GRBL x-y-θ jig with its soft limits (mm, deg) and speed cap."""

    baud: int = 115200
    x_limits_mm: tuple[float, float] = (-20.0, 20.0)
    y_limits_mm: tuple[float, float] = (-20.0, 20.0)
    z_limits_mm: tuple[float, float] = (0.0, 10.0)
    theta_limits_deg: tuple[float, float] = (-90.0, 90.0)
    max_speed_mmps: float = 10.0

    kind = "jig"


@dataclass
class CameraConfig(DeviceConfig):
    """Fingertip camera and the tactile sensor it images (mm/px in x and y)."""

    baud: int = 0  # cameras have no baud; kept so every device has the same fields
    sensor: str = "gelsight"
    mm_per_px_x: float = 0.0634
    mm_per_px_y: float = 0.0634
    width: int = 320
    height: int = 240
    fps: float = 25.0
    fourcc: str = "MJPG"

    kind = "camera"


DEVICE_CLASSES: dict[str, type[DeviceConfig]] = {
    "gripper": GripperConfig,
    "scale": ScaleConfig,
    "jig": JigConfig,
    "camera": CameraConfig,
}


@dataclass
class Bench:
    """A validated bench: its head fields and its devices by table name."""

    name: str
    devices: dict[str, DeviceConfig]
    source: str = "<bench>"
    path: Path | None = None
    text: str = ""  # the file as read (recorded as an attachment of every session)
    scene: str | None = None
    seed: int = 0
    force_map: Path | None = None  # learned marker-force → newton model (tactile-rig calibrate force-map)

    def device(self, name: str) -> DeviceConfig:
        try:
            return self.devices[name]
        except KeyError:
            raise BenchError(self.source, [(None, f"no [{name}] device in the bench; it has: "
                                            f"{', '.join(self.devices) or '(none)'}")]) from None

    @property
    def cameras(self) -> dict[str, CameraConfig]:
        return {k: v for k, v in self.devices.items() if isinstance(v, CameraConfig)}

    @property
    def is_mock(self) -> bool:
        return bool(self.devices) and all(d.is_mock for d in self.devices.values())

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (for recordings and reports)."""

        return {"name": self.name, "source": self.source, "scene": self.scene, "seed": self.seed,
                "force_map": to_jsonable(self.force_map),
                "devices": {k: {"kind": v.kind, **to_jsonable(v)} for k, v in self.devices.items()}}


# -- line numbers -----------------------------------------------------------------------------
_HEADER_RE = re.compile(r"^\s*\[\s*([A-Za-z0-9_.\-\" ]+?)\s*\]\s*(#.*)?$")
_KEY_RE = re.compile(r"^\s*([A-Za-z0-9_\-]+|\"[^\"]*\")\s*=")
_STRING_RE = re.compile(r'"(?:[^"\\]|\\.)*"|\'[^\']*\'')


def line_index(text: str) -> tuple[dict[str, int], dict[tuple[str, str], int]]:
    """Lines (1-based) of each ``[table]`` header and each ``key =`` in it (tomllib keeps none)."""
    tables: dict[str, int] = {}
    keys: dict[tuple[str, str], int] = {}
    current = ""
    depth = 0  # bracket depth of a multi-line array: its lines hold no keys
    for n, raw in enumerate(text.splitlines(), start=1):
        code = raw
        if depth == 0:
            m = _HEADER_RE.match(raw)
            if m:
                current = m.group(1).replace('"', "").strip()
                tables.setdefault(current, n)
                continue
            k = _KEY_RE.match(raw)
            if k:
                keys.setdefault((current, k.group(1).strip('"')), n)
                code = raw[k.end():]
        # Brackets inside strings and comments do not open arrays.
        code = _STRING_RE.sub('""', code).split("#", 1)[0]
        depth = max(0, depth + code.count("[") - code.count("]"))
    return tables, keys


# -- loading ----------------------------------------------------------------------------------
def mock_bench_path() -> Path:
    """The built-in bench of mocks shipped with the package."""
    return Path(str(resources.files("tactile_rig.rig").joinpath(MOCK_BENCH_NAME)))


def load_bench(
    path: str | Path | None = None,
    *,
    text: str | None = None,
    env: Mapping[str, str] | None = None,
    check_ports: bool = True,
    check_files: bool = True,
) -> Bench:
    """Read, override from the environment, and validate a bench file (``path`` or ``text``).

    ``env`` defaults to ``os.environ``. ``check_ports`` verifies that device paths exist;
    ``check_files`` that calibration files exist. Raises :class:`BenchError` listing every problem
    with its line and fix.
    """
    if text is None:
        if path is None:
            raise ValueError("load_bench needs a path or text")
        p = Path(path)
        if not p.is_file():
            raise BenchError(str(p), [(None, f"bench file {str(p)!r} does not exist "
                                       f"(use --mock for the built-in bench of mocks, or write one: "
                                       f"see {mock_bench_path()})")])
        text = p.read_text(encoding="utf-8")
    source = str(path) if path is not None else "<bench>"
    base = Path(path).resolve().parent if path is not None else Path.cwd()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise BenchError(source, [(int(m.group(1)) if m else None,
                                   f"not valid TOML: {exc} (fix the syntax on that line)")]) from None
    tables, keys = line_index(text)
    problems: list[tuple[int | None, str]] = []
    env_lines = _apply_env(data, os.environ if env is None else env, problems)

    def line_of(table: str, key: str | None = None) -> int | None:
        if key is not None and (table, key) in env_lines:
            return None
        if key is not None and (table, key) in keys:
            return keys[(table, key)]
        return tables.get(table)

    def where(table: str, key: str | None = None) -> str:
        envvar = env_lines.get((table, key)) if key else None
        return f" (from ${envvar})" if envvar else ""

    head = data.pop("bench", {})
    bench = Bench(name=str(Path(source).stem), devices={}, source=source,
                  path=Path(path) if path is not None else None, text=text)
    if not isinstance(head, dict):
        problems.append((line_of("bench"), "'bench' must be a table: [bench]"))
        head = {}
    head_keys = {"name": str, "scene": str, "seed": int, "force_map": str}
    for key, value in head.items():
        if key not in head_keys:
            problems.append((line_of("bench", key), _unknown_key("bench", key, list(head_keys))))
        elif not isinstance(value, head_keys[key]) or isinstance(value, bool):
            problems.append((line_of("bench", key), f"[bench] {key} = {value!r}{where('bench', key)} "
                             f"must be a {head_keys[key].__name__}"))
    bench.name = str(head.get("name", bench.name))
    bench.scene = head.get("scene") if isinstance(head.get("scene"), str) else None
    bench.seed = head.get("seed", 0) if isinstance(head.get("seed"), int) else 0
    if isinstance(head.get("force_map"), str):
        fm = _resolve(base, head["force_map"])
        bench.force_map = fm
        if check_files and not fm.is_file():
            problems.append((line_of("bench", "force_map"),
                             f"[bench] force_map file '{fm}' does not exist; make it with: "
                             f"{CALIBRATION_COMMANDS['force_map']} --bench {source} --out {fm}"))

    for table, values in data.items():
        kind = _device_kind(table)
        if kind is None:
            known = ["bench", *DEVICE_CLASSES, "camera_<name>"]
            problems.append((line_of(table), _unknown_key("", table, known, what="table")))
            continue
        if not isinstance(values, dict):
            problems.append((line_of(table, None) or keys.get(("", table)),
                             f"'{table}' must be a table: [{table}] with its keys below it"))
            continue
        cfg = _build_device(table, kind, values, base, line_of, where, problems,
                            check_ports=check_ports, check_files=check_files, source=source)
        if cfg is not None:
            bench.devices[table] = cfg
    if problems:
        raise BenchError(source, problems)
    return bench


def _device_kind(table: str) -> str | None:
    if table in DEVICE_CLASSES:
        return table
    if table.startswith("camera_") and len(table) > len("camera_"):
        return "camera"
    return None


def _unknown_key(table: str, key: str, known: list[str], *, what: str = "key") -> str:
    close = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
    hint = f"did you mean '{close[0]}'?" if close else f"known {what}s: {', '.join(known)}"
    where = f" in [{table}]" if table else ""
    return f"unknown {what} '{key}'{where}; {hint}"


def _resolve(base: Path, p: str) -> Path:
    q = Path(os.path.expanduser(p))
    return q if q.is_absolute() else base / q


def _available_ports() -> list[str]:
    found = sorted(glob.glob("/dev/serial/by-id/*")) or sorted(
        glob.glob("/dev/ttyUSB*") + glob.glob("/dev/ttyACM*"))
    return found


def _available_cameras() -> list[str]:
    return sorted(glob.glob("/dev/v4l/by-id/*")) or sorted(glob.glob("/dev/video*"))


_TYPES: dict[str, Callable[[Any], bool]] = {
    "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "str": lambda v: isinstance(v, str),
}


def _check_value(name: str, hint: str, value: Any) -> tuple[Any, str | None]:
    """Coerce ``value`` to the field's annotation ``hint``; return (value, problem or None)."""
    h = hint.replace(" ", "")
    if h in ("int", "float", "str"):
        if not _TYPES[h](value):
            return None, f"must be a{'n' if h == 'int' else ''} {h}, got {value!r}"
        return (float(value) if h == "float" else value), None
    if h == "list[int]":
        if isinstance(value, int) and not isinstance(value, bool):
            value = [value]
        if not isinstance(value, list) or not value or not all(_TYPES["int"](v) for v in value):
            return None, f"must be a non-empty list of integers such as [1, 2], got {value!r}"
        return list(value), None
    if h == "tuple[float,float]":
        if (not isinstance(value, list) or len(value) != 2
                or not all(_TYPES["float"](v) for v in value) or not value[0] < value[1]):
            return None, f"must be [low, high] with low < high, got {value!r}"
        return (float(value[0]), float(value[1])), None
    if h == "Path|None":
        if not isinstance(value, str):
            return None, f"must be a file path string, got {value!r}"
        return value, None
    return value, None


def _build_device(table: str, kind: str, values: dict[str, Any], base: Path,
                  line_of: Callable[..., int | None], where: Callable[..., str],
                  problems: list[tuple[int | None, str]], *, check_ports: bool, check_files: bool,
                  source: str) -> DeviceConfig | None:
    cls = DEVICE_CLASSES[kind]
    spec = {f.name: f for f in fields(cls) if f.name not in ("name", "line")}
    kwargs: dict[str, Any] = {"name": table, "line": line_of(table)}
    for key, value in values.items():
        if key not in spec:
            problems.append((line_of(table, key), _unknown_key(table, key, sorted(spec))))
            continue
        hint = spec[key].type if isinstance(spec[key].type, str) else str(spec[key].type)
        coerced, err = _check_value(key, hint, value)
        if err:
            problems.append((line_of(table, key), f"[{table}] {key}{where(table, key)} {err}"))
            continue
        kwargs[key] = coerced
    if "port" not in values:
        problems.append((line_of(table), f"[{table}] has no 'port'; add e.g. port = "
                         f"\"{_example_port(kind)}\" (a device path or a rigsim:// mock URL)"))
    if "port" not in values:
        return None
    cal = kwargs.pop("calibration", None)
    cfg = cls(**kwargs)
    if cal is not None:
        cfg.calibration = _resolve(base, cal)
    _validate_device(cfg, line_of, where, problems, check_ports=check_ports,
                     check_files=check_files, source=source)
    return cfg


def _example_port(kind: str) -> str:
    return {"camera": "/dev/video0", "gripper": "/dev/serial/by-id/usb-FTDI_...-port0"}.get(
        kind, "/dev/ttyUSB0")


def _validate_device(cfg: DeviceConfig, line_of: Callable[..., int | None], where: Callable[..., str],
                     problems: list[tuple[int | None, str]], *, check_ports: bool, check_files: bool,
                     source: str) -> None:
    t = cfg.name

    def bad(key: str, msg: str) -> None:
        problems.append((line_of(t, key), f"[{t}] {key}{where(t, key)} {msg}"))

    if check_ports and "://" not in cfg.port and not Path(cfg.port.partition("#")[0]).exists():
        avail = _available_cameras() if isinstance(cfg, CameraConfig) else _available_ports()
        listing = f"ports present: {', '.join(avail)}" if avail else "no such ports are present"
        problems.append((line_of(t, "port"),
                         f"{t}: port '{cfg.port}'{where(t, 'port')} does not exist (unplugged, or "
                         f"renamed?); {listing}; prefer a stable /dev/serial/by-id/ path, or use a "
                         f"rigsim:// URL for a mock"))
    if not isinstance(cfg, CameraConfig) and not 300 <= cfg.baud <= 4_500_000:
        bad("baud", f"= {cfg.baud} is not a serial baud rate (300 .. 4500000), e.g. 57600 or 115200")
    if not 0 < cfg.timeout_s <= 60:
        bad("timeout_s", f"= {cfg.timeout_s} must be in (0, 60] s")
    if isinstance(cfg, GripperConfig):
        if cfg.protocol not in (1, 2):
            bad("protocol", f"= {cfg.protocol} must be 1 or 2 (Dynamixel protocol version)")
        if not all(0 <= i <= 252 for i in cfg.ids):
            bad("ids", f"= {cfg.ids} must be Dynamixel IDs in 0..252")
        if not 0 < cfg.current_limit_frac <= 1:
            bad("current_limit_frac", f"= {cfg.current_limit_frac} must be in (0, 1]")
        if not 0 <= cfg.min_opening_m < cfg.max_opening_m:
            bad("max_opening_m", f"= {cfg.max_opening_m} must exceed min_opening_m = {cfg.min_opening_m} >= 0")
    if isinstance(cfg, ScaleConfig):
        if not cfg.max_force_n > 0:
            bad("max_force_n", f"= {cfg.max_force_n} must be > 0 N")
        if cfg.rate_hz not in (10.0, 80.0):
            bad("rate_hz", f"= {cfg.rate_hz} must be 10 or 80 (the HX711 RATE pin)")
    if isinstance(cfg, JigConfig) and not cfg.max_speed_mmps > 0:
        bad("max_speed_mmps", f"= {cfg.max_speed_mmps} must be > 0 mm/s")
    if isinstance(cfg, CameraConfig):
        if cfg.sensor not in SENSOR_TYPES:
            close = difflib.get_close_matches(cfg.sensor, SENSOR_TYPES, n=1, cutoff=0.4)
            hint = f"; did you mean '{close[0]}'?" if close else ""
            bad("sensor", f"= {cfg.sensor!r} must be one of {', '.join(SENSOR_TYPES)}{hint}")
        for key in ("mm_per_px_x", "mm_per_px_y"):
            v = getattr(cfg, key)
            if not 0 < v < 10:
                bad(key, f"= {v} must be in (0, 10) mm/px (GelSight Mini: 0.0634 at 320x240)")
        if cfg.width <= 0 or cfg.height <= 0:
            bad("width", f"= {cfg.width}x{cfg.height} must be a positive frame size in px")
        if not cfg.fps > 0:
            bad("fps", f"= {cfg.fps} must be > 0 frames per second")
    if check_files and cfg.calibration is not None and not cfg.calibration.is_file():
        what = cfg.sensor if isinstance(cfg, CameraConfig) else cfg.kind
        cmd = CALIBRATION_COMMANDS.get(what, f"tactile-rig calibrate {what}")
        problems.append((line_of(t, "calibration"),
                         f"[{t}] calibration file '{cfg.calibration}' does not exist; make it with: "
                         f"{cmd} --bench {source} --device {t}"))


def _parse_env_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def _apply_env(data: dict[str, Any], env: Mapping[str, str],
               problems: list[tuple[int | None, str]]) -> dict[tuple[str, str], str]:
    """Apply ``TACTILE_RIG_<TABLE>__<KEY>`` variables to ``data``; return (table, key) → variable."""
    applied: dict[tuple[str, str], str] = {}
    for var, raw in sorted(env.items()):
        if not var.startswith(ENV_PREFIX) or "__" not in var[len(ENV_PREFIX):]:
            continue
        table_u, _, key_u = var[len(ENV_PREFIX):].partition("__")
        table, key = table_u.lower(), key_u.lower()
        if table != "bench" and _device_kind(table) is None:
            close = difflib.get_close_matches(table, [*DEVICE_CLASSES, "bench"], n=1, cutoff=0.5)
            hint = f"; did you mean {ENV_PREFIX}{close[0].upper()}__{key_u}?" if close else ""
            problems.append((None, f"environment variable {var}: no device '{table}'{hint}"))
            continue
        section = data.setdefault(table, {})
        if isinstance(section, dict):
            section[key] = _parse_env_value(raw)
            applied[(table, key)] = var
    return applied


# -- CLI helpers ------------------------------------------------------------------------------
def add_bench_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--bench FILE`` / ``--mock`` (mutually exclusive) to a subcommand's parser."""
    g = parser.add_mutually_exclusive_group()
    g.add_argument("--bench", metavar="FILE",
                   help="bench.toml describing the devices (default: $TACTILE_RIG_BENCH)")
    g.add_argument("--mock", action="store_true",
                   help="use the built-in bench of mocks (one virtual clock and world)")


def bench_from_args(args: argparse.Namespace, *, check_files: bool = True) -> Bench:
    """The :class:`Bench` chosen by ``--bench``/``--mock`` (or ``$TACTILE_RIG_BENCH``)."""
    if getattr(args, "mock", False):
        return load_bench(mock_bench_path(), check_files=check_files)
    path = getattr(args, "bench", None) or os.environ.get("TACTILE_RIG_BENCH")
    if not path:
        raise ValueError("no bench given: pass --bench FILE, --mock, or set TACTILE_RIG_BENCH")
    return load_bench(path, check_files=check_files)


# -- connecting -------------------------------------------------------------------------------
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


Connector = Callable[[DeviceConfig, "ConnectContext"], Any]


@dataclass
class ConnectContext:
    """What a connector gets besides its config: the bench's clock and world (mocks)."""

    bench: Bench
    clock: Any
    world: Any = None


def _port_for(cfg: DeviceConfig, ctx: ConnectContext, instances: list[str]) -> str:
    """A rigsim://KIND?... port becomes an instance on the bench's shared clock and world."""
    if not cfg.port.startswith("rigsim://") or cfg.port.startswith("rigsim://@"):
        return cfg.port
    from urllib.parse import parse_qsl, urlsplit


    parts = urlsplit(cfg.port)
    kind = parts.netloc or parts.path.lstrip("/")
    raw = dict(parse_qsl(parts.query, keep_blank_values=True))
    raw.pop("clock", None)  # the bench's clock wins: one time for every device
    raw.pop("scene", None)
    raw.pop("seed", None)
    # The mock runs as the bench says the real device is set up, unless the URL says otherwise.
    if cfg.baud:
        raw.setdefault("baud", str(cfg.baud))
    if isinstance(cfg, GripperConfig):
        raw.setdefault("ids", ",".join(str(i) for i in cfg.ids))
        raw.setdefault("protocol", str(cfg.protocol))
    device = create_device(kind, Params(raw, source=f"{ctx.bench.source} [{cfg.name}] port"),
                           clock=ctx.clock, world=ctx.world)
    name = f"{ctx.bench.name}.{cfg.name}"
    instances.append(name)
    return register_instance(name, device, ctx.clock)


def _connect_gripper(cfg: DeviceConfig, ctx: ConnectContext) -> Any:
    assert isinstance(cfg, GripperConfig)

    cal = None
    if cfg.calibration is not None:
        import json


        try:
            d = json.loads(cfg.calibration.read_text(encoding="utf-8"))
            cal = GripperCalibration.from_dict(d.get("calibration", d) if isinstance(d, dict) else d)
        except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
            raise CalibrationError(f"gripper calibration {cfg.calibration} is unreadable: {exc}; re-make it "
                                   f"with: {CALIBRATION_COMMANDS['gripper']}", device=cfg.name) from None
    return DynamixelGripper(cfg.port, dxl_id=cfg.ids[0], protocol=cfg.protocol, baudrate=cfg.baud, calibration=cal)


def _connect_scale(cfg: DeviceConfig, ctx: ConnectContext) -> Any:
    return Scale(cfg.port, baudrate=cfg.baud, device=cfg.name)


def _connect_jig(cfg: DeviceConfig, ctx: ConnectContext) -> Any:
    assert isinstance(cfg, JigConfig)

    return Jig(cfg.port, baudrate=cfg.baud, x_range_mm=cfg.x_limits_mm, y_range_mm=cfg.y_limits_mm,
               theta_range_deg=cfg.theta_limits_deg, device=cfg.name)


def _connect_camera(cfg: DeviceConfig, ctx: ConnectContext) -> Any:
    """A V4L2 camera, or for ``rigsim://camera?model=NAME`` a camera rendering the bench's world."""
    assert isinstance(cfg, CameraConfig)

    fmt = {"fourcc": cfg.fourcc, "width": cfg.width, "height": cfg.height, "fps": cfg.fps}
    path, _, topic = cfg.port.partition("#")
    if path.endswith(".mcap"):  # a recording served as the camera: "run.mcap" or "run.mcap#/camera/left/image"

        src = RecordedFrameSource(path, topic=topic or None, clock=ctx.clock)
        return FingertipCamera(src, clock=ctx.clock, name=cfg.name, **fmt).open()
    if cfg.port.startswith("rigsim://"):

        sim = SimulatedCamera(cfg.port, clock=ctx.clock, name=cfg.name, world=ctx.world, seed=ctx.bench.seed, **fmt)
        return FingertipCamera(sim, clock=ctx.clock, name=cfg.name, **fmt).open()
    return FingertipCamera(cfg.port, name=cfg.name, **fmt).open()


CONNECTORS: dict[str, Connector] = {
    "gripper": _connect_gripper,
    "scale": _connect_scale,
    "jig": _connect_jig,
    "camera": _connect_camera,
}


def connect_bench(bench: Bench, *, connectors: Mapping[str, Connector] | None = None,
                  clock: Any = None) -> Rig:
    """Connect every device of ``bench``; raise :class:`ConnectErrors` naming EVERY device that failed.

    Mock devices (``rigsim://KIND?...``) share one VirtualClock and the ``[bench] scene`` world.
    Devices that did connect are closed again when any fails. ``connectors`` maps a device kind to
    ``fn(config, context) -> driver`` (defaults: :data:`CONNECTORS`).
    """

    table = dict(CONNECTORS)
    if connectors:
        table.update(connectors)
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
            devices[name] = table[cfg.kind](cfg, ctx)
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
    import copy

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
