"""``tactile-rig trade TOPIC``: speed against accuracy, measured per knob in one run.

A topic is a module of this package exposing::

    TOPIC: str          # its name on the command line
    SUMMARY: str        # one line for --help
    def measure(*, quick: bool, seed: int) -> TradeTable

``measure`` runs every setting of its knobs on the same data in the same process (speed and
accuracy side by side, a baseline in the same run), marks the shipped default, and returns the
table; it never writes files. ``quick`` keeps a run to a few minutes on 2 cores by measuring fewer
frames or episodes per setting, never fewer settings.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from tactile_rig.rig.trade.table import TradeRow, TradeTable

# Topic name -> module; topics import heavy pieces (renderers, scene models), so load on demand.
TOPICS: dict[str, str] = {}
TOPICS.update(gelsight="tactile_rig.rig.trade.gelsight", registration="tactile_rig.rig.trade.registration")


def topic_module(name: str) -> ModuleType:
    """The module measuring ``name``; ``ValueError`` naming the known topics otherwise."""
    try:
        module_name = TOPICS[name]
    except KeyError:
        raise ValueError(f"unknown trade topic {name!r}; expected one of {sorted(TOPICS)}") from None
    return importlib.import_module(module_name)


def measure(name: str, *, quick: bool = False, seed: int = 0) -> TradeTable:
    """Measure topic ``name`` and return its table."""
    table = topic_module(name).measure(quick=quick, seed=seed)
    if not isinstance(table, TradeTable):
        raise TypeError(f"trade topic {name!r} returned {type(table).__name__}, expected TradeTable")
    return table


__all__ = ["TOPICS", "TradeRow", "TradeTable", "measure", "topic_module"]
