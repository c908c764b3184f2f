"""A run as a printed table, and as figures (Li 2014 Fig. 7b/c) plus ``report.md`` in its folder."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tactile_rig.core.geometry import wrap_deg
from tactile_rig.rig import reports
from tactile_rig.rig.jig_accuracy.localizer import TouchLocalizer
from tactile_rig.rig.jig_accuracy.plan import PAPER_FIGURES
from tactile_rig.rig.jig_accuracy.results import PointResult
from tactile_rig.rig.jig_accuracy.run import RunOutcome


def _f(v: float | None, fmt: str) -> str:
    return "—" if v is None or not math.isfinite(float(v)) else format(float(v), fmt)


def format_table(results: Sequence[PointResult], summary: dict[str, Any]) -> str:
    """The run as a text table (one row per point) and the Li 2014 comparison."""
    head = (f"{'#':>3} {'sweep':<11} {'cmd θ°':>7} {'cmd x':>6} {'cmd y':>6} | {'true θ°':>8} {'true x':>7} "
            f"{'true y':>7} | {'est θ°':>8} {'est x':>7} {'est y':>7} | {'err θ°':>6} {'err mm':>6} {'conf':>5}")
    lines = [head, "-" * len(head)]
    for r in sorted(results, key=lambda r: r.index):
        e = r.estimate
        lines.append(
            f"{r.index:>3} {r.sweep:<11} {r.commanded.theta_deg:>7.1f} {r.commanded.x_mm:>6.1f} "
            f"{r.commanded.y_mm:>6.1f} | {r.truth.theta_deg:>8.3f} {r.truth.x_mm:>7.3f} {r.truth.y_mm:>7.3f} | "
            f"{_f(e.theta_deg if e else None, '8.3f'):>8} {_f(e.x_mm if e else None, '7.3f'):>7} "
            f"{_f(e.y_mm if e else None, '7.3f'):>7} | "
            f"{_f(r.rotation_error_deg, '6.3f'):>6} {_f(r.translation_error_mm, '6.3f'):>6} "
            f"{_f(r.confidence, '5.3f'):>5}" + ("" if r.ok else f"  refused: {r.reason}"))
    lines.append("")
    s, p = summary, PAPER_FIGURES
    lines.append(f"rotation sweep    ({s['rotation_points']:>2} points): MAE {_f(s['rotation_mae_deg'], '.3f')}° "
                 f"(std {_f(s['rotation_std_deg'], '.3f')}°)    Li 2014: {p['rotation_mae_deg']}° "
                 f"(std {p['rotation_std_deg']}°)")
    lines.append(f"translation sweep ({s['translation_points']:>2} points): MAE "
                 f"{_f(s['translation_mae_mm'], '.4f')} mm (std {_f(s['translation_std_mm'], '.4f')} mm)    "
                 f"Li 2014: {p['translation_mae_mm']} mm (std {p['translation_std_mm']} mm)")
    lines.append(f"localized {s['n_localized']}/{s['n_points']} points ({s['n_refused']} refused, "
                 f"{s.get('extra_touches', 0)} re-touches)")
    return "\n".join(lines)

def write_report(outcome: RunOutcome, localizer: TouchLocalizer | None = None) -> dict[str, str]:
    """Figures (estimated vs true as Li 2014 Fig. 7b/c, error histograms, the tactile map) and
    ``report.md`` in the run's folder. Needs matplotlib for the figures; without it only the page."""
    out = outcome.out_dir
    files: dict[str, str] = {}
    res = sorted(outcome.results, key=lambda r: r.index)
    rot = [r for r in res if r.sweep == "rotation"]
    tra = [r for r in res if r.sweep == "translation"]
    nan = float("nan")
    figs: list[tuple[Path, str]] = []
    try:
        if rot:
            figs.append((reports.plot_estimated_vs_true(
                [r.truth.theta_deg for r in rot], [r.estimate.theta_deg if r.estimate else nan for r in rot],
                out / "rotation_est_vs_true.png", quantity="rotation", unit="deg",
                title="rotation (cf. Li 2014 Fig. 7b)"), "Rotation sweep: estimated vs true"))
            figs.append((reports.plot_error_histogram(
                [wrap_deg(r.estimate.theta_deg - r.truth.theta_deg) for r in rot if r.estimate],
                out / "rotation_error_hist.png", quantity="rotation error", unit="deg"),
                "Rotation error (estimate − truth)"))
        if tra:
            axis = "x_mm" if any(abs(r.commanded.x_mm) > 0 for r in tra) else "y_mm"
            figs.append((reports.plot_estimated_vs_true(
                [getattr(r.truth, axis) for r in tra], [getattr(r.estimate, axis) if r.estimate else nan for r in tra],
                out / "translation_est_vs_true.png", quantity=f"shift {axis[0]}", unit="mm",
                title="translation (cf. Li 2014 Fig. 7c)"), "Translation sweep: estimated vs true"))
            figs.append((reports.plot_error_histogram(
                [r.translation_error_mm for r in tra if r.translation_error_mm is not None],
                out / "translation_error_hist.png", quantity="translation error", unit="mm"),
                "Translation error: distance between estimate and truth"))
        if localizer is not None and not localizer.map.empty:
            cov = localizer.map.coverage
            rows, cols = np.nonzero(cov.any(axis=1))[0], np.nonzero(cov.any(axis=0))[0]
            crop = np.where(cov, localizer.map.height_mm, np.nan)[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            figs.append((reports.plot_tactile_map(crop, out / "tactile_map.png", mm_per_px=localizer.map.mm_per_px,
                                                  title=f"tactile map ({localizer.map_size} touches)"),
                         "Tactile map (height, mm)"))
    except ModuleNotFoundError as exc:
        if exc.name != "matplotlib":
            raise
        files["figures"] = "skipped: matplotlib is not installed (pip install 'tactile-rig[report]')"
    s = outcome.summary
    page = reports.Report(out, "Jig accuracy run (Li 2014, Fig. 7)")
    page.text("Estimated vs true jig poses; truth is the simulated stage pose on mocks and the commanded "
              "jig pose on a bench. Errors: |Δθ| for the rotation sweep, |Δ(x, y)| for the translation "
              "sweep; MAE and standard deviation of the absolute errors; refused touches are counted, "
              "not scored.")
    page.numbers("Summary", {
        "rotation MAE (deg)": s["rotation_mae_deg"], "rotation std (deg)": s["rotation_std_deg"],
        "translation MAE (mm)": s["translation_mae_mm"], "translation std (mm)": s["translation_std_mm"],
        "Li 2014 rotation MAE / std (deg)": f"{PAPER_FIGURES['rotation_mae_deg']} / {PAPER_FIGURES['rotation_std_deg']}",
        "Li 2014 translation MAE / std (mm)":
            f"{PAPER_FIGURES['translation_mae_mm']} / {PAPER_FIGURES['translation_std_mm']}",
        "points localized": f"{s['n_localized']} / {s['n_points']}"})
    for path, caption in figs:
        page.figure(path, caption)
        files[path.stem] = str(path)
    page.table("Points", [{"#": r.index, "sweep": r.sweep, "true θ": r.truth.theta_deg, "true x": r.truth.x_mm,
                           "true y": r.truth.y_mm, "est θ": r.estimate.theta_deg if r.estimate else None,
                           "est x": r.estimate.x_mm if r.estimate else None,
                           "est y": r.estimate.y_mm if r.estimate else None,
                           "err θ": r.rotation_error_deg, "err mm": r.translation_error_mm,
                           "c": r.confidence, "refused": r.reason or ""} for r in res])
    files["report"] = str(page.write())
    return files