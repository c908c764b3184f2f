"""Parameter sweeps of simulated runs on any ``concurrent.futures`` executor.

A sweep is a target (a registered callable) and a grid of parameters. Each point is keyed by a
stable hash of its parameters (and the target), runs with a seed derived from that key, and writes
``OUT/<key>/result.json`` (plus whatever the target writes in its own folder, e.g. ``run.mcap``).
A point whose result exists is skipped, so a sweep resumes after a crash. With ``episodes=N`` each
point runs N episodes, each its own unit of work with its own key and seed (episode 0 keeps the
point's key, so a sweep rerun with more episodes reuses the ones done); :mod:`tactile_rig.rig.sweep_report`
folds them into one row per point (success rate, median and worst of each figure).

Parameters are checked against the target before anything runs: a scene target knows its models'
parameters, its controller's and its sensor's, and a callable may list its own in ``sweep_params``;
every unknown name across the grid is reported in one ``ValueError`` with the closest known names.

Targets: ``"module:function"`` (any importable callable), called as
``fn(params: dict, *, seed: int, out_dir: Path) -> dict`` (a JSON-able result), or
``"scene:<name>"``: one episode of :mod:`tactile_rig.rig.scene_runner` per point, with parameters
``<model>.<param>`` / ``controller.<param>`` / ``sensor.<param>`` / ``speed_mps`` overriding the scene.

Executors: :class:`~concurrent.futures.ProcessPoolExecutor` locally (default), a
``ThreadPoolExecutor`` for debugging (``--executor thread``), or
Dask distributed (the optional extra ``distributed``): a scheduler at ``address`` or a local cluster
started (and closed) by the executor, its logs kept to errors.
"""

from __future__ import annotations

import ast
import concurrent.futures as cf
import dataclasses
import difflib
import hashlib
import importlib
import inspect
import itertools
import json
import logging
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import tomllib

from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.episodes import _devices
from tactile_rig.rig.scene_runner import _set_param, episode_fn, run_episode
from tactile_rig.sim.base import _MODEL_FACTORIES
from tactile_rig.sim.fakes.sensors import ModelSensor, RenderedSensor
from tactile_rig.sim.scenes import resolve_scene_path

RESULT_FILE = "result.json"
KEY_LENGTH = 16  # hex digits of the SHA-256 of the canonical parameters


