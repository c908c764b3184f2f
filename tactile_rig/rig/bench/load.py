"""Reading a bench file: TOML, environment overrides, typing each value from its config field, and
every problem reported at once with its line (or the environment variable it came from) and the fix."""

from __future__ import annotations

import difflib
import glob
import math
import os
import re
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import tomllib

from tactile_rig.core.errors import BadFile, BenchError
from tactile_rig.rig.files import MAX_JSON_DEPTH, check_file, toml_depth
from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.bench.devices import DEVICE_CLASSES, CameraConfig, DeviceConfig
from tactile_rig.rig.bench.toml_lines import line_index

ENV_PREFIX = "TACTILE_RIG_"
MOCK_BENCH_NAME = "mock_bench.toml"
FORCE_MAP_COMMAND = "tactile-rig calibrate force-map"


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
    # Emulated V4L2 cameras (a rehearsal bench): the registry and the preload library a process
    # opening them is started with (tactile_rig.cli.emulation); None on a bench of real cameras.
    v4l2_registry: Path | None = None
    v4l2_preload: Path | None = None

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


def mock_bench_path() -> Path:
    """The built-in bench of mocks shipped with the package."""
    return Path(str(resources.files("tactile_rig.rig").joinpath(MOCK_BENCH_NAME)))


class _Sources:
    """Where each value came from: its line in the file, or the environment variable that set it."""

    def __init__(self, tables: dict[str, int], keys: dict[tuple[str, str], int],
                 env_vars: dict[tuple[str, str], str]) -> None:
        self.tables, self.keys, self.env_vars = tables, keys, env_vars

    def line(self, table: str, key: str | None = None) -> int | None:
        if key is not None and (table, key) in self.env_vars:
            return None
        if key is not None and (table, key) in self.keys:
            return self.keys[(table, key)]
        return self.tables.get(table)

    def origin(self, table: str, key: str | None = None) -> str:
        var = self.env_vars.get((table, key)) if key else None
        return f" (from ${var})" if var else ""


MAX_BENCH_BYTES = 1 << 20  # a bench file is a page of tables; 1 MiB is far beyond any real one


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
        if not p.exists():
            raise BenchError(str(p), [(None, f"bench file {str(p)!r} does not exist "
                                       f"(use --mock for the built-in bench of mocks, or write one: "
                                       f"see {mock_bench_path()})")])
        try:
            check_file(p, "bench file", max_bytes=MAX_BENCH_BYTES, allow_empty=True)
            text = p.read_text(encoding="utf-8")
        except BadFile as exc:
            raise BenchError(str(p), [(None, f"{exc.problem}; expected {exc.expected}")]) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise BenchError(str(p), [(None, f"cannot be read as UTF-8 text ({exc}); expected a TOML file")]) from None
    source = str(path) if path is not None else "<bench>"
    base = Path(path).resolve().parent if path is not None else Path.cwd()
    depth = toml_depth(text)
    if depth > MAX_JSON_DEPTH:
        raise BenchError(source, [(None, f"nests {depth} levels deep; expected at most {MAX_JSON_DEPTH} "
                                         "(a bench file is flat tables of keys)")])
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise BenchError(source, [(int(m.group(1)) if m else None,
                                   f"not valid TOML: {exc} (fix the syntax on that line)")]) from None
    tables, keys = line_index(text)
    problems: list[tuple[int | None, str]] = []
    src = _Sources(tables, keys, _apply_env(data, os.environ if env is None else env, problems))

    head = data.pop("bench", {})
    bench = Bench(name=str(Path(source).stem), devices={}, source=source,
                  path=Path(path) if path is not None else None, text=text)
    if not isinstance(head, dict):
        problems.append((src.line("bench"), "'bench' must be a table: [bench]"))
        head = {}
    _read_head(bench, head, base, src, problems, check_files=check_files)

    emulated = "v4l2_registry" in head
    for table, values in data.items():
        kind = device_kind(table)
        if kind is None:
            known = ["bench", *DEVICE_CLASSES, "camera_<name>"]
            problems.append((src.line(table), _unknown_key("", table, known, what="table")))
            continue
        if not isinstance(values, dict):
            problems.append((src.line(table, None) or keys.get(("", table)),
                             f"'{table}' must be a table: [{table}] with its keys below it"))
            continue
        cfg = _build_device(table, DEVICE_CLASSES[kind], values, base, src, problems,
                            check_ports=check_ports, check_files=check_files, source=source, emulated=emulated)
        if cfg is not None:
            bench.devices[table] = cfg
    if not problems and not bench.devices:
        # An empty (or comments-only) file would pass every check by checking nothing.
        device_tables = ", ".join(f"[{k}]" for k in DEVICE_CLASSES if k != "camera")
        problems.append((None, f"declares no device; expected at least one of the tables {device_tables} or "
                               f"[camera_<name>] (an example: {mock_bench_path()})"))
    if problems:
        raise BenchError(source, problems)
    return bench


