"""A speed/accuracy trade table: one row per setting, speed and error measured in the same run.

Every topic of ``tactile-rig trade`` (GelSight reconstruction, registration, FingerVision, collision
stop, scenes) measures a list of settings and returns a :class:`TradeTable`. The table knows which
rows are on the Pareto front (no other row is at least as fast *and* at least as accurate, one of the
two strictly), which row is the shipped default (and, when the default is off the front, why:
``default_note``), the conditions it was measured under, and prints itself (text, markdown),
serialises (:meth:`TradeTable.to_dict` / :meth:`TradeTable.from_dict`) and plots itself.

A table may hold several independent studies side by side (e.g. one per scene): ``group_by`` names
the knob that tells them apart; the front is then taken within each group (a row is only compared
with rows of its own group) and each group has its own default.

Speeds measured on a shared machine wobble by several per cent between runs, so two speeds within
``speed_tolerance`` (relative) count as equal when deciding dominance: a row is not pushed off the
front by a rival that is only "faster" within measurement noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from tactile_rig.rig.reports import pyplot
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
    group_by: str = ""  # a knob separating independent studies: one front and one default per value

    def __post_init__(self) -> None:
        if not self.rows:
            raise ValueError(f"trade table {self.topic!r} has no rows; expected at least one measured setting")
        for r in self.rows:
            if not isinstance(r.setting, Mapping):
                raise ValueError(f"trade table {self.topic!r}: row setting {r.setting!r} must be a mapping "
                                 "of knob name to value")
            if self.group_by and self.group_by not in r.setting:
                raise ValueError(f"trade table {self.topic!r}: group_by={self.group_by!r} but row "
                                 f"{dict(r.setting)} has no such knob")
        for g, idx in self._groups().items():
            n_default = sum(self.rows[i].is_default for i in idx)
            if n_default != 1:
                where = f" group {self.group_by}={g}" if self.group_by else ""
                raise ValueError(f"trade table {self.topic!r}{where} marks {n_default} rows as default; "
                                 "expected exactly 1")
        if not 0.0 <= self.speed_tolerance < 1.0:
            raise ValueError(f"speed_tolerance {self.speed_tolerance} must be in [0, 1)")

    def _groups(self) -> dict[Any, list[int]]:
        """Group value → row indices, in first-seen order (one group when ``group_by`` is empty)."""
        out: dict[Any, list[int]] = {}
        for i, r in enumerate(self.rows):
            key = repr(r.setting.get(self.group_by)) if self.group_by else ""
            out.setdefault(key, []).append(i)
        return out

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
        """Indices of the rows on the Pareto front (of their group), group by group, fastest first."""
        out: list[int] = []
        for idx in self._groups().values():
            keep = [i for i in idx if not any(self._dominates(self.rows[j], self.rows[i]) for j in idx if j != i)]
            out += sorted(keep, key=lambda i: -self.rows[i].speed)
        return out

    @property
    def default_index(self) -> int:
        """The (first group's) default row."""
        return next(i for i, r in enumerate(self.rows) if r.is_default)

    @property
    def default_indices(self) -> list[int]:
        """Every group's default row."""
        return [i for i, r in enumerate(self.rows) if r.is_default]

    def default_on_front(self) -> bool:
        """True when every default is on its group's front."""
        front = set(self.front())
        return all(i in front for i in self.default_indices)

    def _order(self) -> list[int]:
        """Rows group by group, fastest first (a failed row last)."""
        out: list[int] = []
        for idx in self._groups().values():
            out += sorted(idx, key=lambda i: -_sortable(self.rows[i].speed))
        return out

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
            "group_by": self.group_by,
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
                       dict(d.get("conditions") or {}), str(d.get("group_by") or ""))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a trade table: missing or malformed {exc}") from None

    def front_text(self) -> str:
        """The Pareto front in one line, fastest first: ``a (speed, error) → b (...)``."""
        front = set(self.front())
        texts = []
        for g, idx in self._groups().items():
            parts = []
            for i in [i for i in self._order() if i in front and i in idx]:
                r = self.rows[i]
                setting = {k: v for k, v in r.setting.items() if k != self.group_by}
                parts.append(f"{_setting_text(setting)}{' [default]' if r.is_default else ''} "
                             f"({_num(r.speed)}, {_num(r.error)})")
            head = f"Pareto front of {self.group_by}={self.rows[idx[0]].setting[self.group_by]}" \
                if self.group_by else "Pareto front"
            texts.append(f"{head}, fastest first: " + " → ".join(parts))
        return "; ".join(texts)

    def _default_line(self) -> str:
        on = self.default_on_front()
        front = set(self.front())
        if len(self.default_indices) == 1:
            line = f"D the default ({_setting_text(self.rows[self.default_index].setting)}), " \
                   f"{'on' if on else 'NOT on'} the front"
        else:
            each = ", ".join(f"{_setting_text(self.rows[i].setting)} {'on' if i in front else 'NOT on'}"
                             for i in self.default_indices)
            line = f"D the defaults, one per {self.group_by} ({each} its front)"
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
        order = self._order()
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
        order = self._order()
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
        plt = pyplot()
        path = Path(path)
        ok = [i for i, r in enumerate(self.rows) if math.isfinite(r.speed) and math.isfinite(r.error)
              and r.speed > 0]
        fig, ax = plt.subplots(figsize=(7.0, 5.2), dpi=110)
        ax.scatter([self.rows[i].speed for i in ok], [self.rows[i].error for i in ok], s=18,
                   color="0.55", label="setting")
        front = [i for i in self.front() if i in ok]
        groups = self._groups()
        for k, (g, idx) in enumerate(groups.items()):
            fr = [i for i in front if i in idx]
            label = "Pareto front" if not self.group_by else f"front, {self.group_by}={self.rows[idx[0]].setting[self.group_by]}"
            ax.plot([self.rows[i].speed for i in fr], [self.rows[i].error for i in fr], "-o",
                    color=f"C{k}", ms=4, label=label)
        defaults = [i for i in self.default_indices if i in ok]
        if defaults:
            ax.scatter([self.rows[i].speed for i in defaults], [self.rows[i].error for i in defaults], s=110,
                       facecolors="none", edgecolors="tab:red", linewidths=1.6, label="default")
        # Front points are numbered; the settings are listed under the axes (long labels beside the
        # points would squeeze the plot).
        legend_lines = []
        for n, i in enumerate(front, 1):
            k = next(k for k, idx in enumerate(groups.values()) if i in idx)
            ann = ax.annotate(str(n), (self.rows[i].speed, self.rows[i].error), fontsize=7, xytext=(4, 3),
                              textcoords="offset points", color=f"C{k}")
            ann.set_in_layout(False)
            legend_lines.append(f"{n}: {_setting_text(self.rows[i].setting)}"
                                f"{' (default)' if self.rows[i].is_default else ''}")
        for d in self.default_indices:
            if d not in front:
                legend_lines.append(f"default: {_setting_text(self.rows[d].setting)}")
        ax.set_xscale("log")
        ax.set_xlabel(f"{self.speed_name} (higher is better)")
        ax.set_ylabel(f"{self.error_name} (lower is better)")
        ax.set_title(f"trade {self.topic}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        shown = legend_lines[:20] + (["…"] if len(legend_lines) > 20 else [])
        fig.set_size_inches(7.0, 4.2 + 0.12 * len(shown))
        fig.text(0.01, 0.01, "\n".join(shown), fontsize=6.5, va="bottom", ha="left", family="monospace")
        fig.tight_layout(rect=(0, (0.12 * len(shown) + 0.15) / (4.2 + 0.12 * len(shown)), 1, 1))
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
    return " ".join(f"{k}={v}" if v != "" else str(k) for k, v in setting.items()) or "(defaults)"


def setting_text(setting: Mapping[str, Any]) -> str:
    """A setting as one line, ``knob=value knob2=value2`` (what the tables and plots print)."""
    return _setting_text(setting)
