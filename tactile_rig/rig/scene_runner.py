"""Run a controller in a simulated scene: wire world, sensors, clock and controller; record the trace.

A scene file (see :mod:`tactile_rig.sim.scenes`) names the world models; three more sections
drive an episode:

``[controller]``  ``kind`` (which episode wiring in :mod:`tactile_rig.rig.episodes` to use) and the
                  controller's parameters;
``[sensor]``      ``kind = "model"`` (perception result from the world, with ``rate_hz``,
                  ``latency_s`` and noise) or ``"rendered"`` (the real renderer and processor);
``[randomize.X]`` per-episode uniform draws ``param = [low, high]`` for model ``X`` (or for
                  ``sensor`` / ``controller``); ``param.i`` draws element ``i`` of a list.

Episode ``i`` of a run with seed ``s`` uses seed ``s + i`` for everything (draws, model noise,
sensor noise), so any episode can be replayed alone. The same wiring runs on a RealClock.
"""

from __future__ import annotations

import copy
import importlib
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from tactile_rig.control.common import ControllerResult
from tactile_rig.core.clock import Clock, VirtualClock
from tactile_rig.core.errors import RigError
from tactile_rig.rig.files import load_toml
from tactile_rig.sim.fakes.sensors import ModelSensor, RenderedSensor
from tactile_rig.sim.scenes import Scene, builtin_scenes, load_scene, resolve_scene_path


@dataclass
class EpisodeReport:
    """One episode: whether it met the controller's property, its outcome and key figures."""

    scene: str
    episode: int
    seed: int
    ok: bool
    outcome: str
    figures: dict[str, float] = field(default_factory=dict)
    message: str = ""
    fault_device: str | None = None
    sim_s: float = 0.0
    wall_s: float = 0.0
    result: ControllerResult | None = None

    def to_json(self) -> dict[str, Any]:
        return {"scene": self.scene, "episode": self.episode, "seed": self.seed, "ok": self.ok,
                "outcome": self.outcome, **{k: _round(v) for k, v in self.figures.items()},
                "message": self.message, "fault_device": self.fault_device,
                "sim_s": _round(self.sim_s), "wall_s": _round(self.wall_s)}


def _round(v: Any) -> Any:
    if isinstance(v, float):
        return None if not math.isfinite(v) else round(v, 6)
    return v


@dataclass
class EpisodeContext:
    """What an episode wiring gets: the built scene, its clock, the drawn sections and an RNG."""

    scene: Scene
    clock: Clock
    seed: int
    controller: dict[str, Any]
    sensor: dict[str, Any]
    rng: np.random.Generator
    speed_mps: float | None = None
    draws: dict[str, float] = field(default_factory=dict)

    @property
    def world(self) -> Any:
        return self.scene.world

    def model(self, name: str) -> Any:
        try:
            return self.scene.world.require(name, who=f"controller {self.controller.get('kind')!r}")
        except LookupError as exc:  # a scene file that lacks a model: a bad argument, not a crash
            raise ValueError(str(exc)) from None

    def make_sensor(self, probe: Callable[[float], Any], *, name: str = "tactile",
                    render: Callable[[float], Any] | None = None,
                    process: Callable[[Any, float], Any] | None = None) -> Any:
        """Build the scene's TactileSensor from ``[sensor]``: a model sensor over ``probe`` or,
        with ``kind = "rendered"``, ``render``/``process``."""

        s = dict(self.sensor)
        kind = s.pop("kind", "model")
        if kind == "model":
            return ModelSensor(self.clock, probe, rng=np.random.default_rng([self.seed, 17]), name=name, **s)
        if kind == "rendered":
            if render is None or process is None:
                raise ValueError(f"scene {self.scene.name!r}: sensor kind 'rendered' is not available "
                                 "for this controller (no renderer/processor wiring)")
            keep = {k: s[k] for k in ("rate_hz", "latency_s", "freeze_at_s") if k in s}
            return RenderedSensor(self.clock, render, process, name=name, **keep)
        raise ValueError(f"scene {self.scene.name!r}: [sensor] kind={kind!r} must be 'model' or 'rendered'")

    def settle_and_check_still(self, motions: Sequence[Any] = (), grippers: Sequence[Any] = (),
                               settle_s: float = 0.5) -> bool:
        """After the run: let time pass and check that no axis or gripper is still moving."""
        self.clock.sleep(settle_s)
        still = True
        for m in motions:
            if hasattr(m, "is_moving"):
                still = still and not m.is_moving()
            else:  # a driver: two pose reads a moment apart must agree
                p0 = m.pose()
                self.clock.sleep(0.1)
                p1 = m.pose()
                still = still and all(abs(a - b) < 1e-3 for a, b in zip(
                    (p0.x_mm, p0.y_mm, p0.z_mm, p0.theta_deg), (p1.x_mm, p1.y_mm, p1.z_mm, p1.theta_deg)))
        for g in grippers:
            try:
                st = g.state()
            except RigError:  # a faulted gripper with torque off cannot move (a bug still raises)
                continue
            if st.moving and abs(st.velocity_mps) > 1e-5:
                still = False
        return still


EpisodeFn = Callable[[EpisodeContext], EpisodeReport]


def episode_fn(kind: str) -> EpisodeFn:
    """The wiring of controller ``kind`` (module :mod:`tactile_rig.rig.episodes.<kind>`)."""
    try:
        module = importlib.import_module(f"tactile_rig.rig.episodes.{kind}")
    except ModuleNotFoundError as exc:
        if exc.name == f"tactile_rig.rig.episodes.{kind}":
            raise ValueError(f"unknown controller kind {kind!r} in the scene's [controller]") from None
        raise
    return module.run_episode