def _read_head(bench: Bench, head: dict[str, Any], base: Path, src: _Sources,
               problems: list[tuple[int | None, str]], *, check_files: bool) -> None:
    head_keys: dict[str, type] = {"name": str, "scene": str, "seed": int, "force_map": str, "v4l2_registry": str,
                                  "v4l2_preload": str}
    for key, value in head.items():
        if key not in head_keys:
            problems.append((src.line("bench", key), _unknown_key("bench", key, list(head_keys))
                             + src.origin("bench", key)))
        elif not isinstance(value, head_keys[key]) or isinstance(value, bool):
            problems.append((src.line("bench", key), f"[bench] {key} = {value!r}{src.origin('bench', key)} "
                             f"must be a {head_keys[key].__name__}"))
    bench.name = str(head.get("name", bench.name))
    bench.scene = head.get("scene") if isinstance(head.get("scene"), str) else None
    bench.seed = head.get("seed", 0) if isinstance(head.get("seed"), int) else 0
    if _is_int(head.get("seed")) and not 0 <= head["seed"] < 2**63:
        problems.append((src.line("bench", "seed"), f"[bench] seed = {head['seed']}{src.origin('bench', 'seed')} "
                         f"must be in 0 .. 2**63 - 1 (a NumPy seed)"))
        bench.seed = 0
    emulation = [k for k in ("v4l2_registry", "v4l2_preload") if isinstance(head.get(k), str)]
    if len(emulation) == 1:
        other = "v4l2_preload" if emulation[0] == "v4l2_registry" else "v4l2_registry"
        problems.append((src.line("bench", emulation[0]), f"[bench] {emulation[0]} needs {other} too (emulated "
                         "cameras need both their registry and their library)"))
    elif emulation:
        bench.v4l2_registry = _resolve(base, head["v4l2_registry"])
        bench.v4l2_preload = _resolve(base, head["v4l2_preload"])
    if isinstance(head.get("force_map"), str):
        fm = _resolve(base, head["force_map"])
        bench.force_map = fm
        if check_files and not fm.is_file():
            problems.append((src.line("bench", "force_map"),
                             f"[bench] force_map file '{fm}' does not exist; make it with: "
                             f"{FORCE_MAP_COMMAND} --bench {bench.source} --out {fm}"))


def device_kind(table: str) -> str | None:
    """The device kind of a table name (``camera_left`` is a camera), or None."""
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
    return sorted(glob.glob("/dev/serial/by-id/*")) or sorted(glob.glob("/dev/ttyUSB*") + glob.glob("/dev/ttyACM*"))


def _available_cameras() -> list[str]:
    return sorted(glob.glob("/dev/v4l/by-id/*")) or sorted(glob.glob("/dev/video*"))


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_value(hint: str, value: Any) -> tuple[Any, str | None]:
    """Coerce ``value`` to the field's annotation ``hint``; return (value, problem or None).

    Numbers must be finite: TOML spells ``inf`` and ``nan``, and neither is a limit or a setting."""
    h = hint.replace(" ", "")
    if h == "int":
        return (value, None) if _is_int(value) else (None, f"must be an int, got {value!r}")
    if h == "float":
        if not _is_number(value):
            return None, f"must be a float, got {value!r}"
        if not math.isfinite(value):
            return None, f"must be a finite number, got {value!r}"
        return float(value), None
    if h == "str":
        return (value, None) if isinstance(value, str) else (None, f"must be a str, got {value!r}")
    if h == "list[int]":
        if _is_int(value):
            value = [value]
        if not isinstance(value, list) or not value or not all(_is_int(v) for v in value):
            return None, f"must be a non-empty list of integers such as [1, 2], got {value!r}"
        return list(value), None
    if h == "tuple[float,float]":
        if (not isinstance(value, list) or len(value) != 2 or not all(_is_number(v) for v in value)):
            return None, f"must be [low, high], two numbers, got {value!r}"
        if not all(math.isfinite(v) for v in value):
            return None, f"must be [low, high], two finite numbers, got {value!r}"
        if not value[0] < value[1]:
            return None, f"must be [low, high] with low < high, got {value!r}"
        return (float(value[0]), float(value[1])), None
    if h == "Path|None":
        if not isinstance(value, str) or not value.strip():
            return None, f"must be a file path string, got {value!r}"
        return value, None
    return value, None


