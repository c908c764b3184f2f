"""A speed/accuracy trade table: one row per setting, speed and error measured in the same run.

Every topic of ``tactile-rig trade`` (GelSight reconstruction, registration, FingerVision, collision
stop, scenes) measures a list of settings and returns a :class:`TradeTable`. The table knows which
rows are on the Pareto front (no other row is at least as fast *and* at least as accurate, one of the
two strictly), which row is the shipped default (and, when the default is off the front, why:
``default_note``), the conditions it was measured under, and prints itself (text, markdown),
serialises (:meth:`TradeTable.to_dict` / :meth:`TradeTable.from_dict`) and plots itself.

Speeds measured on a shared machine wobble by several per cent between runs, so two speeds within
``speed_tolerance`` (relative) count as equal when deciding dominance: a row is not pushed off the
front by a rival that is only "faster" within measurement noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.rig.trade.conditions import conditions_text


@dataclass(frozen=True)
class TradeRow:
    """One measured setting.

    ``setting`` maps knob names to values (only the knobs that differ from the default need be given,
    but every row of a table should name the same knobs); ``speed`` is the topic's speed figure
    (higher is better, e.g. frames per second or real-time factor); ``error`` its accuracy figure
    (lower is better, e.g. height RMS in mm); ``extra`` holds further figures printed beside them.
    """

    setting: Mapping[str, Any]
    speed: float
    error: float
    is_default: bool = False
    extra: Mapping[str, float] = field(default_factory=dict)
    note: str = ""


@dataclass
class TradeTable:
    """A topic's trade: rows plus what the two axes mean and what the error was measured on."""

    topic: str
    speed_name: str
    error_name: str
    data: str
    rows: list[TradeRow]
    knobs: Mapping[str, str] = field(default_factory=dict)
    speed_tolerance: float = 0.05
    notes: list[str] = field(default_factory=list)
    default_note: str = ""  # why the default is where it is (required reading when it is off the front)
    conditions: dict[str, Any] = field(default_factory=dict)  # machine, cores, load: see conditions.py

    def __post_init__(self) -> None:
        if not self.rows:
            raise ValueError(f"trade table {self.topic!r} has no rows; expected at least one measured setting")
        n_default = sum(r.is_default for r in self.rows)
        if n_default != 1:
            raise ValueError(f"trade table {self.topic!r} marks {n_default} rows as default; expected exactly 1")
        if not 0.0 <= self.speed_tolerance < 1.0:
            raise ValueError(f"speed_tolerance {self.speed_tolerance} must be in [0, 1)")
        for r in self.rows:
            if not isinstance(r.setting, Mapping):
                raise ValueError(f"trade table {self.topic!r}: row setting {r.setting!r} must be a mapping "
                                 "of knob name to value")

    def _dominates(self, a: TradeRow, b: TradeRow) -> bool:
        """True when ``a`` is at least as good as ``b`` on both axes and strictly better on one."""
        if not (math.isfinite(a.speed) and math.isfinite(a.error)):
            return False
        if not (math.isfinite(b.speed) and math.isfinite(b.error)):
            return True  # a failed measurement is dominated by any finite one
        tol = self.speed_tolerance * max(abs(a.speed), abs(b.speed))
        a_faster = a.speed > b.speed + tol
        same_speed = abs(a.speed - b.speed) <= tol
        if a_faster and a.error <= b.error:
            return True
        return same_speed and a.error < b.error

    def front(self) -> list[int]:
        """Indices of the rows on the Pareto front, fastest first."""
        idx = [i for i, r in enumerate(self.rows)
               if not any(self._dominates(o, r) for j, o in enumerate(self.rows) if j != i)]
        return sorted(idx, key=lambda i: -self.rows[i].speed)

    @property
    def default_index(self) -> int:
        return next(i for i, r in enumerate(self.rows) if r.is_default)

    def default_on_front(self) -> bool:
        return self.default_index in self.front()

    def to_dict(self) -> dict[str, Any]:
        front = set(self.front())
        return {
            "topic": self.topic,
            "speed_name": self.speed_name,
            "error_name": self.error_name,
            "data": self.data,
            "knobs": dict(self.knobs),
            "speed_tolerance": self.speed_tolerance,
            "default_on_front": self.default_on_front(),
            "default_note": self.default_note,
            "notes": list(self.notes),
            "conditions": dict(self.conditions),
            "rows": [
                {"setting": dict(r.setting), "speed": _finite_or_none(r.speed),
                 "error": _finite_or_none(r.error), "is_default": r.is_default,
                 "on_front": i in front,
                 "extra": {k: _finite_or_none(v) for k, v in r.extra.items()}, "note": r.note}
                for i, r in enumerate(self.rows)
            ],
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "TradeTable":
        """The table :meth:`to_dict` wrote (``null`` figures become NaN: a failed measurement)."""
        try:
            rows = [TradeRow(dict(r["setting"]), _float_or_nan(r["speed"]), _float_or_nan(r["error"]),
                             bool(r.get("is_default", False)),
                             {k: _float_or_nan(v) for k, v in (r.get("extra") or {}).items()},
                             str(r.get("note", "")))
                    for r in d["rows"]]
            return cls(str(d["topic"]), str(d["speed_name"]), str(d["error_name"]), str(d.get("data", "")),
                       rows, dict(d.get("knobs") or {}), float(d.get("speed_tolerance", 0.05)),
                       list(d.get("notes") or []), str(d.get("default_note", "")),
                       dict(d.get("conditions") or {}))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a trade table: missing or malformed {exc}") from None

    def front_text(self) -> str:
        """The Pareto front in one line, fastest first: ``a (speed, error) → b (...)``."""
        parts = []
        for i in self.front():
            r = self.rows[i]
            parts.append(f"{_setting_text(r.setting)}{' [default]' if r.is_default else ''} "
                         f"({_num(r.speed)}, {_num(r.error)})")
        return "Pareto front, fastest first: " + " → ".join(parts)

    def _default_line(self) -> str:
        on = self.default_on_front()
        line = f"D the default ({_setting_text(self.rows[self.default_index].setting)}), " \
               f"{'on' if on else 'NOT on'} the front"
        if self.default_note:
            line += f": {self.default_note}"
        elif not on:
            line += ": no reason given"
        return line

    def _extra_names(self) -> list[str]:
        names: list[str] = []
        for r in self.rows:
            names += [k for k in r.extra if k not in names]
        return names

    def to_markdown(self) -> str:
        """A markdown table sorted by speed (front rows in bold marks), with the default's line,
        the notes and the conditions underneath."""
        front = set(self.front())
        extra = self._extra_names()
        head = ["front", "default", "setting", self.speed_name, self.error_name, *extra, "note"]
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        order = sorted(range(len(self.rows)), key=lambda i: -_sortable(self.rows[i].speed))
        for i in order:
            r = self.rows[i]
            cells = ["**yes**" if i in front else "", "**D**" if r.is_default else "",
                     f"`{_setting_text(r.setting)}`", _num(r.speed), _num(r.error),
                     *[_num(r.extra[k]) if k in r.extra else "" for k in extra], r.note.replace("|", "/")]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        lines.append(self.front_text() + ".")
        lines.append("")
        lines.append(self._default_line().replace("D the default", "The default", 1) + ".")
        for n in self.notes:
            lines += ["", n]
        if self.conditions:
            lines += ["", f"Measured on: {conditions_text(self.conditions)}."]
        return "\n".join(lines)

    def format_text(self) -> str:
        """A plain-text table, sorted by speed, with ``*`` on the front and ``D`` on the default."""
        front = set(self.front())
        extra_names = self._extra_names()
        header = ["", "setting", self.speed_name, self.error_name, *extra_names, "note"]
        body: list[list[str]] = []
        order = sorted(range(len(self.rows)), key=lambda i: -_sortable(self.rows[i].speed))
        for i in order:
            r = self.rows[i]
            mark = ("*" if i in front else " ") + ("D" if r.is_default else " ")
            body.append([mark, _setting_text(r.setting), _num(r.speed), _num(r.error),
                         *[_num(r.extra[k]) if k in r.extra else "" for k in extra_names], r.note])
        widths = [max(len(row[c]) for row in [header, *body]) for c in range(len(header))]
        lines = [f"trade {self.topic}: {self.error_name} (lower is better) against {self.speed_name} "
                 f"(higher is better); data: {self.data}"]
        lines.append("  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip())
        lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths)).rstrip() for row in body]
        lines.append(f"* on the Pareto front (speeds within {self.speed_tolerance:.0%} count as equal)")
        lines.append(self._default_line())
        lines.append(self.front_text())
        lines += [f"note: {n}" for n in self.notes]
        if self.conditions:
            lines.append(f"measured on: {conditions_text(self.conditions)}")
        return "\n".join(lines)

    def plot(self, path: str | Path) -> Path:
        """Draw error against speed (log speed axis), the front as a line, the default ringed; PNG."""
        try:
            import matplotlib
        except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
            raise ModuleNotFoundError("plots need matplotlib: pip install 'tactile-rig[report]'",
                                      name=exc.name) from exc
        matplotlib.use("Agg", force=True)
        import matplotlib.pyplot as plt

        path = Path(path)
        ok = [i for i, r in enumerate(self.rows) if math.isfinite(r.speed) and math.isfinite(r.error)
              and r.speed > 0]
        fig, ax = plt.subplots(figsize=(7.0, 5.2), dpi=110)
        ax.scatter([self.rows[i].speed for i in ok], [self.rows[i].error for i in ok], s=18,
                   color="0.55", label="setting")
        front = [i for i in self.front() if i in ok]
        ax.plot([self.rows[i].speed for i in front], [self.rows[i].error for i in front], "-o",
                color="tab:blue", ms=4, label="Pareto front")
        d = self.default_index
        if d in ok:
            ax.scatter([self.rows[d].speed], [self.rows[d].error], s=110, facecolors="none",
                       edgecolors="tab:red", linewidths=1.6, label="default")
        # Front points are numbered; the settings are listed under the axes (long labels beside the
        # points would squeeze the plot).
        legend_lines = []
        for n, i in enumerate(front, 1):
            ann = ax.annotate(str(n), (self.rows[i].speed, self.rows[i].error), fontsize=7, xytext=(4, 3),
                              textcoords="offset points", color="tab:blue")
            ann.set_in_layout(False)
            legend_lines.append(f"{n}: {_setting_text(self.rows[i].setting)}"
                                f"{' (default)' if self.rows[i].is_default else ''}")
        if d not in front:
            legend_lines.append(f"default: {_setting_text(self.rows[d].setting)}")
        ax.set_xscale("log")
        ax.set_xlabel(f"{self.speed_name} (higher is better)")
        ax.set_ylabel(f"{self.error_name} (lower is better)")
        ax.set_title(f"trade {self.topic}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        caption = "\n".join(legend_lines[:12] + (["…"] if len(legend_lines) > 12 else []))
        fig.text(0.01, 0.01, caption, fontsize=6.5, va="bottom", ha="left", family="monospace")
        fig.tight_layout(rect=(0, 0.026 * (min(len(legend_lines), 13) + 0.5), 1, 1))
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path)
        plt.close(fig)
        return path


def _finite_or_none(x: float) -> float | None:
    return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else None


def _float_or_nan(x: Any) -> float:
    return math.nan if x is None else float(x)


def _sortable(x: float) -> float:
    return x if math.isfinite(x) else -math.inf


def _num(x: Any) -> str:
    if not isinstance(x, (int, float)):
        return str(x)
    if not math.isfinite(x):
        return "failed"
    if x == 0 or 0.01 <= abs(x) < 1e5:
        return f"{x:.4g}"
    return f"{x:.3g}"


def _setting_text(setting: Mapping[str, Any]) -> str:
    return " ".join(f"{k}={v}" for k, v in setting.items()) or "(defaults)"

