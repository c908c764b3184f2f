"""What a sweep runs and which parameters it takes.

A target is ``"module:function"`` (any importable callable, called as ``fn(params, *, seed, out_dir)``),
a name given to :func:`register_target`, or ``"scene:<name>"``: one episode of
:mod:`tactile_rig.rig.scene_runner`, with parameters ``<model>.<param>`` / ``controller.<param>`` /
``sensor.<param>`` / ``speed_mps`` overriding the scene. :func:`check_params` checks every parameter
name of a grid against its target before anything runs: a scene knows its models', its controller's
and its sensor's parameters, a callable may list its own in ``sweep_params``; one ``ValueError`` names
every unknown one with the closest known names.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import importlib
import inspect
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import tomllib

from tactile_rig.rig.episodes import _devices
from tactile_rig.rig.scene_runner import _set_param, episode_fn, run_episode
from tactile_rig.sim.base import _MODEL_FACTORIES
from tactile_rig.sim.fakes.sensors import ModelSensor, RenderedSensor
from tactile_rig.sim.scenes import resolve_scene_path

__all__ = ["check_params", "check_scene_params", "controller_params", "register_target", "resolve_target"]

_TARGETS: dict[str, Callable[..., Any]] = {}


def register_target(name: str, fn: Callable[..., Any]) -> None:
    """Make ``fn(params, *, seed, out_dir)`` reachable as target ``name`` (in this process)."""
    _TARGETS[name] = fn


def resolve_target(target: str) -> Callable[..., Any]:
    """``module:function`` or ``scene:<name>`` → the callable (errors say what was expected)."""
    if target in _TARGETS:
        return _TARGETS[target]
    kind, sep, rest = target.partition(":")
    if not sep or not rest:
        raise ValueError(f"sweep target {target!r} must be 'module:function' or 'scene:<name>'")
    if kind == "scene":
        try:
            runner = importlib.import_module("tactile_rig.rig.scene_runner")
        except ModuleNotFoundError as exc:
            raise ValueError(f"sweep target {target!r}: the scene runner is not available ({exc})") from None
        fn = getattr(runner, "sweep_point", None) or _scene_episode
        runner.resolve_scene_path(rest)  # an unknown scene fails before anything runs
        return _ScenePoint(rest, fn)
    try:
        module = importlib.import_module(kind)
    except ModuleNotFoundError as exc:
        raise ValueError(f"sweep target {target!r}: cannot import module {kind!r} ({exc})") from None
    fn = module
    for part in rest.split("."):
        fn = getattr(fn, part, None)
        if fn is None:
            raise ValueError(f"sweep target {target!r}: module {kind!r} has no {rest!r}")
    if not callable(fn):
        raise ValueError(f"sweep target {target!r} is not callable")
    return fn


@dataclass(frozen=True)
class _ScenePoint:
    scene: str
    fn: Callable[..., Any]

    def __call__(self, params: dict[str, Any], *, seed: int, out_dir: Path) -> Any:
        return self.fn(self.scene, params, seed=seed, out_dir=out_dir)


def _scene_episode(scene: str, params: dict[str, Any], *, seed: int, out_dir: Path) -> dict[str, Any]:
    """One scene-runner episode: ``params`` keys ``<model>.<param>``, ``controller.<p>``, ``sensor.<p>``
    override the scene (and its per-episode draws); ``speed_mps`` is the runner's speed argument."""

    overrides: dict[str, dict[str, Any]] = {}
    speed = params.get("speed_mps")
    raw: dict[str, Any] | None = None
    for k, v in params.items():
        if k == "speed_mps":
            continue
        section, sep, key = k.partition(".")
        if not sep or not key:
            raise ValueError(f"scene sweep parameter {k!r} must be '<model>.<param>', 'controller.<param>', "
                             "'sensor.<param>' or 'speed_mps'")
        over = overrides.setdefault(section, {})
        name, dot, _idx = key.partition(".")
        if dot:  # an element of a list parameter, e.g. table.point_mm.2
            if name not in over:
                raw = raw if raw is not None else tomllib.loads(resolve_scene_path(scene).read_text(encoding="utf-8"))
                base = raw.get("models", {}).get(section, raw.get(section, {})).get(name)
                over[name] = json.loads(json.dumps(base))  # a copy
            _set_param(over, key, v)
        else:
            over[key] = v
    report = run_episode(scene, seed, speed_mps=speed, overrides=overrides)
    return report.to_json()


# -- checking parameters before anything runs --------------------------------------------------
_SCENE_FIXED = {"speed_mps"}
_SENSOR_KEYS = {"kind"} | {
    n for cls in (ModelSensor, RenderedSensor) for n in inspect.signature(cls.__init__).parameters
    if n not in ("self", "clock", "probe", "render", "process", "rng", "name")}