def canonical(params: Mapping[str, Any]) -> str:
    """Canonical JSON of the parameters: sorted keys, no spaces; 1 and 1.0 give the same text."""
    def norm(v: Any) -> Any:
        if isinstance(v, bool) or v is None or isinstance(v, str):
            return v
        if isinstance(v, (int, float)):
            f = float(v)
            return int(f) if f.is_integer() and abs(f) < 2**53 else f
        if isinstance(v, Mapping):
            return {str(k): norm(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [norm(x) for x in v]
        if hasattr(v, "item"):  # numpy scalar
            return norm(v.item())
        raise ValueError(f"sweep parameter value {v!r} ({type(v).__name__}) is not JSON-able")

    return json.dumps(norm(dict(params)), sort_keys=True, separators=(",", ":"), allow_nan=False)


def point_key(target: str, params: Mapping[str, Any]) -> str:
    """Stable key of a point: the same target and parameters give the same key on every machine."""
    return hashlib.sha256(f"{target}\n{canonical(params)}".encode()).hexdigest()[:KEY_LENGTH]


def episode_key(target: str, params: Mapping[str, Any], episode: int = 0) -> str:
    """Key of episode ``episode`` of a point: episode 0 is the point's own key."""
    if episode == 0:
        return point_key(target, params)
    return hashlib.sha256(f"{target}\n{canonical(params)}\n{int(episode)}".encode()).hexdigest()[:KEY_LENGTH]


def seed_from_key(key: str) -> int:
    """A 32-bit seed derived from the point key (so a point is reproducible from its parameters)."""
    return int(key[:8], 16)


def grid(axes: Mapping[str, Iterable[Any]], fixed: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """The Cartesian product of ``axes`` (name → values), each point merged with ``fixed``."""
    names = list(axes)
    values = [list(axes[n]) for n in names]
    for n, v in zip(names, values):
        if not v:
            raise ValueError(f"sweep axis {n!r} has no values")
    return [{**(fixed or {}), **dict(zip(names, combo))} for combo in itertools.product(*values)]


def parse_axis(spec: str) -> tuple[str, list[Any]]:
    """``name=v1,v2,v3`` or ``name=start:stop:step`` (stop inclusive) → (name, values)."""
    name, sep, rhs = spec.partition("=")
    if not sep or not name.strip() or not rhs.strip():
        raise ValueError(f"--param {spec!r} must look like name=1,2,3 or name=start:stop:step")
    name = name.strip()
    if rhs.count(":") == 2:
        try:
            a, b, s = (float(x) for x in rhs.split(":"))
        except ValueError:
            raise ValueError(f"--param {spec!r}: start:stop:step must be numbers") from None
        if s <= 0 or b < a:
            raise ValueError(f"--param {spec!r}: need step > 0 and stop >= start")
        n = int(round((b - a) / s)) + 1
        vals: list[Any] = [round(a + i * s, 12) for i in range(n)]
        return name, [int(v) if float(v).is_integer() else v for v in vals]
    return name, [_scalar(x.strip()) for x in rhs.split(",") if x.strip()]


def _scalar(text: str) -> Any:
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


# -- targets ----------------------------------------------------------------------------------
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


# -- running ----------------------------------------------------------------------------------
@dataclass
class PointResult:
    """One episode of one point: its key, parameters, seed, status (ok | failed | skipped) and
    result or error; ``point`` is the point's key (shared by its episodes)."""

    key: str
    params: dict[str, Any]
    seed: int
    status: str
    result: Any = None
    error: str | None = None
    wall_s: float = 0.0
    episode: int = 0
    point: str = ""


def run_point(target: str, params: dict[str, Any], out_root: str, episode: int = 0) -> dict[str, Any]:
    """Run one episode of one point in the worker and write its result.json (importable: runs in
    other processes)."""
    key = episode_key(target, params, episode)
    seed = seed_from_key(key)
    out_dir = Path(out_root) / key
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    row: dict[str, Any] = {"key": key, "target": target, "params": params, "seed": seed, "episode": episode,
                           "point": point_key(target, params)}
    try:
        fn = resolve_target(target)
        result = fn(dict(params), seed=seed, out_dir=out_dir)
        row.update(status="ok", result=result)
    except Exception as exc:  # noqa: BLE001 - a failed point is reported, the sweep goes on
        row.update(status="failed", error=f"{type(exc).__name__}: {exc}",
                   traceback=traceback.format_exc(limit=5))
    row["wall_s"] = time.monotonic() - t0

    text = json.dumps(to_jsonable(row), indent=1, allow_nan=False)
    if row["status"] == "ok":
        tmp = out_dir / (RESULT_FILE + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, out_dir / RESULT_FILE)  # atomic: a half-written result never counts as done
    else:
        (out_dir / "error.json").write_text(text, encoding="utf-8")
    return json.loads(text)


@dataclass
class SweepSummary:
    """Counts and every episode's result (one entry per point when ``episodes`` is 1)."""

    out_dir: Path
    points: list[PointResult] = field(default_factory=list)
    target: str = ""
    episodes: int = 1

    @property
    def counts(self) -> dict[str, int]:
        c = {"ok": 0, "skipped": 0, "failed": 0}
        for p in self.points:
            c[p.status] = c.get(p.status, 0) + 1
        return c


class DaskExecutor(cf.Executor):
    """A Dask ``Client``'s executor that also closes the client (and a cluster it started) on
    ``shutdown``; the cluster's logs are kept to errors so a sweep's output stays one table."""

    def __init__(self, client: Any, cluster: Any = None, *, restore_log_level: int | None = None) -> None:
        self.client = client
        self.cluster = cluster
        self._ex = client.get_executor()
        self._log_level = restore_log_level

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        return self._ex.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._ex.shutdown(wait=wait)
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        if self._log_level is not None:
            logging.getLogger("distributed").setLevel(self._log_level)
            self._log_level = None


def dask_executor(address: str | None = None, *, workers: int = 2, processes: bool = True,
                  threads_per_worker: int = 1) -> DaskExecutor:
    """An executor on the Dask scheduler at ``address``, or on a local cluster of ``workers``
    (processes, or threads in this process with ``processes=False``) with no dashboard."""
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise ValueError("--executor dask needs Dask distributed: pip install 'tactile-rig[distributed]'") from None
    # Dask logs its cluster's life at INFO; a sweep's output is its table: keep only errors (here and,
    # through silence_logs, in the workers), restored when the executor shuts down.
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    if address:
        return DaskExecutor(Client(address), restore_log_level=level)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, processes=processes,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return DaskExecutor(Client(cluster), cluster, restore_log_level=level)


def make_executor(kind: str = "process", *, workers: int | None = None, address: str | None = None) -> cf.Executor:
    """``process`` (default), ``thread``, or ``dask`` (needs the 'distributed' extra; a local cluster
    of ``workers`` processes unless ``address`` names a scheduler)."""
    if kind == "process":
        return cf.ProcessPoolExecutor(max_workers=workers)
    if kind == "thread":
        return cf.ThreadPoolExecutor(max_workers=workers)
    if kind == "dask":
        return dask_executor(address, workers=workers or 2)
    raise ValueError(f"executor {kind!r} must be 'process', 'thread' or 'dask'")


def run_sweep(target: str, points: list[dict[str, Any]], out_dir: str | Path, *, episodes: int = 1,
              executor: cf.Executor | None = None, progress: Any = None) -> SweepSummary:
    """Run every episode of every point not done yet on ``executor`` (default: a local process pool).

    Parameter names are checked against the target first (one ``ValueError`` for all of them,
    before anything runs). ``progress`` is a :class:`~tactile_rig.rig.progress.Progress` (or
    anything with ``update``), told once per episode as it ends. Duplicate points run once. The
    summary lists the episodes in the order of ``points`` (episodes in order), however they finished.
    """
    if not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes={episodes!r} must be an integer >= 1")
    resolve_target(target)  # fail early, in this process, on a bad target
    for params in points:
        canonical(params)  # validate JSON-ability before anything runs
    check_params(target, points)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = SweepSummary(out, target=target, episodes=episodes)
    todo: dict[str, tuple[dict[str, Any], int]] = {}
    order: dict[str, int] = {}  # point key -> its place in ``points``
    for params in points:
        pkey = point_key(target, params)
        if pkey in order:
            continue
        order[pkey] = len(order)
        for ep in range(episodes):
            key = episode_key(target, params, ep)
            done = out / key / RESULT_FILE
            if done.is_file():
                try:
                    prev = json.loads(done.read_text(encoding="utf-8"))
                except ValueError:
                    prev = None
                if prev is not None and prev.get("status") == "ok":
                    summary.points.append(PointResult(key, params, seed_from_key(key), "skipped",
                                                      result=prev.get("result"), episode=ep, point=pkey))
                    if progress is not None:
                        progress.update(key=key, status="skipped", params=params, episode=ep)
                    continue
            todo[key] = (params, ep)
    if not todo:
        return summary
    own = executor is None
    ex = executor if executor is not None else make_executor("process")
    try:
        futures = {ex.submit(run_point, target, params, str(out), ep): key for key, (params, ep) in todo.items()}
        for fut in cf.as_completed(futures):
            key = futures[fut]
            params, ep = todo[key]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died: report the point as failed
                row = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
            pr = PointResult(key, params, seed_from_key(key), row.get("status", "failed"),
                             result=row.get("result"), error=row.get("error"), wall_s=row.get("wall_s", 0.0),
                             episode=ep, point=point_key(target, params))
            summary.points.append(pr)
            if progress is not None:
                progress.update(key=key, status=pr.status, params=pr.params, episode=ep, error=pr.error)
    finally:
        if own:
            ex.shutdown(wait=True)
    # as_completed yields in finishing order, which differs from run to run on a pool
    summary.points.sort(key=lambda p: (order[p.point], p.episode))
    return summary


def demo_point(params: dict[str, Any], *, seed: int, out_dir: Path) -> dict[str, Any]:
    """A tiny built-in target (``tactile_rig.rig.sweep:demo_point``): noisy quadratic of ``x``.

    Used by the tests and as an example; the result depends on the parameters and the seed only.
    """
    import numpy as np

    rng = np.random.default_rng(seed)
    x = float(params.get("x", 0.0))
    noise = float(params.get("noise", 0.1))
    if params.get("fail"):
        raise ValueError(f"demo point asked to fail (x={x})")
    y = x * x + noise * float(rng.standard_normal())
    return {"y": y, "seed": seed}


demo_point.sweep_params = ("x", "noise", "fail")  # type: ignore[attr-defined]