def scene_info(name_or_path: str) -> dict[str, Any]:
    """Name, description and controller kind of a scene, without building its world."""
    path = resolve_scene_path(name_or_path)
    data = load_toml(path, "scene file")[0]
    head = data.get("scene", {})
    return {"name": path.stem, "controller": data.get("controller", {}).get("kind"),
            "description": head.get("description", ""),
            "models": {k: v.get("type") for k, v in data.get("models", {}).items()}}


def list_scenes() -> list[dict[str, Any]]:
    """Built-in scenes that drive a controller."""
    out = []
    for name in builtin_scenes():
        info = scene_info(name)
        if info["controller"]:
            out.append(info)
    return out


def _set_param(table: dict[str, Any], key: str, value: float) -> None:
    """Set ``param`` or an element ``param.i`` / ``param.i.j`` of a (nested) list."""
    name, *idx = key.split(".")
    if not idx:
        table[name] = value
        return
    node: Any = table.get(name)
    try:
        for i in idx[:-1]:
            node = node[int(i)]
        node[int(idx[-1])] = value
    except (TypeError, IndexError, ValueError):
        raise ValueError(f"randomize: {key!r} does not index into {table.get(name)!r}") from None


def draw_episode(raw: dict[str, Any], rng: np.random.Generator) -> tuple[dict[str, dict[str, Any]], dict[str, float]]:
    """Draw the ``[randomize]`` values: (per-model/section overrides, flat draws for the report)."""
    overrides: dict[str, dict[str, Any]] = {}
    draws: dict[str, float] = {}
    models = raw.get("models", {})
    for target, params in raw.get("randomize", {}).items():
        base = copy.deepcopy(models.get(target, raw.get(target, {})))
        base.pop("type", None)
        over = overrides.setdefault(target, {})
        for key, rng_spec in params.items():
            if not (isinstance(rng_spec, list) and len(rng_spec) == 2):
                raise ValueError(f"randomize.{target}.{key} must be [low, high], got {rng_spec!r}")
            lo, hi = float(rng_spec[0]), float(rng_spec[1])
            v = float(rng.uniform(lo, hi))
            name = key.partition(".")[0]
            if name not in over and name in base:
                over[name] = copy.deepcopy(base[name])
            _set_param(over, key, v)
            draws[f"{target}.{key}"] = v
    return overrides, draws


def run_episode(scene_name: str, seed: int = 0, *, episode: int = 0, speed_mps: float | None = None,
                clock: Clock | None = None, overrides: dict[str, dict[str, Any]] | None = None) -> EpisodeReport:
    """Run one episode of ``scene_name`` with ``seed`` (a fresh VirtualClock unless ``clock``)."""
    path = resolve_scene_path(scene_name)
    raw = load_toml(path, "scene file")[0]
    rng = np.random.default_rng(seed)
    drawn, draws = draw_episode(raw, rng)
    for k, v in (overrides or {}).items():
        drawn.setdefault(k, {}).update(v)
    clock = clock if clock is not None else VirtualClock()
    model_over = {k: v for k, v in drawn.items() if k in raw.get("models", {})}
    scene = load_scene(path, clock=clock, seed=seed, overrides=model_over)
    controller = {**raw.get("controller", {}), **drawn.get("controller", {})}
    sensor = {**raw.get("sensor", {}), **drawn.get("sensor", {})}
    kind = controller.get("kind")
    if not kind:
        raise ValueError(f"scene {scene.name!r} has no [controller] kind: it drives no controller")
    ctx = EpisodeContext(scene, clock, seed, controller, sensor, rng, speed_mps, draws)
    t0_sim, t0_wall = clock.now_s(), time.perf_counter()
    report = episode_fn(kind)(ctx)
    report.scene, report.episode, report.seed = path.stem, episode, seed
    report.sim_s = clock.now_s() - t0_sim
    report.wall_s = time.perf_counter() - t0_wall
    return report


def run_episodes(scene_name: str, seed: int = 0, episodes: int = 1, *, speed_mps: float | None = None,
                 on_episode: Callable[[EpisodeReport], None] | None = None) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed .. seed+episodes-1``); return the summary."""
    reports = []
    for i in range(episodes):
        r = run_episode(scene_name, seed + i, episode=i, speed_mps=speed_mps)
        r.result = None  # keep memory flat over hundreds of episodes
        reports.append(r)
        if on_episode is not None:
            on_episode(r)
    return summarize(scene_name, reports)


def summarize(scene_name: str, reports: list[EpisodeReport]) -> dict[str, Any]:
    outcomes: dict[str, int] = {}
    for r in reports:
        outcomes[r.outcome] = outcomes.get(r.outcome, 0) + 1
    sim = sum(r.sim_s for r in reports)
    wall = sum(r.wall_s for r in reports)
    summary: dict[str, Any] = {"summary": True, "scene": scene_name, "episodes": len(reports),
                               "ok": sum(r.ok for r in reports), "outcomes": outcomes,
                               "sim_s": round(sim, 3), "wall_s": round(wall, 3),
                               "sim_per_wall": round(sim / wall, 2) if wall > 0 else None}
    keys = sorted({k for r in reports for k, v in r.figures.items() if isinstance(v, (int, float))})
    for k in keys:
        vals = [float(r.figures[k]) for r in reports
                if isinstance(r.figures.get(k), (int, float)) and math.isfinite(float(r.figures[k]))]
        if vals:
            summary[f"max_{k}"] = round(max(vals), 6)
    return summary
