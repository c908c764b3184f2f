"""Reports: PNG figures (matplotlib, Agg), a JSON/CSV summary and a short Markdown page.

Functions take plain arrays and dicts, so the jig-accuracy run, the scene runner and the learning
sessions all call them the same way:

- :func:`plot_estimated_vs_true`: estimate against truth with the identity line, mean ± std per
  commanded value (Li 2014 Fig. 7b: rotation, 7c: translation);
- :func:`plot_error_histogram`;
- :func:`plot_tactile_map`: a height or intensity image in millimetres, optional contact overlay;
- :func:`plot_trace`: stacked time series of a controller :class:`~tactile_rig.control.protocols.Trace`
  (force, gripper opening, effort... as the thesis's Figs. 3.4 and 3.16);
- :func:`error_stats`, :func:`write_summary` (JSON + CSV) and :class:`Report` (the Markdown page).

matplotlib is the optional extra ``report``; :func:`pyplot` imports it when a figure is drawn.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from tactile_rig.core.geometry import wrap_deg
from tactile_rig.core.jsonable import to_jsonable


def pyplot() -> Any:
    """matplotlib's ``pyplot`` on the Agg backend (files only, no window, no display), or
    ModuleNotFoundError naming the extra that installs it. Every figure the rig draws goes through here."""
    try:
        import matplotlib
    except ModuleNotFoundError as exc:  # pragma: no cover - depends on the install
        raise ModuleNotFoundError("figures need matplotlib: pip install 'tactile-rig[report]'",
                                  name=exc.name) from exc
    matplotlib.use("Agg", force=True)  # headless: never open a window, never need a display
    import matplotlib.pyplot as plt

    return plt


def _finite_pair(true: Sequence[float] | np.ndarray, est: Sequence[float] | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(true, float).ravel()
    e = np.asarray(est, float).ravel()
    if t.shape != e.shape:
        raise ValueError(f"true ({t.size} values) and estimated ({e.size} values) must have the same length")
    ok = np.isfinite(t) & np.isfinite(e)
    return t[ok], e[ok]


def error_stats(true: Sequence[float], est: Sequence[float], *, angle: bool = False) -> dict[str, float]:
    """MAE, std, RMSE, bias and max of ``est - true`` over the finite pairs (angles wrapped when ``angle``).

    ``n_missing`` counts pairs where either value is not finite (a failed estimate).
    """
    t_all = np.asarray(true, float).ravel()
    t, e = _finite_pair(true, est)
    err = wrap_deg(e - t) if angle else e - t
    n = int(err.size)
    if n == 0:
        nan = float("nan")
        return {"n": 0, "n_missing": int(t_all.size), "mae": nan, "std": nan, "rmse": nan, "bias": nan, "max_abs": nan}
    a = np.abs(err)
    return {"n": n, "n_missing": int(t_all.size - n), "mae": float(a.mean()), "std": float(a.std()),
            "rmse": float(np.sqrt(np.mean(err**2))), "bias": float(err.mean()), "max_abs": float(a.max())}


def plot_estimated_vs_true(true: Sequence[float] | np.ndarray, est: Sequence[float] | np.ndarray, path: str | Path, *,
                           quantity: str = "rotation", unit: str = "deg", title: str | None = None,
                           true_label: str | None = None, est_label: str | None = None) -> Path:
    """Estimated against true (Li 2014 Fig. 7b/c): each commanded value's mean ± std, raw points faint."""
    plt = pyplot()
    t, e = _finite_pair(true, est)
    fig, ax = plt.subplots(figsize=(4.5, 4.2), dpi=100)
    if t.size:
        lo, hi = float(min(t.min(), e.min())), float(max(t.max(), e.max()))
        pad = 0.05 * (hi - lo or 1.0)
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], "k--", lw=0.8, label="ideal")
        ax.scatter(t, e, s=6, alpha=0.3, color="tab:blue")
        levels = np.unique(t)
        means = np.array([e[t == v].mean() for v in levels])
        stds = np.array([e[t == v].std() for v in levels])
        ax.errorbar(levels, means, yerr=stds, fmt="o", ms=3, capsize=2, color="tab:red", label="mean ± std")
        ax.legend(loc="upper left", fontsize=8)
    ax.set_xlabel(f"{true_label or 'true ' + quantity} ({unit})")
    ax.set_ylabel(f"{est_label or 'estimated ' + quantity} ({unit})")
    ax.set_title(title or f"{quantity}: estimated vs true")
    ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_error_histogram(errors: Sequence[float], path: str | Path, *, quantity: str = "error",
                         unit: str = "", bins: int = 30, title: str | None = None) -> Path:
    """Histogram of errors with the MAE and std in the title."""
    plt = pyplot()
    e = np.asarray(errors, float).ravel()
    e = e[np.isfinite(e)]
    fig, ax = plt.subplots(figsize=(4.5, 3.4), dpi=100)
    u = f" ({unit})" if unit else ""
    if e.size:
        ax.hist(e, bins=max(1, min(bins, e.size)), color="tab:blue", alpha=0.8)
        ax.axvline(0.0, color="k", lw=0.8)
        stats = f"MAE {np.abs(e).mean():.3g}{u}, std {np.abs(e).std():.3g}, n={e.size}"
    else:
        stats = "no finite values"
    ax.set_xlabel(f"{quantity}{u}")
    ax.set_ylabel("count")
    ax.set_title(title or stats, fontsize=9)
    return _save(fig, path)