def _model_params(kind: str) -> set[str] | None:
    """Keyword parameters a world model kind accepts; None when they cannot be told from its code."""
    factory = _MODEL_FACTORIES.get(kind)
    if factory is None:
        return None
    candidates: list[Any] = [factory]
    ret = getattr(factory, "__annotations__", {}).get("return")
    if isinstance(ret, str):  # postponed annotation: look the class up in the factory's module
        ret = getattr(inspect.getmodule(factory), ret, None)
    if isinstance(ret, type):
        candidates.append(vars(ret).get("__init__", ret))  # the class's own signature
    if isinstance(factory, type):
        candidates = [vars(factory).get("__init__", factory)]
    names: set[str] = set()
    for fn in candidates:  # the factory's own keywords, then (when it forwards **params) the class's
        try:
            sig = inspect.signature(fn)
        except (TypeError, ValueError):
            return None
        ps = sig.parameters.values()
        names |= {p.name for p in ps if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)}
        if not any(p.kind is p.VAR_KEYWORD for p in ps):
            return names - {"self", "world", "rng", "clock"}
    return None


def _string_keys_read(module: Any) -> set[str]:
    """String literals a module reads as keys: ``x.get("k", ...)`` and ``x["k"]``."""
    try:
        tree = ast.parse(inspect.getsource(module))
    except (OSError, TypeError):
        return set()
    keys: set[str] = set()
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
                and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            keys.add(node.args[0].value)
        elif isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant) \
                and isinstance(node.slice.value, str):
            keys.add(node.slice.value)
    return keys


def controller_params(kind: str) -> set[str]:
    """Keys an episode wiring of controller ``kind`` understands: its controllers' parameter
    dataclasses plus the keys the wiring itself reads."""
    episode_fn(kind)  # an unknown kind: the runner's own error
    module = importlib.import_module(f"tactile_rig.rig.episodes.{kind}")
    keys = {"kind", "expect", "transport", "motion", "gripper"}
    mods = [module, _devices]
    for m in mods:
        keys |= _string_keys_read(m)
        for obj in vars(m).values():
            if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__name__.endswith("Params"):
                keys |= {f.name for f in dataclasses.fields(obj)}
            sub = inspect.getmodule(obj) if callable(obj) else None
            if sub is not None and sub.__name__.startswith("tactile_rig.rig.episodes._") and sub not in mods:
                mods.append(sub)
    return keys


def _unknown(name: str, known: set[str], what: str) -> str:
    close = difflib.get_close_matches(name, sorted(known), n=3)
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else \
        f"; known: {', '.join(sorted(known))}"
    return f"{what} has no parameter {name!r}{hint}"


def check_scene_params(scene: str, names: Iterable[str]) -> None:
    """Raise one ``ValueError`` listing every sweep parameter the scene would not understand."""
    path = resolve_scene_path(scene)
    raw = tomllib.loads(path.read_text(encoding="utf-8"))
    models = raw.get("models", {})
    kind = raw.get("controller", {}).get("kind")
    problems: list[str] = []
    ctrl_keys: set[str] | None = None
    for full in sorted(set(names)):
        if full in _SCENE_FIXED:
            continue
        section, sep, key = full.partition(".")
        base = key.partition(".")[0]
        if not sep or not key:
            problems.append(f"{full!r} must be '<model>.<param>', 'controller.<param>', 'sensor.<param>' "
                            "or 'speed_mps'")
        elif section == "controller":
            if ctrl_keys is None:
                ctrl_keys = controller_params(kind) | set(raw.get("controller", {})) if kind else set()
            if base not in ctrl_keys:
                problems.append(f"{full!r}: " + _unknown(base, ctrl_keys, f"controller {kind!r}"))
        elif section == "sensor":
            if base not in _SENSOR_KEYS:
                problems.append(f"{full!r}: " + _unknown(base, _SENSOR_KEYS, "the sensor"))
        elif section in models:
            known = _model_params(str(models[section].get("type")))
            if known is None:
                known = set(models[section]) - {"type"}
            if base not in known:
                problems.append(f"{full!r}: " + _unknown(base, known, f"model {section!r} ({models[section].get('type')})"))
        else:
            sections = sorted(set(models) | {"controller", "sensor"})
            close = difflib.get_close_matches(section, sections, n=2)
            problems.append(f"{full!r}: scene {path.stem!r} has no model {section!r}"
                            + (f"; did you mean {' or '.join(repr(c) for c in close)}?" if close
                               else f"; its sections: {', '.join(sections)}"))
    if problems:
        raise ValueError(f"sweep of scene {path.stem!r}: {len(problems)} unknown parameter(s), nothing ran: "
                         + "; ".join(problems))


def check_params(target: str, points: Iterable[Mapping[str, Any]]) -> None:
    """Check every parameter name of every point against ``target`` (one error for all of them)."""
    names = {n for p in points for n in p}
    fn = resolve_target(target)
    if isinstance(fn, _ScenePoint):
        check_scene_params(fn.scene, names)
        return
    known = getattr(fn, "sweep_params", None)
    if known is not None:
        bad = sorted(names - set(known))
        if bad:
            raise ValueError(f"sweep target {target!r}: {len(bad)} unknown parameter(s), nothing ran: "
                             + "; ".join(_unknown(b, set(known), "it") for b in bad))
