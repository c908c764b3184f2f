"""Parameter sweeps of simulated runs on any ``concurrent.futures`` executor.

A sweep is a target (a registered callable) and a grid of parameters. Each point is keyed by a
stable hash of its parameters (and the target), runs with a seed derived from that key, and writes
``OUT/<key>/result.json`` (plus whatever the target writes in its own folder, e.g. ``run.mcap``).
A point whose result exists is skipped, so a sweep resumes after a crash.

Targets: ``"module:function"`` (any importable callable), called as
``fn(params: dict, *, seed: int, out_dir: Path) -> dict`` (a JSON-able result), or
``"scene:<name>"``: one episode of :mod:`tactile_rig.rig.scene_runner` per point, with parameters
``<model>.<param>`` / ``controller.<param>`` / ``sensor.<param>`` / ``speed_mps`` overriding the scene.

Executors: :class:`~concurrent.futures.ProcessPoolExecutor` locally (default), a
``ThreadPoolExecutor`` for debugging (``--executor thread``), or
Dask distributed via ``Client(address).get_executor()`` (the optional extra ``distributed``).
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import importlib
import itertools
import json
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.scene_runner import run_episode

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
    return fn  # type: ignore[return-value]


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
    for k, v in params.items():
        if k == "speed_mps":
            continue
        section, sep, key = k.partition(".")
        if not sep or not key:
            raise ValueError(f"scene sweep parameter {k!r} must be '<model>.<param>', 'controller.<param>', "
                             "'sensor.<param>' or 'speed_mps'")
        overrides.setdefault(section, {})[key] = v
    report = run_episode(scene, seed, speed_mps=speed, overrides=overrides)
    return report.to_json()


# -- running ----------------------------------------------------------------------------------
@dataclass
class PointResult:
    """One point: its key, parameters, seed, status (ok | failed | skipped) and result or error."""

    key: str
    params: dict[str, Any]
    seed: int
    status: str
    result: Any = None
    error: str | None = None
    wall_s: float = 0.0


def run_point(target: str, params: dict[str, Any], out_root: str) -> dict[str, Any]:
    """Run one point in the worker and write its result.json (importable: runs in other processes)."""
    key = point_key(target, params)
    seed = seed_from_key(key)
    out_dir = Path(out_root) / key
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    row: dict[str, Any] = {"key": key, "target": target, "params": params, "seed": seed}
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
    """Counts and every point's result."""

    out_dir: Path
    points: list[PointResult] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        c = {"ok": 0, "skipped": 0, "failed": 0}
        for p in self.points:
            c[p.status] = c.get(p.status, 0) + 1
        return c


def make_executor(kind: str = "process", *, workers: int | None = None, address: str | None = None) -> cf.Executor:
    """``process`` (default), ``thread``, or ``dask`` (needs the 'distributed' extra and ``address``)."""
    if kind == "process":
        return cf.ProcessPoolExecutor(max_workers=workers)
    if kind == "thread":
        return cf.ThreadPoolExecutor(max_workers=workers)
    if kind == "dask":
        try:
            from distributed import Client
        except ModuleNotFoundError:
            raise ValueError("--executor dask needs Dask distributed: pip install 'tactile-rig[distributed]'") from None
        client = Client(address) if address else Client(n_workers=workers or 2, processes=True)
        return client.get_executor()
    raise ValueError(f"executor {kind!r} must be 'process', 'thread' or 'dask'")


def run_sweep(target: str, points: list[dict[str, Any]], out_dir: str | Path, *,
              executor: cf.Executor | None = None, progress: Any = None) -> SweepSummary:
    """Run every point not done yet on ``executor`` (default: a local process pool).

    ``progress`` is a :class:`~tactile_rig.rig.progress.Progress` (or anything with ``update``).
    Duplicate points (same key) run once.
    """
    resolve_target(target)  # fail early, in this process, on a bad target
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = SweepSummary(out)
    todo: dict[str, dict[str, Any]] = {}
    for params in points:
        canonical(params)  # validate JSON-ability before anything runs
        key = point_key(target, params)
        if key in todo or any(p.key == key for p in summary.points):
            continue
        done = out / key / RESULT_FILE
        if done.is_file():
            try:
                prev = json.loads(done.read_text(encoding="utf-8"))
            except ValueError:
                prev = None
            if prev is not None and prev.get("status") == "ok":
                summary.points.append(PointResult(key, params, seed_from_key(key), "skipped",
                                                  result=prev.get("result")))
                if progress is not None:
                    progress.update(key=key, status="skipped", params=params)
                continue
        todo[key] = params
    if not todo:
        return summary
    own = executor is None
    ex = executor if executor is not None else make_executor("process")
    try:
        futures = {ex.submit(run_point, target, params, str(out)): key for key, params in todo.items()}
        for fut in cf.as_completed(futures):
            key = futures[fut]
            try:
                row = fut.result()
            except Exception as exc:  # noqa: BLE001 - a worker that died: report the point as failed
                row = {"status": "failed", "error": f"{type(exc).__name__}: {exc}"}
            pr = PointResult(key, todo[key], seed_from_key(key), row.get("status", "failed"),
                             result=row.get("result"), error=row.get("error"), wall_s=row.get("wall_s", 0.0))
            summary.points.append(pr)
            if progress is not None:
                progress.update(key=key, status=pr.status, params=pr.params, error=pr.error)
    finally:
        if own:
            ex.shutdown(wait=True)
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
