"""``tactile-rig trade TOPIC``: speed against accuracy, measured per knob in one run.

A topic is one module of this package plus one line in :data:`TOPICS`. The module exposes::

    TOPIC: str          # its name on the command line (the key in TOPICS)
    SUMMARY: str        # one line for --help and the docs page
    def measure(*, quick: bool, seed: int) -> TradeTable

``measure`` runs every setting of its knobs on the same data in the same process (speed and
accuracy side by side, a baseline in the same run), marks the shipped default (and, when the default
is not on the Pareto front, says why in ``TradeTable.default_note``), and returns the table; it never
writes files. ``quick`` keeps a run to a few minutes on 2 cores by measuring fewer frames or episodes
per setting, never fewer settings. :func:`measure` records the conditions (machine, load, cores).

:mod:`tactile_rig.rig.trade.timing` holds the speed helpers topics share (interleaved rounds, so a
load spike on a shared machine hits every setting alike).
"""

from __future__ import annotations

import importlib
import importlib.util
import time
from types import ModuleType

from tactile_rig.core.memory import keep_freed_memory
from tactile_rig.rig.trade.conditions import measure_conditions
from tactile_rig.rig.trade.table import TradeRow, TradeTable

# Topic name -> module. One line per topic; a line whose module is absent from this checkout is
# listed as "not installed" rather than breaking the command.
TOPICS: dict[str, str] = {
    "collision": "tactile_rig.rig.trade.collision",
    "fingervision": "tactile_rig.rig.trade.fingervision",
    "gelsight": "tactile_rig.rig.trade.gelsight",
    "registration": "tactile_rig.rig.trade.registration",
    "scenes": "tactile_rig.rig.trade.scenes",
}


def register_topic(name: str, module: str) -> None:
    """Add topic ``name`` measured by importable ``module`` (a user's own study, for instance)."""
    if not name or not name.replace("_", "").isalnum():
        raise ValueError(f"trade topic name {name!r} must be a non-empty word (letters, digits, _)")
    TOPICS[name] = module


def available_topics() -> list[str]:
    """Registered topics whose module exists in this installation, sorted."""
    out = []
    for name, module in TOPICS.items():
        try:
            found = importlib.util.find_spec(module) is not None
        except ModuleNotFoundError:  # the parent package itself is missing
            found = False
        if found:
            out.append(name)
    return sorted(out)


def topic_module(name: str) -> ModuleType:
    """The module measuring ``name``; ``ValueError`` naming the known topics otherwise."""
    try:
        module_name = TOPICS[name]
    except KeyError:
        raise ValueError(f"unknown trade topic {name!r}; expected one of {available_topics()}") from None
    if name not in available_topics():
        raise ValueError(f"trade topic {name!r} is registered but its module {module_name} is not in this "
                         f"installation; available: {available_topics()}")
    module = importlib.import_module(module_name)
    if not callable(getattr(module, "measure", None)):
        raise TypeError(f"trade topic module {module_name} has no measure(*, quick, seed) function")
    return module


def summary(name: str) -> str:
    """The topic's one-line summary (imports its module)."""
    return str(getattr(topic_module(name), "SUMMARY", ""))


def measure(name: str, *, quick: bool = False, seed: int = 0) -> TradeTable:
    """Measure topic ``name`` and return its table with the run's conditions recorded."""
    module = topic_module(name)
    # Speeds are measured as the CLI runs (its per-frame commands keep freed memory): a setting's
    # buffers are reused across calls, not faulted in afresh (tactile_rig.core.memory).
    kept = keep_freed_memory()
    before = measure_conditions()
    t0 = time.perf_counter()
    table = module.measure(quick=quick, seed=seed)
    wall_s = time.perf_counter() - t0
    if not isinstance(table, TradeTable):
        raise TypeError(f"trade topic {name!r} returned {type(table).__name__}, expected TradeTable")
    after = measure_conditions()
    table.conditions = {**before, **table.conditions, "quick": bool(quick), "seed": int(seed),
                        "keep_freed_memory": kept,
                        "load_1min_after": after["load_1min"], "wall_s": round(wall_s, 2)}
    return table


__all__ = ["TOPICS", "TradeRow", "TradeTable", "available_topics", "measure", "measure_conditions",
           "register_topic", "summary", "topic_module"]