def plot_tactile_map(image: np.ndarray, path: str | Path, *, mm_per_px: tuple[float, float] | float | None = None,
                     title: str = "tactile map", label: str = "height (mm)",
                     points_mm: np.ndarray | None = None) -> Path:
    """A tactile map image (height map or stitched intensity), axes in mm when ``mm_per_px`` is given."""
    plt = pyplot()
    img = np.asarray(image)
    if img.ndim not in (2, 3) or img.size == 0:
        raise ValueError(f"tactile map must be a non-empty HxW or HxWx3 image, got shape {img.shape}")
    fig, ax = plt.subplots(figsize=(5.5, 4.2), dpi=100)
    extent = None
    if mm_per_px is not None:
        if isinstance(mm_per_px, tuple):
            sx, sy = float(mm_per_px[0]), float(mm_per_px[1])
        else:
            sx = sy = float(mm_per_px)
        h, w = img.shape[:2]
        extent = (0.0, w * float(sx), h * float(sy), 0.0)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
    else:
        ax.set_xlabel("x (px)")
        ax.set_ylabel("y (px)")
    if img.ndim == 3:
        ax.imshow(img[:, :, ::-1] if img.dtype == np.uint8 else img, extent=extent)
    else:
        im = ax.imshow(np.where(np.isfinite(img), img, np.nan), cmap="viridis", extent=extent)
        fig.colorbar(im, ax=ax, label=label)
    if points_mm is not None and len(points_mm):
        p = np.asarray(points_mm, float)
        ax.plot(p[:, 0], p[:, 1], "r+", ms=6)
    ax.set_title(title)
    return _save(fig, path)


def plot_trace(trace: Any, path: str | Path, *, channels: Sequence[str | Sequence[str]] | None = None,
               title: str = "controller trace", units: Mapping[str, str] | None = None,
               events: Mapping[str, float] | None = None) -> Path:
    """Stacked time series of a Trace (``t_s`` + ``channels``) or a dict ``{"t_s": [...], name: [...]}``.

    ``channels`` picks and orders the panels; an entry that is a tuple of names overlays them on one
    panel (e.g. ``("force_n", "target_force_n")``). ``events`` (label → time in s) are drawn as
    vertical lines on every panel (e.g. "grasp", "slip").
    """
    plt = pyplot()
    t, chans = _trace_columns(trace)
    panels = [[c] if isinstance(c, str) else list(c) for c in (channels if channels is not None else list(chans))]
    names = [n for group in panels for n in group]
    missing = [n for n in names if n not in chans]
    if missing:
        raise ValueError(f"trace has no channel(s) {', '.join(missing)}; it has: {', '.join(chans) or '(none)'}")
    if not names:
        raise ValueError("trace has no channels to plot")
    fig, axes = plt.subplots(len(panels), 1, sharex=True, figsize=(6.5, 1.6 * len(panels) + 0.6), dpi=100,
                             squeeze=False)
    for ax, group in zip(axes[:, 0], panels):
        for name in group:
            ax.plot(t, chans[name], lw=1.0, label=name)
        if len(group) > 1:
            ax.legend(fontsize=7, loc="upper right")
        unit = (units or {}).get(group[0], "")
        ax.set_ylabel(f"{', '.join(group)}{f' ({unit})' if unit else ''}", fontsize=8)
        ax.grid(alpha=0.3)
        for label, te in (events or {}).items():
            ax.axvline(te, color="tab:red", lw=0.8, ls=":")
            if ax is axes[0, 0]:
                ax.annotate(label, (te, 1.0), xycoords=("data", "axes fraction"), fontsize=7, color="tab:red",
                            va="bottom")
    axes[-1, 0].set_xlabel("time (s)")
    axes[0, 0].set_title(title)
    return _save(fig, path)


