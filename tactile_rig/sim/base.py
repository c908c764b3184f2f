"""The simulated world: small physics models composed per scene.

A scene needs only some models (a jig sweep needs the stage, an object and the GelSight renderer;
a handover needs fingers, object, FingerVision renderer and a scripted hand). Each model is a small
class with units in its names that integrates its own state lazily up to a time:
``advance_to(t_s)``. A :class:`World` holds the models of one scene by name, on one clock.

Model kinds register a factory with :func:`register_model`; :func:`tactile_rig.sim.scenes.load_scene`
builds a World from a TOML scene file. The package :mod:`tactile_rig.sim` imports every built-in
model module, so importing anything of it (this module included) registers them all.
"""

from __future__ import annotations

import threading
from typing import Any, Callable, Iterator, Protocol, runtime_checkable

import numpy as np

from tactile_rig.core.clock import Clock, VirtualClock


@runtime_checkable
class WorldModel(Protocol):
    """A physics model: integrates its state up to ``t_s`` (never backwards)."""

    def advance_to(self, t_s: float) -> None: ...


ModelFactory = Callable[..., WorldModel]
_MODEL_FACTORIES: dict[str, ModelFactory] = {}


def register_model(kind: str) -> Callable[[ModelFactory], ModelFactory]:
    """Register a model factory under ``kind``: ``factory(world, rng, **params) -> model``.

    A class whose ``__init__(self, world, rng, **params)`` follows that signature can be decorated
    directly.
    """

    def deco(factory: ModelFactory) -> ModelFactory:
        if kind in _MODEL_FACTORIES and _MODEL_FACTORIES[kind] is not factory:
            raise ValueError(f"world model kind {kind!r} is registered twice")
        _MODEL_FACTORIES[kind] = factory
        return factory

    return deco


def model_kinds() -> list[str]:
    """Names of the registered model kinds (every built-in one registers when :mod:`tactile_rig.sim`
    is imported, which importing this module implies)."""
    return sorted(_MODEL_FACTORIES)


class World:
    """The models of one scene, on one clock; models are advanced lazily to ``clock.now_s()``."""

    def __init__(self, clock: Clock | None = None, *, seed: int = 0, name: str = "world") -> None:
        self.clock: Clock = clock if clock is not None else VirtualClock()
        self.seed = int(seed)
        self.name = name
        self._models: dict[str, WorldModel] = {}
        self._lock = threading.RLock()

    def add(self, name: str, model: WorldModel) -> WorldModel:
        """Add ``model`` under ``name`` (names are unique within a world)."""
        if name in self._models:
            raise ValueError(f"scene {self.name!r} already has a model named {name!r}")
        self._models[name] = model
        return model

    def build(self, name: str, kind: str, **params: Any) -> WorldModel:
        """Create a model of a registered ``kind`` with its own seeded RNG and add it under ``name``."""
        try:
            factory = _MODEL_FACTORIES[kind]
        except KeyError:
            raise ValueError(
                f"scene {self.name!r}: unknown model type {kind!r} for model {name!r}; "
                f"known types: {', '.join(sorted(_MODEL_FACTORIES)) or '(none)'}"
            ) from None
        # Each model gets its own stream so adding a model does not change another's noise.
        rng = np.random.default_rng([self.seed, _stable_hash(name)])
        return self.add(name, factory(self, rng, **params))

    def __contains__(self, name: object) -> bool:
        return name in self._models

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def get(self, name: str, default: Any = None) -> Any:
        return self._models.get(name, default)

    def require(self, name: str, who: str = "a mock") -> Any:
        """Return the model ``name`` or raise a ``LookupError`` that says which scene lacks it."""
        try:
            return self._models[name]
        except KeyError:
            raise LookupError(
                f"{who} needs world model {name!r}, but scene {self.name!r} only models: "
                f"{', '.join(self._models) or '(nothing)'}"
            ) from None

    def advance_to(self, t_s: float | None = None) -> float:
        """Integrate every model up to ``t_s`` (default: the clock's now); return that time."""
        t = self.clock.now_s() if t_s is None else t_s
        with self._lock:
            for model in self._models.values():
                model.advance_to(t)
        return t

    def __repr__(self) -> str:
        return f"World({self.name!r}, models={list(self._models)}, clock={self.clock!r})"


def _stable_hash(text: str) -> int:
    import zlib

    return zlib.crc32(text.encode("utf-8"))