def _build_device(table: str, cls: type[DeviceConfig], values: dict[str, Any], base: Path, src: _Sources,
                  problems: list[tuple[int | None, str]], *, check_ports: bool, check_files: bool,
                  source: str, emulated: bool = False) -> DeviceConfig | None:
    spec = {f.name: f for f in fields(cls) if f.name not in ("name", "line")}
    kwargs: dict[str, Any] = {"name": table, "line": src.line(table)}
    for key, value in values.items():
        if key not in spec:
            problems.append((src.line(table, key), _unknown_key(table, key, sorted(spec)) + src.origin(table, key)))
            continue
        field_type = spec[key].type
        hint = field_type if isinstance(field_type, str) else str(field_type)
        coerced, err = _check_value(hint, value)
        if err:
            problems.append((src.line(table, key), f"[{table}] {key}{src.origin(table, key)} {err}"))
            continue
        kwargs[key] = coerced
    if "port" not in values:
        problems.append((src.line(table), f"[{table}] has no 'port'; add e.g. port = "
                         f"\"{cls.example_port}\" (a device path or a rigsim:// mock URL)"))
        return None
    if "port" not in kwargs:
        return None  # a mistyped port was reported above
    # Every file a device names (its calibration, a camera's force map and substance model) is
    # relative to the bench file.
    files = {k: kwargs.pop(k) for k in [k for k in kwargs if k in _path_fields(cls)]}
    cfg = cls(**kwargs)
    for key, value in files.items():
        setattr(cfg, key, _resolve(base, value))

    def problem(key: str, message: str) -> None:
        problems.append((src.line(table, key), f"[{table}] {key}{src.origin(table, key)} {message}"))

    cfg.check(problem)
    _check_presence(cfg, src, problems, check_ports=check_ports, check_files=check_files, source=source,
                    emulated=emulated)
    return cfg


def _path_fields(cls: type[DeviceConfig]) -> set[str]:
    return {f.name for f in fields(cls) if str(f.type).replace(" ", "") == "Path|None"}


# The command that makes each file a camera may name besides its calibration.
_FILE_COMMANDS = {"force_map": FORCE_MAP_COMMAND, "substance_model": "tactile-rig calibrate substance"}


def _check_presence(cfg: DeviceConfig, src: _Sources, problems: list[tuple[int | None, str]], *,
                    check_ports: bool, check_files: bool, source: str, emulated: bool = False) -> None:
    """The port and the calibration file exist (checks of the machine, not of the values)."""
    t = cfg.name
    missing = cfg.port.strip() and "://" not in cfg.port and not Path(cfg.port.partition("#")[0]).exists()
    if check_ports and missing and emulated and isinstance(cfg, CameraConfig):
        problems.append((src.line(t, "port"),
                         f"{t}: port '{cfg.port}' is an emulated camera ([bench] v4l2_registry) that this process "
                         f"does not see: start the process with the environment 'tactile-rig bench env --bench "
                         f"{source}' prints (the tactile-rig command does so by itself), and keep the rehearsal "
                         f"serving it running"))
    elif check_ports and missing:
        avail = _available_cameras() if isinstance(cfg, CameraConfig) else _available_ports()
        listing = f"ports present: {', '.join(avail)}" if avail else "no such ports are present"
        problems.append((src.line(t, "port"),
                         f"{t}: port '{cfg.port}'{src.origin(t, 'port')} does not exist (unplugged, or "
                         f"renamed?); {listing}; prefer a stable /dev/serial/by-id/ path, or use a "
                         f"rigsim:// URL for a mock"))
    if check_files and cfg.calibration is not None and not cfg.calibration.is_file():
        what = cfg.calibration_kind
        cls = DEVICE_CLASSES.get(what)
        cmd = (cls.calibration_command if cls is not None and cls.calibration_command
               else f"tactile-rig calibrate {what}")
        problems.append((src.line(t, "calibration"),
                         f"[{t}] calibration file '{cfg.calibration}' does not exist; make it with: "
                         f"{cmd} --bench {source} --device {t}"))
    for key, cmd in _FILE_COMMANDS.items():
        f = getattr(cfg, key, None)
        if check_files and f is not None and not _model_exists(Path(f)):
            problems.append((src.line(t, key), f"[{t}] {key} file '{f}' does not exist; make it with: "
                             f"{cmd} --bench {source} --camera {t}"))


def _model_exists(p: Path) -> bool:
    """A learned model is named by its .json, its .npz, its stem or its folder."""
    if p.is_dir():
        return any(p.glob("*.json"))
    return p.is_file() or p.with_suffix(".json").is_file()


def _parse_env_value(raw: str) -> Any:
    try:
        if toml_depth(raw) > MAX_JSON_DEPTH:
            return raw  # reported by the key's type check, naming the variable
        return tomllib.loads(f"v = {raw}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError):
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
        if table != "bench" and device_kind(table) is None:
            close = difflib.get_close_matches(table, [*DEVICE_CLASSES, "bench"], n=1, cutoff=0.5)
            hint = f"; did you mean {ENV_PREFIX}{close[0].upper()}__{key_u}?" if close else ""
            problems.append((None, f"environment variable {var}: no device '{table}'{hint}"))
            continue
        if not key:
            problems.append((None, f"environment variable {var}: no key after '__'; expected "
                                   f"{ENV_PREFIX}{table_u}__<KEY>"))
            continue
        section = data.setdefault(table, {})
        if isinstance(section, dict):
            section[key] = _parse_env_value(raw)
            applied[(table, key)] = var
    return applied