def _trace_columns(trace: Any) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if isinstance(trace, Mapping):
        if "t_s" not in trace:
            raise ValueError("a trace dict needs a 't_s' column")
        t = np.asarray(trace["t_s"], float)
        chans = {k: np.asarray(v, float) for k, v in trace.items() if k != "t_s"}
    else:
        t = np.asarray(getattr(trace, "t_s"), float)
        chans = {k: np.asarray(v, float) for k, v in getattr(trace, "channels").items()}
    for k, v in chans.items():
        if v.shape != t.shape:
            raise ValueError(f"trace channel {k!r} has {v.size} values for {t.size} times")
    return t, chans


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(p, format="png")
    pyplot().close(fig)
    return p


# -- tables -----------------------------------------------------------------------------------
def write_summary(out_dir: str | Path, summary: Mapping[str, Any], rows: Iterable[Mapping[str, Any]] | None = None,
                  *, name: str = "summary") -> dict[str, Path]:
    """Write ``<name>.json`` (the summary, plus the rows) and ``<name>.csv`` (the rows, one per point)."""

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows_l = [dict(r) for r in rows] if rows is not None else []
    paths = {"json": out / f"{name}.json"}
    body = dict(summary)
    if rows_l:
        body["rows"] = rows_l
    paths["json"].write_text(json.dumps(to_jsonable(body), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    if rows_l:
        cols: list[str] = []
        for r in rows_l:
            cols += [k for k in r if k not in cols]
        paths["csv"] = out / f"{name}.csv"
        with open(paths["csv"], "w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=cols)
            w.writeheader()
            for r in rows_l:
                w.writerow({k: _cell(r.get(k)) for k in cols})
    return paths


def _cell(v: Any) -> Any:
    if isinstance(v, float):
        return "" if not math.isfinite(v) else repr(v)
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v)
    return v


@dataclass
class Report:
    """A short Markdown page tying figures, numbers and tables together (``report.md`` in ``out_dir``)."""

    out_dir: Path
    title: str
    parts: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)

    def text(self, markdown: str) -> "Report":
        self.parts.append(markdown.strip() + "\n")
        return self

    def numbers(self, heading: str, values: Mapping[str, Any]) -> "Report":
        """A two-column table of named values (floats to 4 significant digits)."""
        lines = [f"## {heading}", "", "| quantity | value |", "|---|---|"]
        for k, v in values.items():
            lines.append(f"| {k} | {_fmt(v)} |")
        self.parts.append("\n".join(lines) + "\n")
        return self

    def table(self, heading: str, rows: Sequence[Mapping[str, Any]]) -> "Report":
        if not rows:
            return self
        cols: list[str] = []
        for r in rows:
            cols += [k for k in r if k not in cols]
        lines = [f"## {heading}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in rows:
            lines.append("| " + " | ".join(_fmt(r.get(c)) for c in cols) + " |")
        self.parts.append("\n".join(lines) + "\n")
        return self

    def figure(self, path: str | Path, caption: str) -> "Report":
        p = Path(path)
        try:
            rel = p.resolve().relative_to(self.out_dir.resolve())  # links work when the folder moves
        except ValueError:
            rel = p
        self.parts.append(f"![{caption}]({rel.as_posix()})\n\n*{caption}*\n")
        return self

    def write(self, name: str = "report.md") -> Path:
        p = self.out_dir / name
        p.write_text(f"# {self.title}\n\n" + "\n".join(self.parts), encoding="utf-8")
        return p


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return "n/a" if not math.isfinite(v) else f"{v:.4g}"
    if isinstance(v, np.generic):
        return _fmt(v.item())
    return str(v) if v is not None else ""
