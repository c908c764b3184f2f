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
``<model>.<param>`` / ``controller.<param>`` / ``sensor.<param>`` / ``speed_mps`` overriding the scene
(:mod:`tactile_rig.rig.sweep_targets`).

Executors: :class:`~concurrent.futures.ProcessPoolExecutor` locally (default), a
``ThreadPoolExecutor`` for debugging (``--executor thread``), or
Dask distributed (the optional extra ``distributed``): a scheduler at ``address`` or a local cluster
started (and closed) by the executor, its logs kept to errors (:mod:`tactile_rig.rig.sweep_executors`).

This module keys the points, runs them and collects the results; the names of the other two are
importable from here as well.
"""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import itertools
import json
import os
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

from tactile_rig.core.jsonable import to_jsonable
from tactile_rig.rig.sweep_executors import DaskExecutor, dask_executor, make_executor
from tactile_rig.rig.sweep_targets import (
    check_params,
    check_scene_params,
    controller_params,
    register_target,
    resolve_target,
)

__all__ = [
    "DaskExecutor", "KEY_LENGTH", "PointResult", "RESULT_FILE", "SweepSummary", "canonical", "check_params",
    "check_scene_params", "controller_params", "dask_executor", "demo_point", "episode_key", "grid",
    "make_executor", "parse_axis", "point_key", "register_target", "resolve_target", "run_point", "run_sweep",
    "seed_from_key",
]

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
