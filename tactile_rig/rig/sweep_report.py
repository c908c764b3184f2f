"""One table from a sweep: per point, the success rate and the median and worst of each figure.

A sweep point that ran N episodes answers "how often does it work here, and how bad does it get":
:func:`sweep_table` folds the episodes of each point into one :class:`SweepRow`. An episode counts
as a success when it ran without an exception and its result does not say otherwise (a result's
``ok`` field, as every scene episode has). A figure is any numeric field of the results (bookkeeping
fields such as the seed are left out); its worst value is the largest, unless the figure is named
in ``higher_is_better`` (then the smallest). Failed episodes have no figures: they count against the
success rate only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from tactile_rig.rig.reports import pyplot
from tactile_rig.rig.sweep import SweepSummary

# Result fields that describe the run, not the outcome.
BOOKKEEPING = frozenset({"seed", "episode", "wall_s", "sim_s", "ok", "summary"})


@dataclass
class FigureStats:
    median: float
    worst: float
    n: int


@dataclass
class SweepRow:
    """One point: its parameters, episodes run, successes and each figure's statistics."""

    params: dict[str, Any]
    episodes: int
    successes: int
    figures: dict[str, FigureStats] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes if self.episodes else math.nan


def _succeeded(status: str, result: Any) -> bool:
    if status not in ("ok", "skipped"):
        return False
    if isinstance(result, dict) and "ok" in result:
        return bool(result["ok"])
    return True


def _numeric(result: Any) -> dict[str, float]:
    if not isinstance(result, dict):
        return {}
    return {k: float(v) for k, v in result.items()
            if k not in BOOKKEEPING and isinstance(v, (int, float)) and not isinstance(v, bool)}


def sweep_table(summary: SweepSummary, *, figures: Sequence[str] | None = None,
                higher_is_better: Iterable[str] = ()) -> list[SweepRow]:
    """Rows in the order points first appear; ``figures`` restricts (and orders) the figures shown
    (an unknown name is a ``ValueError`` naming the figures the results have)."""
    better_high = set(higher_is_better)
    groups: dict[str, list[Any]] = {}
    for p in summary.points:
        groups.setdefault(p.point or p.key, []).append(p)
    found: list[str] = []
    for eps in groups.values():
        for p in eps:
            found += [k for k in _numeric(p.result) if k not in found]
    if figures:
        bad = [f for f in figures if f not in found]
        if bad:
            raise ValueError(f"--figure {', '.join(bad)}: the results have no such figure; they have: "
                             f"{', '.join(found) or '(no numeric figures)'}")
        names = list(figures)
    else:
        names = found
    bad_hib = sorted(better_high - set(found))
    if bad_hib:
        raise ValueError(f"--higher-is-better {', '.join(bad_hib)}: no such figure; the results have: "
                         f"{', '.join(found) or '(none)'}")
    rows = []
    for eps in groups.values():
        row = SweepRow(dict(eps[0].params), len(eps), sum(_succeeded(p.status, p.result) for p in eps))
        row.errors = sorted({p.error for p in eps if p.error})
        for name in names:
            vals = np.array([v for p in eps if math.isfinite(v := _numeric(p.result).get(name, math.nan))])
            if vals.size:
                worst = float(vals.min() if name in better_high else vals.max())
                row.figures[name] = FigureStats(float(np.median(vals)), worst, int(vals.size))
        rows.append(row)
    return rows


def _num(x: float) -> str:
    if not math.isfinite(x):
        return "-"
    if x == 0 or 0.01 <= abs(x) < 1e5:
        return f"{x:.4g}"
    return f"{x:.3g}"


def _swept(rows: list[SweepRow]) -> list[str]:
    """Parameter names whose value differs between points (the axes), in first-seen order."""
    names: list[str] = []
    for r in rows:
        names += [k for k in r.params if k not in names]
    return [n for n in names if len({repr(r.params.get(n)) for r in rows}) > 1] or names


def format_table(rows: list[SweepRow], *, higher_is_better: Iterable[str] = ()) -> str:
    """Plain text: one line per point, ``median / worst`` per figure."""
    hib = set(higher_is_better)
    axes = _swept(rows)
    figs: list[str] = []
    for r in rows:
        figs += [k for k in r.figures if k not in figs]
    head = [*axes, "episodes", "success", *[f"{f} med/worst{'(min)' if f in hib else ''}" for f in figs]]
    body = []
    for r in rows:
        cells = [str(r.params.get(a, "")) for a in axes] + [str(r.episodes), f"{r.success_rate:.0%}"]
        for f in figs:
            st = r.figures.get(f)
            cells.append(f"{_num(st.median)} / {_num(st.worst)}" if st else "-")
        body.append(cells)
    widths = [max(len(x[c]) for x in [head, *body]) for c in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip()]
    lines += ["  ".join(c.ljust(w) for c, w in zip(b, widths)).rstrip() for b in body]
    for r in rows:
        for e in r.errors[:2]:
            lines.append(f"  failed at {r.params}: {e}")
    return "\n".join(lines)


def table_json(rows: list[SweepRow]) -> list[dict[str, Any]]:
    return [{"params": r.params, "episodes": r.episodes, "successes": r.successes,
             "success_rate": r.success_rate,
             "figures": {k: {"median": v.median, "worst": v.worst, "n": v.n} for k, v in r.figures.items()},
             "errors": r.errors} for r in rows]


def plot_table(rows: list[SweepRow], path: str | Path, *, figures: Sequence[str] | None = None) -> Path:
    """Success rate and each figure (median, with the worst as a second marker) against the first
    swept parameter; one line per combination of the others. PNG; needs matplotlib."""
    plt = pyplot()
    axes = _swept(rows)
    x_name = axes[0] if axes else None
    figs = list(figures) if figures else []
    if not figs:
        for r in rows:
            figs += [k for k in r.figures if k not in figs]
    figs = figs[:4]
    groups: dict[str, list[SweepRow]] = {}
    for r in rows:
        label = " ".join(f"{a}={r.params.get(a)}" for a in axes[1:]) or "all"
        groups.setdefault(label, []).append(r)

    def xval(r: SweepRow, i: int) -> Any:
        v = r.params.get(x_name) if x_name else i
        return v if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)

    fig, axs = plt.subplots(1 + len(figs), 1, figsize=(6.4, 2.2 * (1 + len(figs))), dpi=110, sharex=True,
                            squeeze=False)
    for label, rs in groups.items():
        xs = [xval(r, i) for i, r in enumerate(rs)]
        line, = axs[0, 0].plot(xs, [r.success_rate for r in rs], "-o", ms=4, label=label)
        for k, f in enumerate(figs, 1):
            med = [r.figures[f].median if f in r.figures else math.nan for r in rs]
            worst = [r.figures[f].worst if f in r.figures else math.nan for r in rs]
            axs[k, 0].plot(xs, med, "-o", ms=4, color=line.get_color())
            axs[k, 0].plot(xs, worst, "v", ms=5, color=line.get_color(), alpha=0.7)
    axs[0, 0].set_ylabel("success rate")
    axs[0, 0].set_ylim(-0.05, 1.05)
    for k, f in enumerate(figs, 1):
        axs[k, 0].set_ylabel(f, fontsize=8)
    axs[-1, 0].set_xlabel(x_name or "point")
    if len(groups) > 1:
        axs[0, 0].legend(fontsize=6)
    axs[0, 0].set_title("sweep: median (line) and worst (▼) per point", fontsize=9)
    for a in axs[:, 0]:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
